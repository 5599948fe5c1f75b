"""Watch a task: run its scripted expert and save a video of the front camera.

    python -m gym_actionflow StackThree --variant D1 --episodes 3 --video stack_three.gif

Prints each episode's outcome and length; ``--video`` writes the frames (GIF, or MP4 when imageio's ffmpeg
plugin is installed).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import numpy as np

import gym_actionflow


def main(argv: list[str] | None = None) -> None:
    names = [task.name for task in gym_actionflow.TASKS]
    parser = argparse.ArgumentParser(
        prog="python -m gym_actionflow",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("task", choices=names)
    parser.add_argument(
        "--variant", default=None, help="initial-state distribution, e.g. D0, D1 (MugHanging: train or test)"
    )
    parser.add_argument("--episodes", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0, help="first seed; episode i uses seed + i")
    parser.add_argument("--noise", type=float, default=0.0, help="expert noise (0: deterministic)")
    parser.add_argument("--video", type=Path, default=None, help="output .gif or .mp4 of the front camera")
    parser.add_argument("--fps", type=int, default=20)
    args = parser.parse_args(argv)
    if args.video is not None and args.video.suffix not in (".gif", ".mp4"):
        parser.error(f"--video {args.video}: expected a .gif or .mp4 file name")
    if args.video is not None and args.video.suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            parser.error("--video *.mp4 needs `pip install imageio-ffmpeg`; or write a .gif instead")

    task = gym_actionflow.find_task(args.task)
    try:
        kwargs = task.kwargs(args.variant)
    except ValueError as err:
        parser.error(f"--{err}")
    env = gym.make(task.env_id, **kwargs)
    expert = gym_actionflow.make_expert(env, noise=args.noise, seed=args.seed)
    frames: list[np.ndarray] = []
    on_frame = frames.append if args.video is not None else None
    for i in range(args.episodes):
        episode = gym_actionflow.run_episode(env, expert, args.seed + i, on_frame=on_frame)
        outcome = "success" if episode.success else "failure"
        print(f"{task.env_id} seed {args.seed + i}: {outcome} after {episode.steps} steps")
    if args.video is not None:
        import imageio.v2 as imageio

        args.video.parent.mkdir(parents=True, exist_ok=True)
        if args.video.suffix == ".gif":
            imageio.mimsave(args.video, frames, duration=1000 / args.fps, loop=0)
        else:
            imageio.mimsave(args.video, frames, fps=args.fps)
        print(f"wrote {len(frames)} frames to {args.video}")
    env.close()


if __name__ == "__main__":
    main()
