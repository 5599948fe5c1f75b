"""The recording log beside LeRobot's metadata (``<root>/meta/actionflow_recording.json``): the recipe, and
which seeds were kept and which failed. It lets a rerun resume and the dataset card tell the story."""

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
    pending_seed: int | None = None
    """Seed of the episode being written: set while LeRobot writes it, so that a kill half-way is undone."""
    seconds: float = 0.0

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
        return cls(**json.loads(path.read_text())) if path.is_file() else None


def same_recording(a: dict, b: dict) -> list[str]:
    """What differs between two logged recipes that a resume must not mix (empty: the same recording)."""
    keys = ("task", "variant", "seed", "noise", "obs_mode", "env_kwargs", "repo_id")
    return [f"{k}: {a.get(k)!r} on disk vs {b.get(k)!r} now" for k in keys if a.get(k) != b.get(k)]
