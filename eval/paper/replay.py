"""Replay baseline of the paper's light-bulb experiment: the recorded demonstrations' actions, replayed open
loop on the layouts they were recorded on, and the same shifted sideways by an offset.

    python -m eval.paper.replay --root outputs/paper/data/<dataset> --offset-mm 1.5 --out replay.json

The paper's real robot replayed its demonstrations with 8/10 success and 5/10 when they were 1.5 mm off,
which measures how much precision the task asks for. In simulation an unshifted replay is exact (the same
seed, the same actions), so it checks the recording; the shifted one moves every commanded position by the
offset along the world y axis (the bulb is in the hand from the start, so the insertion moves with it),
alternating the side from one episode to the next, as the Lightbulb tests do.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def episodes_actions(root: Path) -> list[np.ndarray]:
    """Each recorded episode's actions ``[T, 10]``, in episode order (read from the dataset's parquet files,
    without loading LeRobot)."""
    import pyarrow.parquet as pq

    files = sorted((root / "data").rglob("*.parquet"))
    if not files:
        raise FileNotFoundError(f"{root}/data holds no parquet file; is {root} a recorded dataset?")
    tables = [pq.read_table(f, columns=["episode_index", "frame_index", "action"]).to_pandas() for f in files]
    import pandas as pd

    frames = pd.concat(tables).sort_values(["episode_index", "frame_index"])
    return [np.stack(group["action"].to_numpy()) for _, group in frames.groupby("episode_index", sort=True)]


def replay_episode(env, seed: int, actions: np.ndarray) -> bool:
    """Reset ``env`` with ``seed`` and execute ``actions [T, 10]`` open loop (until they run out or the
    episode ends); whether the task was solved at any step."""
    from gym_actionflow.rollout import rollout

    queue = iter(actions)
    solved: list[bool] = []

    def note(obs: dict, reward: float, terminated: bool, truncated: bool, info: dict) -> None:
        solved.append(bool(info["is_success"]))

    rollout(env, lambda obs: next(queue), seed, after_step=note, max_steps=len(actions))
    return any(solved)


def replay_shifted(env, seeds: list[int], actions: list[np.ndarray], offset_mm: float) -> list[bool]:
    """Replay each episode's ``actions [T, 10]`` on ``env`` from its seed, every commanded position moved by
    ``offset_mm`` along the world y axis, to +y in even episodes and to -y in odd ones; whether each was
    solved. The one replay protocol: the dataset replay below and ``eval.diagnostics.lightbulb_fit`` (which
    replays expert episodes it simulates) both run it."""
    successes = []
    for i, (seed, episode) in enumerate(zip(seeds, actions, strict=True)):
        shifted = episode.copy()
        shifted[:, 1] += (1 if i % 2 == 0 else -1) * offset_mm / 1000
        successes.append(replay_episode(env, seed, shifted))
    return successes


def replay(root: Path, offset_mm: float) -> dict:
    from gym_actionflow.registry import make_env

    from lerobot_actionflow.tools.record.log import RecordingLog

    log = RecordingLog.load(root)
    if log is None:
        raise FileNotFoundError(f"{root} has no recording log; record it with actionflow-record first")
    recipe = log.recipe
    env = make_env(recipe["task"], recipe["variant"], **recipe.get("env_kwargs", {}))
    actions = episodes_actions(root)
    seeds = log.kept_seeds[: len(actions)]  # the finalized episodes are the first kept seeds, in order
    successes = replay_shifted(env, seeds, actions, offset_mm)
    env.close()
    return {"success": float(np.mean(successes)), "n": len(successes), "offset_mm": offset_mm, "seeds": seeds,
            "successes": successes}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--root", type=Path, required=True, help="a dataset recorded by actionflow-record")
    parser.add_argument("--offset-mm", type=float, default=0.0)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    result = replay(args.root, args.offset_mm)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"replay {args.offset_mm:g} mm off: {result['success']:.0%} of {result['n']}")


if __name__ == "__main__":
    main()
