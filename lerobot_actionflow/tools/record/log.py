"""The recording log beside LeRobot's metadata (``<root>/meta/actionflow_recording.json``): the recipe, and
which seeds were kept and which failed. It lets a rerun resume and the dataset card tell the story.

A kept seed is logged once its episode is durable (in the journal, :mod:`.journal`), possibly before the
dataset is finalized with it: the first ``total_episodes`` kept seeds are the finalized dataset's episodes,
the rest are replayed from the journal by the next run."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

LOG_NAME = "actionflow_recording.json"


@dataclass
class RecordingLog:
    """Which seeds were tried, kept and failed; lets a rerun resume and the dataset card tell the story."""

    recipe: dict
    kept_seeds: list[int] = field(default_factory=list)
    failed_seeds: list[int] = field(default_factory=list)
    seconds: float = 0.0
    segments: dict[str, list[int]] = field(default_factory=dict)
    """A generation's kept episodes: seed (as text) -> the source episode of each segment."""

    @property
    def next_seed(self) -> int:
        tried = self.kept_seeds + self.failed_seeds
        return max(tried) + 1 if tried else self.recipe["seed"]

    @property
    def success_rate(self) -> float:
        tried = len(self.kept_seeds) + len(self.failed_seeds)
        return len(self.kept_seeds) / tried if tried else float("nan")

    def save(self, root: Path) -> None:
        path = root / "meta" / LOG_NAME
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(asdict(self), indent=2))
        tmp.replace(path)  # atomic: the log is never half-written

    @classmethod
    def load(cls, root: Path) -> RecordingLog | None:
        path = root / "meta" / LOG_NAME
        if not path.is_file():
            return None
        data = json.loads(path.read_text())
        data.pop("pending_seed", None)  # logs from before the journal: the roll-back undoes that seed
        return cls(**data)


_ADDED_FIELDS = {"obs_layout": "tokens", "cameras": None, "image_storage": "video", "source": None,
                 "policy": None}
"""Recipe fields added after the first recordings, with the value an older log (which lacks them) meant."""


def same_recording(a: dict, b: dict) -> list[str]:
    """What differs between two logged recipes that a resume must not mix (empty: the same recording)."""
    keys = ("task", "variant", "seed", "noise", "obs_mode", *_ADDED_FIELDS, "env_kwargs", "repo_id")
    a, b = _ADDED_FIELDS | a, _ADDED_FIELDS | b
    return [f"{k}: {a.get(k)!r} on disk vs {b.get(k)!r} now" for k in keys if a.get(k) != b.get(k)]
