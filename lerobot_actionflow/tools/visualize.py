"""Rerun recordings (``.rrd``) of a trained ActionFlow checkpoint: a closed-loop rollout, or how the flow
turns noise into the action chunk for one dataset frame.

    python -m lerobot_actionflow.tools.visualize outputs/train/.../pretrained_model --task Stack-v0 \\
        --seed 1000 --out rollout.rrd
    python -m lerobot_actionflow.tools.visualize flow outputs/train/.../pretrained_model \\
        --root datasets/stack --frame 123 --out flow.rrd
    rerun rollout.rrd          # or: python -m rerun rollout.rrd

The rollout, on the timeline ``step`` (20 Hz control steps):
    ``world/scene/<token>``     every scene token's pose as coordinate axes, with its name;
    ``world/chunk``             each generated action chunk, as a path of its target positions;
    ``world/flow/step_<k>``     the chunk after Euler step k (k = 0: the noise, k = K: the chunk), see below;
    ``world/eef_path``          the executed end-effector path so far;
    ``world/point_cloud``       the fixture point cloud, when the task has one;
    ``wrist``                   the wrist camera image, when the observation has one;
    ``gripper/*``, ``success``  gripper command and opening, and the task's success flag.

``flow`` (no environment): one frame of a LeRobotDataset, with the observation history the policy reads, on
the timeline ``frame``: the scene tokens at that frame, ``world/expert`` (the recorded actions from the frame
on, the chunk the policy was trained to produce), ``world/chunk`` and ``world/flow/step_<k>``.

Flow steps are also on the timeline ``flow_t`` (the flow time t_k of step k, 0 to 1, shown as seconds): each
is a path of the chunk's positions, grey at the noise turning orange at the chunk, with the points coloured
by the gripper command (blue open, red closed) and each action's orientation as small axes (x red, y green,
z blue). Scrub ``flow_t`` to watch the sampler carry the noise to the chunk.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from lerobot_actionflow import schema
from lerobot_actionflow.core import geometry as g

CHUNK_COLOR = (255, 140, 0)
PATH_COLOR = (40, 120, 255)
EXPERT_COLOR = (200, 60, 200)
NOISE_COLOR = (150, 150, 150)
GRIPPER_OPEN_COLOR = (60, 160, 255)
GRIPPER_CLOSED_COLOR = (230, 30, 30)
AXIS_COLORS = ((230, 30, 30), (30, 200, 30), (30, 80, 230))
FLOW_AXES_LENGTH = 0.015  # m


def _pose_rt(pose9: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), rotation (3, 3)) of a pose vector."""
    from gym_actionflow.geometry import pose9_to_rt

    rot, pos = pose9_to_rt(pose9)
    return pos, rot


def _blend(a: tuple[int, int, int], b: tuple[int, int, int], w: np.ndarray | float) -> np.ndarray:
    """Colours from ``a`` (w = 0) to ``b`` (w = 1), ``[*, 3]`` uint8."""
    w = np.clip(np.asarray(w, dtype=np.float64), 0.0, 1.0)[..., None]
    return ((1 - w) * np.asarray(a) + w * np.asarray(b)).round().astype(np.uint8)


def _log_scene(rec, poses: np.ndarray, names: list[str]) -> None:
    """Token poses ``(N, 9)`` as named coordinate axes under ``world/scene``."""
    import rerun as rr

    for i, pose in enumerate(poses):
        pos, rot = _pose_rt(pose)
        rec.log(
            f"world/scene/{names[i]}", rr.Transform3D(translation=pos, mat3x3=rot), rr.TransformAxes3D(0.05)
        )
    rec.log("world/scene/labels", rr.Points3D(poses[:, :3], labels=names, radii=0.004))


def _log_path(rec, entity: str, actions: np.ndarray, color: tuple[int, int, int]) -> None:
    """Actions ``(H, 10)`` as a path through their target positions."""
    import rerun as rr

    rec.log(
        entity,
        rr.LineStrips3D([actions[:, :3]], colors=color, radii=0.003),
        rr.Points3D(actions[:, :3], colors=color, radii=0.005),
    )


def log_flow(rec, flow, index: int = 0, axes_length: float = FLOW_AXES_LENGTH) -> None:
    """Log every Euler step of one chunk's sampling as ``world/flow/step_<k>``, at ``flow_t = t_k``.

    ``flow`` is a :class:`~lerobot_actionflow.modeling_actionflow.FlowTrajectory` (``times [K + 1]``,
    ``actions [K + 1, B, H, 10]``, world frame); ``index`` picks the batch element. Each step is a path of
    the H target positions, its points coloured by the gripper command and small axes for the orientations.
    Other entities logged after this call are not on the ``flow_t`` timeline.
    """
    import rerun as rr

    actions = flow.actions[:, index].detach().cpu().double()  # [K + 1, H, 10]
    rot, pos = g.pose9_to_rt(actions[..., : schema.POSE_DIM])  # [K + 1, H, 3, 3], [K + 1, H, 3]
    rot, pos = rot.numpy(), pos.numpy()
    gripper = actions[..., schema.POSE_DIM].numpy()  # [K + 1, H]
    times = flow.times.detach().cpu().double().numpy()
    horizon = pos.shape[1]
    axis_colors = np.tile(np.asarray(AXIS_COLORS, dtype=np.uint8), (horizon, 1))  # [H * 3, 3]
    for k, t in enumerate(times):
        rec.set_time("flow_t", duration=float(t))
        color = tuple(int(c) for c in _blend(NOISE_COLOR, CHUNK_COLOR, float(t)))
        rec.log(
            f"world/flow/step_{k}",
            rr.LineStrips3D([pos[k]], colors=color, radii=0.0015),
            rr.Points3D(
                pos[k],
                colors=_blend(GRIPPER_OPEN_COLOR, GRIPPER_CLOSED_COLOR, (gripper[k] + 1) / 2),
                radii=0.003,
            ),
            rr.Arrows3D(
                origins=np.repeat(pos[k], 3, axis=0),
                vectors=axes_length * rot[k].transpose(0, 2, 1).reshape(-1, 3),  # the columns: x, y, z axes
                colors=axis_colors,
                radii=0.0008,
            ),
        )
    rec.disable_timeline("flow_t")


def record_rollout(
    policy,
    preprocessor,
    postprocessor,
    env,
    seed: int,
    path: str | Path,
    token_names: list[str] | None = None,
    flow: bool = True,
) -> dict:
    """Run ``policy`` on ``env`` from ``reset(seed)`` until the episode ends
    (:func:`gym_actionflow.rollout.rollout`); save everything to ``path``.

    ``flow``: log every Euler step of each generated chunk (``world/flow/step_<k>``, see :func:`log_flow`);
    the policy's actions are the same either way.

    Returns ``{"success": bool, "steps": int, "path": Path}``."""
    import rerun as rr
    from gym_actionflow.rollout import rollout

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream("actionflow_rollout")
    rec.save(str(path))
    names = token_names or ["eef", *env.unwrapped.entity_names]
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    eef_path: list[np.ndarray] = []
    logged_chunk = None

    def act(obs: dict) -> np.ndarray:
        """Log the scene at this step, then the policy's action and any chunk it generated for it."""
        nonlocal logged_chunk
        rec.set_time("step", sequence=len(eef_path))
        _log_scene(rec, obs["token_poses"], names)
        eef_path.append(obs["token_poses"][0, :3].copy())
        if len(eef_path) > 1:
            rec.log("world/eef_path", rr.LineStrips3D([np.array(eef_path)], colors=PATH_COLOR, radii=0.002))
        if "point_cloud" in obs:
            rec.log("world/point_cloud", rr.Points3D(obs["point_cloud"], radii=0.002, colors=(120, 120, 120)))
        if "pixels" in obs:
            for cam, image in obs["pixels"].items():
                rec.log(cam, rr.Image(image))

        batch = preprocessor(schema.policy_batch(obs))
        with torch.inference_mode():
            action = postprocessor(policy.select_action(batch))
        if policy.last_chunk is not None and policy.last_chunk is not logged_chunk:
            logged_chunk = policy.last_chunk  # a new chunk was generated at this step
            _log_path(rec, "world/chunk", logged_chunk[0].cpu().numpy(), CHUNK_COLOR)
            if flow:
                log_flow(rec, policy.last_flow)
        action = action[0].cpu().numpy()
        rec.log("gripper/command", rr.Scalars(float(action[9])))
        rec.log("gripper/opening", rr.Scalars(float(obs["agent_pos"][9])))
        return action

    def stepped(obs: dict, reward: float, terminated: bool, truncated: bool, info: dict) -> None:
        rec.log("success", rr.Scalars(float(info["is_success"])))

    record_flow = policy.record_flow
    policy.record_flow = flow
    try:
        policy.reset()
        episode = rollout(env, act, seed, after_step=stepped)
    finally:
        policy.record_flow = record_flow
        rec.flush()
        rec.disconnect()
    return {"success": episode.success, "steps": episode.steps, "path": path}


def load_dataset(
    config, root: str | Path, repo_id: str, episodes: list[int] | None = None, action_steps: int | None = None
):
    """The LeRobotDataset at ``root`` with the windows ``config`` (a LeRobot policy config) trains on: each
    frame holds ``n_obs_steps`` of observation history and ``horizon`` actions, padded at episode ends (as
    ``lerobot-train`` loads it). ``episodes`` keeps only those episodes; ``action_steps`` makes the action
    window that many actions from the frame on instead (what an evaluation compares a chunk with)."""
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata

    meta = LeRobotDatasetMetadata(repo_id, root=root)
    deltas = resolve_delta_timestamps(config, meta) or {}
    if action_steps is not None:
        deltas[schema.ACTION] = [i / meta.fps for i in range(action_steps)]
    return LeRobotDataset(repo_id, root=root, episodes=episodes, delta_timestamps=deltas or None)


def record_dataset_flow(
    policy,
    preprocessor,
    dataset,
    frame: int,
    path: str | Path,
    seed: int = 0,
    token_names: list[str] | None = None,
) -> dict:
    """Sample one chunk for ``dataset[frame]`` with every Euler step kept, and save it to ``path`` with the
    scene and the expert's recorded actions. ``dataset`` must hold the policy's windows (see
    :func:`load_dataset`); the noise is drawn after ``torch.manual_seed(seed)``.

    Returns ``{"path": Path, "steps": K, "position_error": m}``, the last the mean distance between the
    sampled chunk's and the expert's target positions (over the expert's real, unpadded actions)."""
    import rerun as rr

    n = len(dataset)
    if not 0 <= frame < n:
        raise IndexError(
            f"frame {frame} is out of range: the dataset {dataset.repo_id} has {n} frames; expected "
            f"0 <= frame <= {n - 1}"
        )
    item = dataset[frame]
    missing = [k for k in (*policy.observation_keys, schema.ACTION) if k not in item]
    if missing:
        raise ValueError(
            f"the dataset {dataset.repo_id} has no {missing}; this policy reads "
            f"{list(policy.observation_keys)} and the comparison needs {schema.ACTION!r}"
        )
    batch = preprocessor({k: item[k].unsqueeze(0) for k in policy.observation_keys})  # [1, T, ...]
    torch.manual_seed(seed)
    flow = policy.sample_trajectory(batch)
    chunk = flow.actions[-1, 0].cpu().numpy()  # [H, 10]
    expert = item[schema.ACTION]
    if "action_is_pad" in item:
        expert = expert[~item["action_is_pad"]]
    expert = expert.numpy()  # [<= H, 10]

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream("actionflow_flow")
    rec.save(str(path))
    try:
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.set_time("frame", sequence=frame)
        poses = item[schema.TOKEN_POSES][-1].numpy()  # [N, 9], the current step of the history
        names = token_names or ["eef", *(f"token_{i}" for i in range(1, len(poses)))]
        _log_scene(rec, poses, names)
        if schema.POINT_CLOUD in item:
            points = item[schema.POINT_CLOUD][-1].numpy()
            rec.log("world/point_cloud", rr.Points3D(points, radii=0.002, colors=(120, 120, 120)))
        for key in policy.model.image_keys:
            image = item[key][-1].permute(1, 2, 0).numpy()  # [C, H, W] float in [0, 1] -> [H, W, C]
            rec.log(key.rsplit(".", 1)[-1], rr.Image((image * 255).round().clip(0, 255).astype(np.uint8)))
        _log_path(rec, "world/expert", expert, EXPERT_COLOR)
        _log_path(rec, "world/chunk", chunk, CHUNK_COLOR)
        log_flow(rec, flow)
    finally:
        rec.flush()
        rec.disconnect()
    error = float(np.linalg.norm(chunk[: len(expert), :3] - expert[:, :3], axis=-1).mean())
    return {"path": path, "steps": len(flow.times) - 1, "position_error": error}


def _checkpoint_arg(parser: argparse.ArgumentParser, path: Path) -> None:
    if not (path / "config.json").is_file():
        what = "has no config.json" if path.is_dir() else "does not exist"
        parser.error(
            f"checkpoint {path} {what}; expected a pretrained_model directory (config.json, "
            "model.safetensors), e.g. outputs/train/<run>/checkpoints/last/pretrained_model"
        )


def flow_main(argv: list[str] | None = None) -> None:
    """``python -m lerobot_actionflow.tools.visualize flow ...``: the flow of one dataset frame."""
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_actionflow import ActionFlowPolicy

    parser = argparse.ArgumentParser(
        prog="python -m lerobot_actionflow.tools.visualize flow",
        description="Record how the flow carries noise to the action chunk for one LeRobotDataset frame, "
        "with the expert's recorded actions to compare (see the module docstring).",
    )
    parser.add_argument("checkpoint", type=Path, help="a pretrained_model directory")
    parser.add_argument("--root", type=Path, required=True, help="the LeRobotDataset directory")
    parser.add_argument("--repo-id", help="the dataset's repo id (default: local/<root folder name>)")
    parser.add_argument("--frame", type=int, required=True, help="global frame index in the dataset")
    parser.add_argument("--seed", type=int, default=0, help="torch seed of the noise")
    parser.add_argument("--out", type=Path, default=Path("outputs/flow.rrd"))
    args = parser.parse_args(argv)

    _checkpoint_arg(parser, args.checkpoint)
    if not (args.root / "meta" / "info.json").is_file():
        what = "has no meta/info.json" if args.root.is_dir() else "does not exist"
        parser.error(
            f"dataset root {args.root} {what}; expected a LeRobotDataset directory (meta/info.json, data/), "
            "as written by actionflow-record --root"
        )
    repo_id = args.repo_id or f"local/{args.root.name}"
    policy = ActionFlowPolicy.from_pretrained(args.checkpoint)
    policy.eval()
    pre, _ = make_pre_post_processors(policy.config, pretrained_path=str(args.checkpoint))
    dataset = load_dataset(policy.config, args.root, repo_id)
    try:
        result = record_dataset_flow(policy, pre, dataset, args.frame, args.out, seed=args.seed)
    except IndexError as e:
        parser.error(str(e))
    print(
        f"{repo_id} frame {args.frame}: {result['steps']} Euler steps; the chunk's target positions are "
        f"{result['position_error'] * 1000:.1f} mm from the expert's on average"
    )
    print(f"Saved {result['path']}; open it with:  rerun {result['path']}")


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["flow"]:
        flow_main(argv[1:])
        return

    import gymnasium as gym
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_actionflow import ActionFlowPolicy
    from lerobot_actionflow.env_config import ActionFlowEnvConfig

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("checkpoint", type=Path, help="a pretrained_model directory")
    parser.add_argument("--task", default="Stack-v0")
    parser.add_argument("--variant", default=None)
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--out", type=Path, default=Path("outputs/rollout.rrd"))
    parser.add_argument("--no-flow", action="store_true", help="leave out the Euler steps of each chunk")
    args = parser.parse_args(argv)

    _checkpoint_arg(parser, args.checkpoint)
    cfg = ActionFlowEnvConfig(task=args.task, variant=args.variant)
    policy = ActionFlowPolicy.from_pretrained(args.checkpoint)
    policy.eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(args.checkpoint))
    env = gym.make(f"gym_actionflow/{cfg.task}", **cfg.gym_kwargs)
    result = record_rollout(policy, pre, post, env, args.seed, args.out, flow=not args.no_flow)
    env.close()
    outcome = "success" if result["success"] else "failure"
    print(f"{cfg.task} seed {args.seed}: {outcome} after {result['steps']} steps")
    print(f"Saved {result['path']}; open it with:  rerun {result['path']}")


if __name__ == "__main__":
    main()
