"""Every finished episode survives Ctrl-C, a crash or a kill; an episode a kill interrupts while LeRobot
writes it is undone on the next run.

Before an episode is written, :func:`begin_episode` notes what is on disk (the file list and copies of the
metadata LeRobot rewrites); :func:`end_episode` drops the note once the episode is durable; a rerun that finds
the note calls :func:`roll_back`. Ctrl-C and SIGTERM are held while an episode is written
(:func:`deferred_interrupts`).
"""

from __future__ import annotations

import contextlib
import json
import shutil
import signal
from collections.abc import Iterator
from pathlib import Path

from lerobot_actionflow.tools.record.log import LOG_NAME

PENDING = "actionflow_pending"
"""Folder under ``meta/`` holding what an episode write may change; present only while one is written."""
RESTORED = ("meta/info.json", "meta/stats.json", "meta/tasks.parquet")


@contextlib.contextmanager
def deferred_interrupts() -> Iterator[None]:
    """Hold Ctrl-C / SIGTERM while an episode is written, then deliver it: no half-written episode."""
    received: list[int] = []
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

    def hold(signum, _frame):
        received.append(signum)

    for sig in previous:
        signal.signal(sig, hold)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if received:
            raise KeyboardInterrupt


def terminate_as_interrupt(signum, _frame):
    """SIGTERM handler: stop like Ctrl-C, so the finished episodes are kept."""
    raise KeyboardInterrupt


def begin_episode(root: Path) -> None:
    """Note what is on disk before an episode is written, so that a kill half-way through can be undone."""
    pending = root / "meta" / PENDING
    shutil.rmtree(pending, ignore_errors=True)
    pending.mkdir()
    for rel in RESTORED:
        if (root / rel).is_file():
            shutil.copy2(root / rel, pending / Path(rel).name)
    files = sorted(
        p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file() and PENDING not in p.parts
    )
    tmp = pending / "files.tmp"
    tmp.write_text(json.dumps(files))
    tmp.replace(pending / "files.json")  # written last: its presence means the snapshot is complete


def end_episode(root: Path) -> None:
    shutil.rmtree(root / "meta" / PENDING, ignore_errors=True)


def roll_back(root: Path) -> None:
    """Remove every file an unfinished episode write added, and put LeRobot's metadata back as it was."""
    pending = root / "meta" / PENDING
    listing = pending / "files.json"
    if listing.is_file():  # else the kill came before the write started: the dataset is untouched
        keep = set(json.loads(listing.read_text())) | {f"meta/{LOG_NAME}"}
        for path in list(root.rglob("*")):
            if path.is_file() and PENDING not in path.parts and path.relative_to(root).as_posix() not in keep:
                path.unlink()
        for rel in RESTORED:
            if (pending / Path(rel).name).is_file():
                shutil.copy2(pending / Path(rel).name, root / rel)
    shutil.rmtree(pending, ignore_errors=True)
