"""The main job: train ActionFlow with the real ``lerobot-train`` on a synthetic token dataset, then show
what it learned, on new scenes and on the same scenes rigidly moved (equivariance).

    python -m lerobot_actionflow.demo [--episodes 50] [--steps 800] [--output-dir outputs/demo]

Every step is a standard LeRobot tool: a LeRobotDataset on disk, ``lerobot-train --policy.type=actionflow``,
``ActionFlowPolicy.from_pretrained`` with the checkpoint's saved pre/post-processors.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import torch

from lerobot_actionflow import geometry as g
from lerobot_actionflow import synthetic as syn

REPO_ID = "local/actionflow_synthetic_reach"


def train(dataset_root: Path, out: Path, steps: int, batch_size: int, seed: int) -> Path:
    cmd = [
        str(Path(sys.executable).parent / "lerobot-train"),
        "--policy.type=actionflow",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        "--policy.optimizer_lr=2e-3",
        f"--dataset.repo_id={REPO_ID}",
        f"--dataset.root={dataset_root}",
        f"--steps={steps}",
        f"--batch_size={batch_size}",
        "--num_workers=2",
        f"--save_freq={steps}",
        f"--log_freq={max(steps // 15, 1)}",
        f"--seed={seed}",
        f"--output_dir={out}",
    ]
    print("$ " + " ".join(cmd), flush=True)
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    subprocess.run(cmd, check=True, env=env)
    return out / "checkpoints" / "last" / "pretrained_model"


def evaluate(ckpt: Path, scenes: int, seed: int) -> None:
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_actionflow import ActionFlowPolicy

    policy = ActionFlowPolicy.from_pretrained(ckpt)
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(ckpt))

    def act(obs):
        return post(policy.select_action(pre(obs)))

    scene = syn.sample_scenes(scenes, seed)
    # The same scenes, each moved by one random rigid transform (rotation about any axis, up to ~0.5 m).
    gen = torch.Generator().manual_seed(seed + 1)
    rot = g.random_rotation((), generator=gen, dtype=torch.float64)
    trans = torch.randn(3, generator=gen, dtype=torch.float64) * 0.3
    rows = []
    for name, sc in (
        ("new scenes", scene),
        ("same scenes, moved by a random SE(3)", scene.transformed(rot, trans)),
    ):
        policy.reset()
        torch.manual_seed(seed)
        res = syn.evaluate_closed_loop(act, sc)
        rows.append((name, res))
    print(
        "\nClosed-loop evaluation: reach the grasp pose (< 1 cm, < 0.05 rad) and close the gripper, 40 steps"
    )
    print(f"{'':40s} {'success':>8s} {'median trans err':>17s} {'median rot err':>15s}")
    for name, res in rows:
        print(
            f"{name:40s} {res.success.float().mean().item():8.0%} "
            f"{res.trans_error.median().item() * 1000:14.1f} mm {res.rot_error.median().item():11.3f} rad"
        )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--output-dir", type=Path, default=Path("outputs/demo"))
    parser.add_argument("--episodes", type=int, default=50, help="expert episodes in the training dataset")
    parser.add_argument("--steps", type=int, default=800, help="lerobot-train optimisation steps")
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--eval-scenes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=1000)
    args = parser.parse_args()

    start = time.time()
    if args.output_dir.exists():
        shutil.rmtree(args.output_dir)
    dataset_root = args.output_dir / "dataset"
    print(
        f"Recording {args.episodes} expert episodes of the synthetic reach task -> {dataset_root}", flush=True
    )
    syn.write_dataset(dataset_root, REPO_ID, episodes=args.episodes, steps=30, seed=0)
    ckpt = train(dataset_root, args.output_dir / "train", args.steps, args.batch_size, seed=args.seed)
    evaluate(ckpt, args.eval_scenes, seed=args.seed)
    print(f"\nCheckpoint: {ckpt}\nTotal time: {time.time() - start:.0f} s")


if __name__ == "__main__":
    main()
