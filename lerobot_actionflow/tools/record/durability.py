"""Every kept episode survives Ctrl-C, a crash or a kill, at a cost per episode that does not grow with the
dataset.

LeRobot appends episodes to an open dataset cheaply (``save_episode``), but the dataset is readable only once
finalized (parquet footers, buffered metadata), and reopening it afterwards reads all of its metadata: doing
both after every episode makes an episode cost more the larger the dataset. A recording therefore finalizes
only at a *checkpoint* (every 50 episodes or every tenth of the dataset, and at the end or on Ctrl-C).
Between checkpoints:

- :func:`snapshot`, taken when the dataset is (re)opened after a checkpoint, notes what is on disk: the file
  list and copies of the metadata files LeRobot rewrites in place;
- each kept episode is written to the journal (:mod:`.journal`) and logged before LeRobot writes it.

At a checkpoint the dataset is finalized, then :func:`commit` drops the snapshot: from there on the dataset
itself holds the episodes and the journal is emptied. A rerun that finds a snapshot calls :func:`roll_back`,
which brings the dataset back to its last checkpoint (whatever a kill left half-written), and replays the
journal into it. Ctrl-C and SIGTERM are held while an episode or a checkpoint is written
(:func:`deferred_interrupts`). Our own files (the log, the journal, the snapshot) are ``meta/actionflow_*``:
a roll-back leaves them alone.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import signal
from collections.abc import Iterator
from pathlib import Path

PENDING = "actionflow_pending"
"""Folder under ``meta/`` holding the snapshot; present from a (re)opening of the dataset to its next
checkpoint."""
OWN_FILES = "meta/actionflow_"
"""Prefix of the files this tool keeps beside LeRobot's (log, journal, snapshot): never rolled back."""
RESTORED = ("meta/info.json", "meta/stats.json", "meta/tasks.parquet")
"""LeRobot's files that an appended episode rewrites in place; every other file it writes is new."""


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


def _dataset_files(root: Path) -> list[str]:
    paths = (p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())
    return sorted(p for p in paths if not p.startswith(OWN_FILES))


def snapshot(root: Path) -> None:
    """Note the dataset as it is (finalized), so that what the episodes after it write can be undone."""
    pending = root / "meta" / PENDING
    shutil.rmtree(pending, ignore_errors=True)
    pending.mkdir()
    for rel in RESTORED:
        if (root / rel).is_file():
            shutil.copy2(root / rel, pending / Path(rel).name)
    tmp = pending / "files.tmp"
    tmp.write_text(json.dumps(_dataset_files(root)))
    tmp.replace(pending / "files.json")  # written last: its presence means the snapshot is complete


def commit(root: Path) -> None:
    """The dataset is finalized with every episode written since the snapshot: drop the snapshot."""
    shutil.rmtree(root / "meta" / PENDING, ignore_errors=True)


def roll_back(root: Path) -> None:
    """Bring the dataset back to its snapshot: remove every file written since and put LeRobot's rewritten
    metadata back. Without a snapshot the dataset is as its last checkpoint left it: nothing to do."""
    pending = root / "meta" / PENDING
    listing = pending / "files.json"
    if listing.is_file():  # else the kill came before the snapshot was complete: nothing was written since
        keep = set(json.loads(listing.read_text()))
        for rel in _dataset_files(root):
            if rel not in keep:
                (root / rel).unlink()
        for rel in RESTORED:
            if (pending / Path(rel).name).is_file():
                shutil.copy2(pending / Path(rel).name, root / rel)
    shutil.rmtree(pending, ignore_errors=True)
