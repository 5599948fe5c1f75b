"""ActionFlowPolicy: the LeRobot policy. It glues the adaptation module, the flow and the network together.

Data flow for one chunk::

    token poses [B, T, N, 9] --(EEF frame of token 0 at the last step, x scale)--> local poses
    token features / images / points --> encoders --> SceneTokens (once per chunk)
    noise in the local frame --(K Euler steps of the flow, network velocity)--> local action poses
    --(back to the world frame)--> actions [B, H, 10] = target EEF pose (9) + gripper
"""

from __future__ import annotations

import time
from collections import deque

import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from torch import Tensor

from lerobot_actionflow.configuration_actionflow import ActionFlowConfig
from lerobot_actionflow.core import geometry as g
from lerobot_actionflow.core.adaptation import EEFFrame
from lerobot_actionflow.core.flow import EuclideanFlow, SE3Flow, SE3State, integrate, time_grid
from lerobot_actionflow.core.network import ActionFlowNetwork, NetworkSpec, SceneTokens
from lerobot_actionflow.schema import (
    ACTION,
    ACTION_DIM,
    GRIPPER_DIM,
    POINT_CLOUD,
    POSE_DIM,
    POSE_LAYOUT,
    TOKEN_FEATURES,
    TOKEN_POSES,
)


class ActionFlowPolicy(PreTrainedPolicy):
    """ActionFlow (Funk et al.): equivariant, accurate and fast policies with SE(3) flow matching."""

    config_class = ActionFlowConfig
    name = "actionflow"
    _clock = staticmethod(time.perf_counter)  # seconds; replaceable in tests

    def __init__(self, config: ActionFlowConfig, **kwargs):
        super().__init__(config)
        config.validate_features()
        self.config = config
        self.flow = SE3Flow(GRIPPER_DIM) if config.action_space == "se3" else EuclideanFlow(GRIPPER_DIM)
        inputs = config.input_features
        n_tokens, feature_dim = inputs[TOKEN_FEATURES].shape
        self.image_keys = tuple(config.image_features)
        self.has_point_cloud = POINT_CLOUD in inputs
        spec = NetworkSpec(
            token_feature_dim=feature_dim,
            tokens_per_step=n_tokens,
            n_obs_steps=config.n_obs_steps,
            horizon=config.horizon,
            action_input_dim=GRIPPER_DIM if config.action_space == "se3" else self.flow.velocity_dim,
            velocity_dim=self.flow.velocity_dim,
            image_keys=self.image_keys,
            point_cloud=self.has_point_cloud,
        )
        self.network = ActionFlowNetwork(
            spec,
            config.architecture,
            config.dim,
            config.num_heads,
            config.ipa_layers,
            config.transformer_layers,
            config.ipa_head_dim,
            config.ipa_query_points,
            config.ipa_value_points,
            config.dropout,
        )
        self.observation_keys = (TOKEN_POSES, TOKEN_FEATURES, *self.image_keys) + (
            (POINT_CLOUD,) if self.has_point_cloud else ()
        )
        self.reset()

    def get_optim_params(self) -> dict:
        return self.parameters()

    def reset(self):
        """Clear the observation history and the action queue; call on every ``env.reset()``."""
        self._obs_queues = {k: deque(maxlen=self.config.n_obs_steps) for k in self.observation_keys}
        self._action_queue: deque[Tensor] = deque(maxlen=self.config.n_action_steps)
        self.last_chunk: Tensor | None = None
        self._last_action: Tensor | None = None

    # ------------------------------------------------------------------ inputs

    def _check_and_stack(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """Validate the observation and return it with a history axis: ``[B, T, ...]``, ``T = n_obs_steps``.

        A batch without a history axis (one step, as from an environment) is repeated over the history.
        """
        for key in self.observation_keys:
            if key not in batch:
                raise ValueError(
                    f"missing observation key {key!r}; the batch has {sorted(batch)}. ActionFlow expects "
                    f"{TOKEN_POSES} (N, 9), {TOKEN_FEATURES} (N, F)"
                    + "".join(f", {k}" for k in self.observation_keys[2:])
                )
        poses, feats = batch[TOKEN_POSES], batch[TOKEN_FEATURES]
        n_tokens, feature_dim = self.config.input_features[TOKEN_FEATURES].shape
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
        for key in self.observation_keys:
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

    def _encode(self, obs: dict[str, Tensor]) -> tuple[EEFFrame, SceneTokens]:
        """Adaptation module + encoders: the EEF frame of the current step and the scene tokens in it."""
        rot, trans = g.pose9_to_rt(obs[TOKEN_POSES])  # [B, T, N, 3, 3], [B, T, N, 3]
        frame = EEFFrame(rot[:, -1, 0], trans[:, -1, 0], self.config.translation_scale)
        rot_l, trans_l = frame.to_local(rot, trans)
        images = {k: obs[k] for k in self.image_keys}
        points = frame.points_to_local(obs[POINT_CLOUD]) if self.has_point_cloud else None
        return frame, self.network.encode_observation(obs[TOKEN_FEATURES], rot_l, trans_l, images, points)

    def _velocity(self, scene: SceneTokens, x, t: Tensor) -> Tensor:
        poses = self.flow.to_poses(x)
        act_input = poses.extra if isinstance(self.flow, SE3Flow) else x
        return self.network(scene, poses.rot, poses.trans, act_input, t)

    # ------------------------------------------------------------------ training

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Flow-matching loss: weighted MSE of the translation, rotation and gripper velocity terms."""
        obs = self._check_and_stack(batch)
        if ACTION not in batch:
            raise ValueError(f"missing key {ACTION!r} for training; the batch has {sorted(batch)}")
        action = batch[ACTION]
        if action.dim() != 3 or action.shape[1:] != (self.config.horizon, ACTION_DIM):
            raise ValueError(
                f"{ACTION} has shape {tuple(action.shape)}; expected (B, horizon={self.config.horizon}, 10): "
                f"target EEF pose {POSE_LAYOUT} + gripper"
            )
        frame, scene = self._encode(obs)
        rot1, trans1 = frame.to_local(*g.pose9_to_rt(action))
        x1 = self.flow.from_poses(SE3State(rot1, trans1, action[..., POSE_DIM:]))
        b = action.shape[0]
        x0 = self.flow.noise(b, self.config.horizon, device=action.device, dtype=action.dtype)
        t = torch.rand(b, device=action.device, dtype=action.dtype)
        xt, target = self.flow.interpolate(x0, x1, t)
        sq_err = (self._velocity(scene, xt, t) - target) ** 2  # [B, H, D]

        valid = torch.ones_like(sq_err[..., 0])
        if self.config.mask_padded_actions and "action_is_pad" in batch:
            valid = (~batch["action_is_pad"]).to(sq_err.dtype)
        rot_end = 6 if isinstance(self.flow, SE3Flow) else 9
        terms = {
            "translation": sq_err[..., :3].mean(-1),
            "rotation": sq_err[..., 3:rot_end].mean(-1),
            "gripper": sq_err[..., rot_end:].mean(-1),
        }
        weights = {
            "translation": self.config.translation_loss_weight,
            "rotation": self.config.rotation_loss_weight,
            "gripper": self.config.gripper_loss_weight,
        }
        denom = valid.sum().clamp_min(1.0)
        losses = {k: (v * valid).sum() / denom for k, v in terms.items()}
        loss = sum(weights[k] * losses[k] for k in losses)
        return loss, {f"loss_{k}": v.item() for k, v in losses.items()}

    # ------------------------------------------------------------------ inference

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], noise=None, **kwargs) -> Tensor:
        """Sample a chunk ``[B, horizon, 10]`` with ``num_inference_steps`` Euler steps.

        ``noise`` (optional) is the initial flow state in the EEF frame: an ``SE3State`` for
        ``action_space="se3"``, a ``[B, H, 10]`` tensor for ``"euclidean"``; by default it is drawn from
        torch's global generator.
        """
        obs = self._check_and_stack(batch)
        frame, scene = self._encode(obs)
        b, device = obs[TOKEN_POSES].shape[0], obs[TOKEN_POSES].device
        x = noise if noise is not None else self.flow.noise(b, self.config.horizon, device=device)
        grid = time_grid(
            self.config.num_inference_steps,
            self.config.time_schedule,
            self.config.time_schedule_rate,
            device=device,
        )
        x = integrate(self.flow, lambda state, t: self._velocity(scene, state, t), x, grid)
        poses = self.flow.to_poses(x)
        rot, trans = frame.to_world(poses.rot, poses.trans)
        return torch.cat([g.rt_to_pose9(rot, trans), poses.extra.clamp(-1.0, 1.0)], dim=-1)

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """One action ``[B, 10]`` per call: a new chunk is sampled every ``n_action_steps`` calls."""
        for key in self.observation_keys:
            if key not in batch:
                self._check_and_stack(batch)  # raises the missing-key error
            queue = self._obs_queues[key]
            while len(queue) < queue.maxlen - 1:  # first call: fill the history with the current frame
                queue.append(batch[key])
            queue.append(batch[key])
        if not self._action_queue:
            history = {k: torch.stack(list(q), dim=1) for k, q in self._obs_queues.items()}
            start = self._clock()
            chunk = self.predict_action_chunk(history)
            self.last_chunk = chunk  # the whole generated chunk, world frame (for visualisation)
            skip = 0
            if self.config.latency_compensation:
                # Actions are due at 1 / control_fps intervals from the observation; keep at least one.
                elapsed = self._clock() - start
                skip = min(int(elapsed * self.config.control_fps), self.config.horizon - 1)
            self._action_queue.extend(chunk[:, skip : skip + self.config.n_action_steps].unbind(1))
        action = self._action_queue.popleft()
        if self.config.action_smoothing > 0 and self._last_action is not None:
            action = smooth_action(self._last_action, action, self.config.action_smoothing)
        self._last_action = action
        return action


def smooth_action(previous: Tensor, new: Tensor, alpha: float) -> Tensor:
    """Exponential smoothing ``alpha * previous + (1 - alpha) * new`` done on SE(3): translation and gripper
    linearly, rotation along the geodesic from the previous to the new orientation."""
    rot_prev, trans_prev = g.pose9_to_rt(previous[..., :POSE_DIM])
    rot_new, trans_new = g.pose9_to_rt(new[..., :POSE_DIM])
    rot = rot_prev @ g.so3_exp((1.0 - alpha) * g.so3_log(rot_prev.transpose(-1, -2) @ rot_new))
    trans = alpha * trans_prev + (1.0 - alpha) * trans_new
    gripper = alpha * previous[..., POSE_DIM:] + (1.0 - alpha) * new[..., POSE_DIM:]
    return torch.cat([g.rt_to_pose9(rot, trans), gripper], dim=-1)
