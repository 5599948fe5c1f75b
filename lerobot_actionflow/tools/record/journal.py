"""The journal: kept episodes not yet in a finalized dataset, one file per seed
(``<root>/meta/actionflow_journal/<seed>.npz``, the episode's dataset columns and its task).

LeRobot makes a dataset readable only when it is finalized, which costs more as the dataset grows, so a
recording finalizes it only every few dozen episodes (:mod:`.durability`). In between, a kept episode is
durable because it is in the journal: a rerun replays the journal into the dataset instead of simulating the
episodes again, and each checkpoint empties it.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from lerobot_actionflow.tools.record.simulate import Episode

JOURNAL = "actionflow_journal"
TASK_KEY = "task"


def _folder(root: Path) -> Path:
    return root / "meta" / JOURNAL


def write(root: Path, episode: Episode) -> None:
    """Journal a kept episode; atomic (written under a temporary name, then renamed)."""
    folder = _folder(root)
    folder.mkdir(exist_ok=True)
    tmp = folder / f"{episode.seed}.tmp"
    with tmp.open("wb") as f:
        np.savez(f, **episode.columns, **{TASK_KEY: np.asarray(episode.task)})
    os.replace(tmp, folder / f"{episode.seed}.npz")


def read(root: Path, seed: int) -> Episode:
    path = _folder(root) / f"{seed}.npz"
    if not path.is_file():
        raise FileNotFoundError(f"{root}: the journal has no episode for seed {seed} ({path})")
    with np.load(path) as data:
        columns = {key: data[key] for key in data.files if key != TASK_KEY}
        return Episode(seed, True, columns, str(data[TASK_KEY]))


def seeds(root: Path) -> list[int]:
    """The seeds journaled (complete entries only)."""
    folder = _folder(root)
    return sorted(int(p.stem) for p in folder.glob("*.npz") if p.stem.isdigit()) if folder.is_dir() else []


def discard(root: Path, drop: set[int]) -> None:
    """Remove the entries of ``drop`` and any write a kill interrupted."""
    for seed in drop:
        (_folder(root) / f"{seed}.npz").unlink(missing_ok=True)
    for tmp in _folder(root).glob("*.tmp"):
        tmp.unlink()


def clear(root: Path) -> None:
    """Empty the journal: every episode in it is in the finalized dataset."""
    shutil.rmtree(_folder(root), ignore_errors=True)
