"""What a camera saw through a recorded episode: evenly spaced frames side by side in one PNG.

    python -m eval.diagnostics.camera_view --root outputs/lb_rgb/dataset --camera wrist --episode 0 \\
        --frames 10 --scale 2 --out eval/results/lightbulb_wrist_view.png

Reads any LeRobotDataset with ``observation.images.<camera>`` (PNG frames or video) and writes the episode's
frames ``0, ..., last`` at ``--frames`` even steps, left to right, each enlarged ``--scale`` times with no
smoothing so that the pixels the policy sees stay visible. Prints the frame indices it took.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def episode_frames(root: Path, camera: str, episode: int, count: int) -> tuple[list[int], list[np.ndarray]]:
    """``count`` evenly spaced frames (HWC uint8) of ``episode`` from ``observation.images.<camera>``, and
    their frame indices."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = LeRobotDataset(f"local/{root.name}", root=root, episodes=[episode])
    key = f"observation.images.{camera}"
    if key not in dataset.meta.features:
        cams = sorted(k.rsplit(".", 1)[1] for k in dataset.meta.camera_keys)
        raise SystemExit(f"--camera {camera!r}: {root} has no {key}; its cameras: {cams}")
    n = len(dataset)
    picks = np.linspace(0, n - 1, min(count, n)).round().astype(int).tolist()
    frames = []
    for i in picks:
        image = dataset[i][key]  # (3, H, W) float in [0, 1]
        frames.append((image.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8))
    return picks, frames


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--root", type=Path, required=True, help="the LeRobotDataset's folder")
    parser.add_argument("--camera", default="wrist", help="the <cam> of observation.images.<cam>")
    parser.add_argument("--episode", type=int, default=0)
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--scale", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("outputs/bench/camera_view.png"))
    args = parser.parse_args(argv)
    if args.frames < 1 or args.scale < 1:
        parser.error(f"--frames {args.frames}, --scale {args.scale}: expected positive integers")
    from PIL import Image

    picks, frames = episode_frames(args.root, args.camera, args.episode, args.frames)
    strip = np.concatenate(frames, axis=1).repeat(args.scale, axis=0).repeat(args.scale, axis=1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(strip).save(args.out)
    print(f"wrote {args.out}: episode {args.episode}, frames {picks}")


if __name__ == "__main__":
    main()
