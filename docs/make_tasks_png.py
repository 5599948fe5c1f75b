"""Make docs/tasks.png, the README's picture of the suite: every registered task's starting scene.

    python docs/make_tasks_png.py [--seed 1] [--output docs/tasks.png]

One tile per task (``env.render()``, the front camera) in registry order, four per row. Each task is shown in
its last, widest variant (D2 for the MimicGen tasks that have one), so the picture shows the hardest starting
layouts; MugHanging in its ``test`` layout, where the hanger moves.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gym_actionflow
import gymnasium as gym
import numpy as np
from PIL import Image

VARIANT = {"MugHanging": "test"}
"""Tasks shown in another variant than their last."""
COLUMNS = 4


def task_tiles(seed: int) -> list[np.ndarray]:
    """The starting scene of each registered task, (H, W, 3) uint8 each."""
    tiles = []
    for task in gym_actionflow.TASKS:
        env = gym.make(task.env_id, **task.kwargs(VARIANT.get(task.name, task.variants[-1])))
        env.reset(seed=seed)
        tiles.append(env.render())
        env.close()
    return tiles


def grid(tiles: list[np.ndarray], columns: int = COLUMNS) -> np.ndarray:
    """Tiles in rows of ``columns``, the last row padded with white."""
    blank = np.full_like(tiles[0], 255)
    rows = -(-len(tiles) // columns)
    padded = tiles + [blank] * (rows * columns - len(tiles))
    lines = [np.concatenate(padded[r * columns : (r + 1) * columns], axis=1) for r in range(rows)]
    return np.concatenate(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--output", type=Path, default=Path(__file__).with_name("tasks.png"))
    args = parser.parse_args(argv)
    Image.fromarray(grid(task_tiles(args.seed))).save(args.output, optimize=True)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
