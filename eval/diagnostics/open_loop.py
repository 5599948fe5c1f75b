"""Open-loop error of a trained policy on held-out expert demonstrations.

    actionflow-record --task MugHanging --variant train --episodes 10 --seed 5000 --env-kwarg mug_yaw=slight \
        --repo-id local/mug_heldout --root outputs/heldout/mug_hanging
    python -m eval.diagnostics.open_loop outputs/train/<run>/checkpoints/last/pretrained_model \
        --root outputs/heldout/mug_hanging
    python -m eval.diagnostics.open_loop <diffusion checkpoint> --root outputs/heldout/coffee \
        --set noise_scheduler_type=DDIM --set num_inference_steps=100

The demonstrations are a LeRobotDataset recorded by ``actionflow-record`` from seeds the policy was not
trained on (``--seed 5000`` above; trainings record from 0), read through LeRobot's ``LeRobotDataset`` with
the policy's own observation history (its delta timestamps), exactly as ``lerobot-train`` reads its data.
The checkpoint is an ActionFlow policy or any other LeRobot policy saved by ``lerobot-train`` (Diffusion
Policy...), which reads the demonstrations through its own saved pre- and post-processors (normalisation)
and is compared on the actions it returns (Diffusion Policy: its ``n_action_steps``, from the current frame
on).

For every frame of the first ``--episodes`` episodes, the policy samples a chunk from the demonstration's own
observation history and it is compared with the demonstration's next actions: the median position error of
chunk steps 0, 3 and 7, the median rotation error of steps 7 and 15 (and how often step 15 is off by over 20
degrees), the spread of the samples over ``--samples`` noise draws, and how often the gripper command has the
wrong sign. Rows: all frames, the 12 frames before the expert first closes the gripper (the grasp), the carry
(from the grasp to 12 frames before the release, where MugHanging turns the mug) and the 12 before it opens
it again (a release). This separates a policy that cannot fit its data (large errors here) from one that
drifts in closed loop (small errors here, failures in ``lerobot-eval``).
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from lerobot_actionflow import ActionFlowPolicy, schema
from lerobot_actionflow.core import geometry
from lerobot_actionflow.tools.visualize import load_dataset

if TYPE_CHECKING:
    from lerobot.configs.policies import PreTrainedConfig

Predict = Callable[[dict], torch.Tensor]


def parse_value(text: str) -> int | float | bool | str:
    """A ``--set`` value as the field needs it: an int, a float, ``true`` / ``false``, or the text itself."""
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def parse_settings(items: Sequence[str]) -> dict[str, str]:
    """``["FIELD=VALUE", ...]`` (repeated ``--set``) as ``{field: value text}``; anything else is refused."""
    bad = [item for item in items if "=" not in item]
    if bad:
        raise SystemExit(f"--set {bad[0]!r}: expected FIELD=VALUE")
    return dict(item.split("=", 1) for item in items)


def override(config, settings: dict[str, str]):
    """``config`` with evaluation-time fields replaced, as ``lerobot-eval --policy.FIELD=VALUE`` does (e.g.
    ``noise_scheduler_type=DDIM``, ``num_inference_steps=10``, ``clip_sample=false``); values are read by
    :func:`parse_value`, and an unknown field, or a value of the wrong kind for a boolean or numeric field,
    is refused by name."""
    fields = {f.name for f in dataclasses.fields(config)}
    changes = {}
    for name, text in settings.items():
        if name not in fields:
            raise SystemExit(f"--set {name}={text}: {type(config).__name__} has no field {name!r}")
        value, current = parse_value(text), getattr(config, name)
        if isinstance(current, bool) and not isinstance(value, bool):
            raise SystemExit(f"--set {name}={text}: expected true or false")
        elif isinstance(current, int | float) and not isinstance(value, int | float):
            raise SystemExit(f"--set {name}={text}: expected a number")
        changes[name] = value
    return dataclasses.replace(config, **changes) if changes else config


def respace(policy, spacing: str) -> None:
    """Rebuild a Diffusion Policy's noise scheduler with diffusers' ``timestep_spacing`` (``leading``, the
    default: K steps from t = 100 - 100/K; ``trailing``: from t = 99, the noisiest; ``linspace``), its other
    settings kept. LeRobot's config has no such field; this tells a sampler's step count from where it
    starts."""
    scheduler = getattr(getattr(policy, "diffusion", None), "noise_scheduler", None)
    if scheduler is None:
        raise SystemExit(f"--timestep-spacing: a {type(policy).__name__} has no diffusion noise scheduler")
    policy.diffusion.noise_scheduler = type(scheduler).from_config(scheduler.config, timestep_spacing=spacing)


@dataclasses.dataclass(frozen=True)
class LoadedPolicy:
    config: PreTrainedConfig
    """The policy's config after the overrides (its delta timestamps say which history it reads)."""
    horizon: int
    """Actions per returned chunk, from the current frame on."""
    predict: Predict


def load_policy(
    checkpoint: Path, settings: dict[str, str] | None = None, spacing: str | None = None
) -> LoadedPolicy:
    """A saved policy whose ``predict(batch)`` maps raw demonstration observations ``{key: [B, n_obs, ...]}``
    to a chunk of raw actions ``[B, horizon, 10]``, starting at the current frame. ActionFlow reads its raw
    token poses; another LeRobot policy goes through its saved processors. ``settings`` overrides config
    fields first (``override``), as lerobot-eval's ``--policy.*`` flags; ``spacing`` sets a diffusion
    sampler's timestep spacing (``respace``)."""
    from lerobot.configs.policies import PreTrainedConfig

    config = override(PreTrainedConfig.from_pretrained(checkpoint), settings or {})
    if config.type == "actionflow":
        if spacing is not None:
            raise SystemExit("--timestep-spacing: an ActionFlow policy has no diffusion noise scheduler")
        policy = ActionFlowPolicy.from_pretrained(checkpoint, config=config).eval()
        return LoadedPolicy(policy.config, policy.config.horizon, policy.predict_action_chunk)
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    policy = get_policy_class(config.type).from_pretrained(checkpoint, config=config).eval()
    if spacing is not None:
        respace(policy, spacing)
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    keys = set(policy.config.input_features)

    def predict(batch: dict) -> torch.Tensor:
        missing = keys - set(batch)
        if missing:
            raise KeyError(f"the demonstrations lack {sorted(missing)}, which {checkpoint} reads")
        policy.reset()  # empty observation queues: predict_action_chunk reads the batch's own history
        return post(policy.predict_action_chunk(pre({k: batch[k] for k in keys})))

    return LoadedPolicy(policy.config, policy.config.n_action_steps, predict)


@dataclasses.dataclass(frozen=True)
class Demonstrations:
    """Every frame of some recorded episodes, as the policy reads them."""

    observations: dict[str, torch.Tensor]
    """Observation key -> ``[n, n_obs, ...]``: each frame's history, padded at its episode's start."""
    actions: torch.Tensor
    """``[n, horizon, 10]``: the demonstration's actions from each frame on (the last one repeated past the
    episode's end)."""
    episode: np.ndarray
    """``[n]`` the episode of each frame."""

    @property
    def gripper(self) -> np.ndarray:
        """``[n]`` the gripper command of each frame."""
        return self.actions[:, 0, schema.POSE_DIM].numpy()


def demonstrations(
    config: PreTrainedConfig, root: Path, repo_id: str, horizon: int, episodes: int | None = None
) -> Demonstrations:
    """The first ``episodes`` episodes (all if None) of the LeRobotDataset at ``root``, with the history
    ``config`` reads and ``horizon`` actions from each frame on."""
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    total = LeRobotDatasetMetadata(repo_id, root=root).total_episodes
    chosen = list(range(min(episodes, total))) if episodes is not None else None
    dataset = load_dataset(config, root, repo_id, episodes=chosen, action_steps=horizon)
    loader = torch.utils.data.DataLoader(dataset, batch_size=64, shuffle=False, num_workers=0)
    parts: dict[str, list[torch.Tensor]] = {}
    for batch in loader:
        for key, value in batch.items():
            if isinstance(value, torch.Tensor):
                parts.setdefault(key, []).append(value)
    data = {key: torch.cat(values) for key, values in parts.items()}
    observations = {k: v for k, v in data.items() if k.startswith("observation.") and "_is_pad" not in k}
    return Demonstrations(observations, data[schema.ACTION], data["episode_index"].numpy())


def phases(demo: Demonstrations) -> dict[str, np.ndarray]:
    """Frame masks: all, the 12 frames before each episode's first close, the carry, the 12 before the next
    open."""
    grip, episode = demo.gripper, demo.episode
    grasp, carry, release = (np.zeros(len(grip), bool) for _ in range(3))
    for e in np.unique(episode):
        idx = np.where(episode == e)[0]
        g = grip[idx]
        close = int(np.argmax(g > 0))
        opened = close + int(np.argmax(g[close:] < 0)) if np.any(g[close:] < 0) else len(g)
        grasp[idx[max(close - 12, 0) : close]] = True
        carry[idx[close : max(opened - 12, close)]] = True
        release[idx[max(opened - 12, 0) : opened]] = True
    return {"all frames": np.ones(len(grip), bool), "12 before grasp": grasp, "carry": carry,
            "12 before release": release}


@torch.no_grad()
def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--root", type=Path, required=True,
                   help="a LeRobotDataset of held-out demonstrations (actionflow-record --root)")
    p.add_argument("--repo-id", help="the dataset's repo id (default: local/<root folder name>)")
    p.add_argument("--episodes", type=int, default=10, help="the first N episodes of the dataset")
    p.add_argument("--samples", type=int, default=4)
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", dest="settings",
                   help="override a policy config field first, e.g. noise_scheduler_type=DDIM "
                   "num_inference_steps=10 (repeatable)")
    p.add_argument("--timestep-spacing", choices=("leading", "trailing", "linspace"),
                   help="Diffusion Policy only: where its K sampling steps sit among the 100 trained ones "
                   "(default: as saved, diffusers' leading)")
    args = p.parse_args(argv)

    torch.set_num_threads(1)
    if not (args.root / "meta" / "info.json").is_file():
        raise SystemExit(f"--root {args.root}: no LeRobotDataset there (meta/info.json); record one with "
                         "actionflow-record --root")
    loaded = load_policy(args.checkpoint, parse_settings(args.settings), args.timestep_spacing)
    horizon = loaded.horizon
    if horizon < 8:
        raise SystemExit(f"{args.checkpoint} returns {horizon} actions per chunk; the table reads steps 0-7")
    repo_id = args.repo_id or f"local/{args.root.name}"
    demo = demonstrations(loaded.config, args.root, repo_id, horizon, args.episodes)
    chunks = []
    for s in range(args.samples):
        torch.manual_seed(s)
        chunks.append(loaded.predict(demo.observations))
    chunks = torch.stack(chunks)  # [S, n, H, 10]
    expert = demo.actions
    trans_err, rot_err = geometry.pose9_errors(chunks[0, ..., :9], expert[..., :9])  # [n, H] m, rad
    err = trans_err.numpy() * 1000  # mm
    spread = (chunks[..., :3] - chunks[..., :3].mean(0)).norm(dim=-1).mean(0).numpy() * 1000
    wrong = (chunks[0, ..., 9].sign() != expert[..., 9].sign()).numpy()
    rot_err = np.degrees(rot_err.numpy())
    n_episodes = len(np.unique(demo.episode))
    print(f"{args.checkpoint}: {n_episodes} demonstrations of {repo_id} ({args.root})")
    last = horizon - 1  # ActionFlow's chunk: step 15; Diffusion Policy's executed actions: step 7
    print(f"| frames | n | error step 0 / 3 / 7 (mm) | rotation error step 7 / {last} (deg) "
          f"| rotation step {last} > 20 deg | sample spread step 0 / 7 (mm) | gripper wrong 0-7 |")
    print("|---|---|---|---|---|---|---|")
    for name, mask in phases(demo).items():
        e, sp, r = (np.median(x[mask], axis=0) for x in (err, spread, rot_err))
        far = (rot_err[mask, last] > 20).mean()
        print(f"| {name} | {mask.sum()} | {e[0]:.1f} / {e[3]:.1f} / {e[7]:.1f} | {r[7]:.1f} / {r[last]:.1f} "
              f"| {far:.1%} | {sp[0]:.1f} / {sp[7]:.1f} | {wrong[mask, :8].mean():.1%} |")


if __name__ == "__main__":
    main()
