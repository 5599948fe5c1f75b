"""ActionFlowPolicy: the LeRobot policy. It validates inputs, keeps the observation history and the action
queue, and applies the runtime options (latency compensation, action smoothing); the model it wraps
(:class:`~lerobot_actionflow.core.model.ActionFlowModel`) holds encode / loss / sample.
"""

from __future__ import annotations

import copy
import json
import logging
import time
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import torch
from lerobot.configs import PreTrainedConfig
from lerobot.policies.pretrained import PreTrainedPolicy
from torch import Tensor

from lerobot_actionflow.configuration_actionflow import ActionFlowConfig
from lerobot_actionflow.core import geometry as g
from lerobot_actionflow.core.model import ActionFlowModel
from lerobot_actionflow.core.pose_layouts import POSE_LAYOUTS, actions_from_ours, actions_to_ours
from lerobot_actionflow.schema import (
    ACTION,
    POSE_DIM,
    POSE_LAYOUT,
    STATE,
    TOKEN_FEATURES,
    TOKEN_POSES,
)

LEGACY_DEFAULTS = {
    "squash_limit": 1.0,
    "rotation_noise_std": None,
    "euclidean_frame": "eef",
    "image_history": None,
}
"""Config fields whose default changed after checkpoints were published, with the value those checkpoints were
trained with: a saved config that lacks the field gets this value back on loading, not today's default."""
_HUB_KWARGS = (
    "force_download",
    "resume_download",
    "proxies",
    "token",
    "cache_dir",
    "local_files_only",
    "revision",
)


def saved_config_keys(pretrained_name_or_path: str | Path, **hub_kwargs) -> set[str] | None:
    """The field names in a checkpoint's saved ``config.json`` (a local folder or a Hub repo); None when it
    cannot be read (LeRobot's own loading then reports the problem)."""
    path = Path(pretrained_name_or_path)
    try:
        if path.is_dir():
            config_file = path / "config.json"
        else:
            from huggingface_hub import hf_hub_download

            config_file = hf_hub_download(
                repo_id=str(pretrained_name_or_path), filename="config.json", **hub_kwargs
            )
        return set(json.loads(Path(config_file).read_text()))
    except Exception:  # noqa: BLE001 - missing or unreadable: not ours to report
        return None


@dataclass
class FlowTrajectory:
    """Every state of the sampler for one chunk, world frame: what the ``K`` Euler steps do to the noise.

    ``times [K + 1]``: flow times ``t_0 = 0`` (the noise) < ... < ``t_K = 1`` (the chunk).
    ``actions [K + 1, B, horizon, 10]``: each state as actions (target EEF pose + gripper command, clamped to
    [-1, 1] as in the chunk); ``actions[-1]`` is the chunk that ``predict_action_chunk`` returns.
    """

    times: Tensor
    actions: Tensor


class ActionFlowPolicy(PreTrainedPolicy):
    """ActionFlow (Funk et al.): equivariant, accurate and fast policies with SE(3) flow matching."""

    config_class = ActionFlowConfig
    name = "actionflow"
    clock = staticmethod(time.perf_counter)
    """The clock (seconds) latency compensation reads around each chunk's sampling; a runtime that simulates
    its inference delay (``eval/bench_delay.py``) or a test replaces it with its own."""
    record_flow = False
    """True: ``select_action`` keeps every Euler step of each new chunk in ``last_flow`` (for visualisation);
    the chunk is the same either way."""

    def __init__(self, config: ActionFlowConfig, dataset_meta=None, **kwargs):
        super().__init__(config)
        config.validate_features()
        self.config = config
        if dataset_meta is not None and getattr(dataset_meta, "tasks", None) is not None:
            # lerobot-train: the checkpoint records which task(s) it learned (lerobot-eval checks them).
            config.trained_tasks = sorted(str(t) for t in dataset_meta.tasks.index)
        self._task_checked = False
        self.state_layout = config.state_layout()
        """Where the EEF is in ``observation.state`` (a dataset without token keys), else None."""
        self.action_layout: str = config.action_layout
        """The dataset's action layout: ``forward`` converts its actions to ours, sampling back."""
        _check_gripper_range(kwargs.get("dataset_stats"))
        model = ActionFlowModel(config.model_spec())
        # Checkpoints hold the network's weights as `network.*` (the names from before the model existed): the
        # network is registered here under that name, and the model, which has no weights of its own, is kept
        # as a plain attribute so that its network is not registered a second time as `model.network.*`.
        self.network = model.network
        object.__setattr__(self, "model", model)
        self.ema_network = None
        """The weights' moving average (``ema_decay`` > 0), which sampling uses outside training mode."""
        if config.ema_decay > 0:
            self.ema_network = copy.deepcopy(self.network).requires_grad_(False)
            self.register_buffer("ema_updates", torch.zeros((), dtype=torch.long))
        self.observation_keys = model.observation_keys
        """The batch keys the policy reads: the model's, with ``observation.state`` for the token keys in a
        dataset without them."""
        if self.state_layout is not None:
            self.observation_keys = (STATE, *model.observation_keys[2:])
        self.reset()

    def get_optim_params(self) -> dict:
        return self.network.parameters()  # not the moving average, which `update` sets

    @torch.no_grad()
    def update(self) -> None:
        """Move the moving average of the weights toward the trained ones, after each optimiser step
        (LeRobot's training loop calls it); nothing when ``ema_decay`` is 0."""
        if self.ema_network is None:
            return
        n = int(self.ema_updates)
        decay = min(self.config.ema_decay, (1 + n) / (10 + n))
        for avg, w in zip(self.ema_network.parameters(), self.network.parameters(), strict=True):
            avg.lerp_(w, 1.0 - decay)
        for avg, b in zip(self.ema_network.buffers(), self.network.buffers(), strict=True):
            avg.copy_(b)
        self.ema_updates += 1

    @contextmanager
    def _sampling_weights(self):
        """Sample with the moving average when there is one and the policy is not in training mode."""
        if self.ema_network is None or self.training:
            yield
            return
        self.model.network = self.ema_network
        try:
            yield
        finally:
            self.model.network = self.network

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path: str | Path, *, config=None, **kwargs):
        """LeRobot's loading, plus: a checkpoint saved before a default changed keeps the value it was trained
        with (:data:`LEGACY_DEFAULTS`), unless the caller set the field to something else."""
        hub = {k: kwargs[k] for k in _HUB_KWARGS if k in kwargs}
        if config is None:
            config = PreTrainedConfig.from_pretrained(pretrained_name_or_path, **hub)
        saved = saved_config_keys(pretrained_name_or_path, **hub)
        if saved is not None:
            for name, legacy in LEGACY_DEFAULTS.items():
                default = ActionFlowConfig.__dataclass_fields__[name].default
                if name not in saved and getattr(config, name) == default and default != legacy:
                    logging.info(f"{pretrained_name_or_path}: saved before '{name}' existed; using {legacy}")
                    setattr(config, name, legacy)
        return super().from_pretrained(pretrained_name_or_path, config=config, **kwargs)

    @classmethod
    def _load_as_safetensor(cls, model, model_file: str, map_location: str, strict: bool):
        """LeRobot's loading of the weights, with a damaged file named instead of a deep traceback."""
        from safetensors import SafetensorError

        try:
            return super()._load_as_safetensor(model, model_file, map_location, strict)
        except SafetensorError as err:
            raise ValueError(
                f"cannot read the policy weights {model_file}: {err}. The file is damaged or incomplete (an "
                "interrupted download or copy?): copy or download the checkpoint again"
            ) from None

    def reset(self):
        """Clear the observation history and the action queue; call on every ``env.reset()``."""
        self._obs_queues = {k: deque(maxlen=self.config.n_obs_steps) for k in self.observation_keys}
        self._action_queue: deque[Tensor] = deque(maxlen=self.config.n_action_steps)
        self.last_chunk: Tensor | None = None
        self.last_flow: FlowTrajectory | None = None
        self._last_action: Tensor | None = None

    # ------------------------------------------------------------------ inputs

    def _check_and_stack(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """Validate the observation and return it with a history axis: ``[B, T, ...]``, ``T = n_obs_steps``.

        A batch without a history axis (one step, as from an environment) is repeated over the history.
        Without token keys the EEF token is built from ``observation.state`` first.
        """
        for key in self.observation_keys:
            if key not in batch:
                scene = (
                    [f"{TOKEN_POSES} (N, 9)", f"{TOKEN_FEATURES} (N, F)"]
                    if self.state_layout is None
                    else [f"{STATE} ({self.state_layout.dim},)"]
                )
                raise ValueError(
                    f"missing observation key {key!r}; the batch has {sorted(batch)}. ActionFlow expects "
                    + ", ".join([*scene, *self.model.observation_keys[2:]])
                )
        if self.state_layout is not None:
            batch = {**batch, **self._state_tokens(batch[STATE])}
        poses, feats = batch[TOKEN_POSES], batch[TOKEN_FEATURES]
        n_tokens, feature_dim = self.model.spec.tokens_per_step, self.model.spec.token_feature_dim
        if poses.dim() not in (3, 4) or poses.shape[-1] != POSE_DIM:
            raise ValueError(
                f"{TOKEN_POSES} has shape {tuple(poses.shape)}; expected (B, N, 9) or (B, T, N, 9) pose "
                "vectors "
                f"{POSE_LAYOUT}"
            )
        if feats.shape[:-1] != poses.shape[:-1]:
            raise ValueError(
                f"{TOKEN_FEATURES} has shape {tuple(feats.shape)} but {TOKEN_POSES} has shape "
                f"{tuple(poses.shape)}; expected the same leading dims and token count, (..., N, F)"
            )
        if poses.shape[-2] != n_tokens or feats.shape[-1] != feature_dim:
            raise ValueError(
                f"{TOKEN_POSES} / {TOKEN_FEATURES} have shapes {tuple(poses.shape)} / {tuple(feats.shape)}; "
                "this "
                f"policy was built for N={n_tokens} tokens with F={feature_dim} features"
            )
        if not torch.isfinite(poses).all():
            bad = (~torch.isfinite(poses)).nonzero()[0].tolist()
            raise ValueError(
                f"{TOKEN_POSES} contains a non-finite value ({poses[tuple(bad)].item()} at index {bad}); "
                "expected finite pose vectors"
            )
        has_history = poses.dim() == 4
        out = {}
        for key in self.model.observation_keys:
            x = batch[key]
            if not has_history:
                x = x.unsqueeze(1).expand(x.shape[0], self.config.n_obs_steps, *x.shape[1:])
            if x.shape[1] != self.config.n_obs_steps:
                raise ValueError(
                    f"{key} has {x.shape[1]} history steps (shape {tuple(x.shape)}); expected "
                    f"n_obs_steps={self.config.n_obs_steps}"
                )
            out[key] = x
        return out

    def _state_tokens(self, state: Tensor) -> dict[str, Tensor]:
        """``observation.state [B, D]`` or ``[B, T, D]`` -> the EEF token: token poses ``[B, (T,) 1, 9]`` and
        features ``[B, (T,) 1, F]``."""
        dim = self.state_layout.dim
        if state.dim() not in (2, 3) or state.shape[-1] != dim:
            raise ValueError(
                f"{STATE} has shape {tuple(state.shape)}; expected (B, {dim}) or (B, T, {dim}), the state "
                f"this policy was trained on (the EEF pose in layout {self.state_layout.pose!r} at index "
                f"{self.state_layout.start})"
            )
        poses, feats = self.state_layout.tokens(state)
        return {TOKEN_POSES: poses, TOKEN_FEATURES: feats}

    # ------------------------------------------------------------------ training

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Flow-matching loss: weighted MSE of the translation, rotation and gripper velocity terms."""
        obs = self._check_and_stack(batch)
        if ACTION not in batch:
            raise ValueError(f"missing key {ACTION!r} for training; the batch has {sorted(batch)}")
        action, size = batch[ACTION], POSE_LAYOUTS[self.action_layout] + 1
        if action.dim() != 3 or action.shape[1:] != (self.config.horizon, size):
            layout = f"pose {POSE_LAYOUT}" if self.action_layout == "pose9" else f"pose {self.action_layout}"
            raise ValueError(
                f"{ACTION} has shape {tuple(action.shape)}; expected (B, horizon={self.config.horizon}, "
                f"{size}): target EEF {layout} + gripper"
            )
        action = actions_to_ours(self.action_layout, action)  # [B, H, 10]
        valid = torch.ones_like(action[..., 0], dtype=torch.bool)
        if self.config.mask_padded_actions and "action_is_pad" in batch:
            valid = ~batch["action_is_pad"]
        loss, losses = self.model.loss(obs, action, valid)
        return loss, {f"loss_{k}": v.item() for k, v in losses.items()}

    # ------------------------------------------------------------------ inference

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], noise=None, **kwargs) -> Tensor:
        """Sample a chunk ``[B, horizon, A]`` with ``num_inference_steps`` Euler steps, in the dataset's
        action layout (``A = 10``, target pose9 + gripper, for ours).

        ``noise`` (optional) is the initial flow state in the EEF frame: an ``SE3State`` for
        ``action_space="se3"``, a ``[B, H, 10]`` tensor for ``"euclidean"``; by default it is drawn from
        torch's global generator.
        """
        with self._sampling_weights():
            chunk = self.model.sample(self._check_and_stack(batch), noise, self.config.sampler())
        return actions_from_ours(self.action_layout, chunk)

    @torch.no_grad()
    def sample_trajectory(self, batch: dict[str, Tensor], noise=None) -> FlowTrajectory:
        """:meth:`predict_action_chunk` with every intermediate state kept (see :class:`FlowTrajectory`):
        under the same seed ``actions[-1]`` is bit for bit the chunk ``predict_action_chunk`` samples
        (tested), as both run ``ActionFlowModel``'s one sampling path. Actions are ours (pose9 + gripper)
        whatever the dataset's action layout."""
        with self._sampling_weights():
            times, actions = self.model.sample_trajectory(
                self._check_and_stack(batch), noise, self.config.sampler()
            )
        return FlowTrajectory(times=times, actions=actions)

    def _check_task(self, batch: dict) -> None:
        """Refuse an environment whose task (``batch["task"]``, which lerobot-eval fills from the env's
        ``task_description``) is not one this checkpoint was trained on. Once per policy."""
        self._task_checked = True
        tasks = batch.get("task")
        if not (self.config.check_task and self.config.trained_tasks and tasks):
            return
        tasks = [tasks] if isinstance(tasks, str) else list(tasks)
        foreign = sorted({t for t in tasks if t and t not in self.config.trained_tasks})
        if foreign:
            raise ValueError(
                f"this checkpoint was trained on the task {self.config.trained_tasks} but the environment's "
                f"task is {foreign}: evaluate it on the task it learned (its tokens "
                f"{self.config.token_names or '(unnamed)'} can match another task's by shape, and such a run "
                "fails without a word), or pass --policy.check_task=false to run it anyway"
            )

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """One action ``[B, A]`` per call (the dataset's action layout; ``A = 10`` for ours): a new chunk is
        sampled every ``n_action_steps`` calls."""
        if not self._task_checked:
            self._check_task(batch)
        for key in self.observation_keys:
            if key not in batch:
                self._check_and_stack(batch)  # raises the missing-key error
            queue = self._obs_queues[key]
            while len(queue) < queue.maxlen - 1:  # first call: fill the history with the current frame
                queue.append(batch[key])
            queue.append(batch[key])
        if not self._action_queue:
            history = {k: torch.stack(list(q), dim=1) for k, q in self._obs_queues.items()}
            start = self.clock()
            if self.record_flow:
                self.last_flow = self.sample_trajectory(history)
                chunk = actions_from_ours(self.action_layout, self.last_flow.actions[-1])
            else:
                chunk = self.predict_action_chunk(history)
            self.last_chunk = chunk  # the whole generated chunk, world frame, dataset layout (visualisation)
            skip = 0
            if self.config.latency_compensation:
                # Actions are due at 1 / control_fps intervals from the observation; keep at least one. On
                # CUDA the chunk's kernels are only queued when the sampler returns: wait for them before
                # reading the clock. (No wait before `start`: work still queued then, such as this
                # observation's transfer to the device, delays the chunk too and belongs in the span.)
                self._synchronize()
                elapsed = self.clock() - start
                skip = min(int(elapsed * self.config.control_fps), self.config.horizon - 1)
            self._action_queue.extend(chunk[:, skip : skip + self.config.n_action_steps].unbind(1))
        action = self._action_queue.popleft()
        if self.config.action_smoothing > 0 and self._last_action is not None:
            ours = [actions_to_ours(self.action_layout, a) for a in (self._last_action, action)]
            action = actions_from_ours(self.action_layout, smooth_action(*ours, self.config.action_smoothing))
        self._last_action = action
        return action

    def set_executed_action(self, action: Tensor) -> None:
        """Tell the policy which action ``[B, A]`` the robot executed last, when that was not the one
        ``select_action`` returned (an asynchronous runtime keeps executing the previous chunk while the next
        is sampled): ``action_smoothing`` filters the next returned action against it."""
        self._last_action = action

    def _device(self) -> torch.device:
        """The device the network runs on (where its weights are, whatever ``config.device`` says)."""
        return next(self.network.parameters()).device

    def _synchronize(self) -> None:
        """Wait until the device has finished the work queued so far: on CUDA, kernels run asynchronously, and
        a clock read without waiting measures when they were launched, not when they finished. Nothing to
        wait for on the CPU."""
        device = self._device()
        if device.type == "cuda":
            torch.cuda.synchronize(device)


def smooth_action(previous: Tensor, new: Tensor, alpha: float) -> Tensor:
    """Exponential smoothing ``alpha * previous + (1 - alpha) * new`` done on SE(3): translation and gripper
    linearly, rotation along the geodesic from the previous to the new orientation."""
    rot_prev, trans_prev = g.pose9_to_rt(previous[..., :POSE_DIM])
    rot_new, trans_new = g.pose9_to_rt(new[..., :POSE_DIM])
    rot, _ = g.so3_geodesic(rot_prev, rot_new, 1.0 - alpha)
    trans = alpha * trans_prev + (1.0 - alpha) * trans_new
    gripper = alpha * previous[..., POSE_DIM:] + (1.0 - alpha) * new[..., POSE_DIM:]
    return torch.cat([g.rt_to_pose9(rot, trans), gripper], dim=-1)


def _check_gripper_range(stats: dict | None) -> None:
    """Refuse a dataset whose action's gripper value (its last element) leaves [-1, 1]: the sampled command
    is clamped there, so such a policy could never command the larger values (no stats: nothing to check)."""
    column = (stats or {}).get(ACTION) or {}
    if "min" not in column or "max" not in column:
        return
    low, high = float(torch.as_tensor(column["min"])[-1]), float(torch.as_tensor(column["max"])[-1])
    if low < -1.0 - 1e-6 or high > 1.0 + 1e-6:
        raise ValueError(
            f"the dataset's action gripper value (its last element) ranges over [{low:g}, {high:g}]; "
            "ActionFlow expects a gripper command in [-1, 1] (-1 open, 1 closed) and clamps what it samples "
            "there: record the gripper command scaled to [-1, 1]"
        )
