"""Record one closed-loop rollout of a trained ActionFlow checkpoint as a rerun recording (``.rrd``).

    python -m lerobot_actionflow.tools.visualize outputs/train/.../pretrained_model --task Stack-v0 \\
        --seed 1000 --out rollout.rrd
    rerun rollout.rrd          # or: python -m rerun rollout.rrd

What is logged, on the timeline ``step`` (20 Hz control steps):
    ``world/scene/<token>``     every scene token's pose as coordinate axes, with its name;
    ``world/chunk``             each generated action chunk, as a path of its target positions + axes;
    ``world/eef_path``          the executed end-effector path so far;
    ``world/point_cloud``       the fixture point cloud, when the task has one;
    ``wrist``                   the wrist camera image, when the observation has one;
    ``gripper/*``, ``success``  gripper command and opening, and the task's success flag.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from lerobot_actionflow import schema

CHUNK_COLOR = (255, 140, 0)
PATH_COLOR = (40, 120, 255)


def _pose_rt(pose9: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), rotation (3, 3)) of a pose vector."""
    from gym_actionflow.geometry import pose9_to_rt

    rot, pos = pose9_to_rt(pose9)
    return pos, rot


def record_rollout(
    policy,
    preprocessor,
    postprocessor,
    env,
    seed: int,
    path: str | Path,
    token_names: list[str] | None = None,
) -> dict:
    """Run ``policy`` on ``env`` from ``reset(seed)`` until the episode ends; save everything to ``path``.

    Returns ``{"success": bool, "steps": int, "path": Path}``."""
    import rerun as rr

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream("actionflow_rollout")
    rec.save(str(path))
    names = token_names or ["eef", *env.unwrapped.entity_names]
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    policy.reset()
    obs, info = env.reset(seed=seed)
    eef_path: list[np.ndarray] = []
    logged_chunk = None
    steps, done = 0, False
    while not done:
        rec.set_time("step", sequence=steps)
        for i, pose in enumerate(obs["token_poses"]):
            pos, rot = _pose_rt(pose)
            rec.log(
                f"world/scene/{names[i]}",
                rr.Transform3D(translation=pos, mat3x3=rot),
                rr.TransformAxes3D(0.05),
            )
        rec.log(
            "world/scene/labels",
            rr.Points3D(obs["token_poses"][:, :3], labels=names, radii=0.004),
        )
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
            chunk = logged_chunk[0].cpu().numpy()
            rec.log(
                "world/chunk",
                rr.LineStrips3D([chunk[:, :3]], colors=CHUNK_COLOR, radii=0.003),
                rr.Points3D(chunk[:, :3], colors=CHUNK_COLOR, radii=0.005),
            )
        action = action[0].cpu().numpy()
        rec.log("gripper/command", rr.Scalars(float(action[9])))
        rec.log("gripper/opening", rr.Scalars(float(obs["agent_pos"][9])))
        obs, _, terminated, truncated, info = env.step(action)
        rec.log("success", rr.Scalars(float(info["is_success"])))
        steps += 1
        done = terminated or truncated
    rec.flush()
    rec.disconnect()
    return {"success": bool(info["is_success"]), "steps": steps, "path": path}


def main(argv: list[str] | None = None) -> None:
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
    args = parser.parse_args(argv)

    cfg = ActionFlowEnvConfig(task=args.task, variant=args.variant)
    policy = ActionFlowPolicy.from_pretrained(args.checkpoint)
    policy.eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(args.checkpoint))
    env = gym.make(f"gym_actionflow/{cfg.task}", **cfg.gym_kwargs)
    result = record_rollout(policy, pre, post, env, args.seed, args.out)
    env.close()
    outcome = "success" if result["success"] else "failure"
    print(f"{cfg.task} seed {args.seed}: {outcome} after {result['steps']} steps")
    print(f"Saved {result['path']}; open it with:  rerun {result['path']}")


if __name__ == "__main__":
    main()
