"""What to record: a :class:`Recipe` (task, variant, episodes, seed, noise, ...), from a TOML file or the
command line, and the command line that reproduces it."""

from __future__ import annotations

import shlex
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any


@dataclass
class Recipe:
    """What to record. A recipe file (TOML) holds these fields; the command line gives the same ones."""

    task: str
    """Task name (``StackThree``) or gym id (``gym_actionflow/StackThree-v0``)."""
    variant: str
    """Initial-state distribution: D0/D1/D2 (D2: ThreePieceAssembly, Coffee, Threading), or
    train/test/scene_moved for MugHanging."""
    episodes: int
    """Successful episodes to keep."""
    repo_id: str
    """Dataset repo id; the data goes to ``$HF_LEROBOT_HOME/<repo_id>`` unless a root is given."""
    seed: int = 0
    """First seed; seeds are tried in order until ``episodes`` successes are kept."""
    noise: float = 1.0
    """Expert noise (0: deterministic waypoints; 1: the suite's standard demonstration noise)."""
    obs_mode: str = "state"
    """``state`` (tokens only) or ``pixels`` (adds the wrist camera, stored as video)."""
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    """Further ``gym.make`` keyword arguments (e.g. ``hanger_obs = "point_cloud"``)."""

    REQUIRED = ("task", "variant", "episodes", "repo_id")

    def __post_init__(self) -> None:
        if int(self.episodes) < 1:
            raise ValueError(f"episodes={self.episodes}; expected an integer >= 1")
        if self.noise < 0:
            raise ValueError(f"noise={self.noise}; expected >= 0")
        self.episodes, self.seed, self.noise = int(self.episodes), int(self.seed), float(self.noise)

    def command(self) -> str:
        """The ``actionflow-record`` command line that reproduces this dataset."""
        args = ["actionflow-record", "--task", self.task, "--variant", self.variant]
        args += ["--episodes", str(self.episodes), "--seed", str(self.seed), "--noise", f"{self.noise:g}"]
        if self.obs_mode != "state":
            args += ["--obs-mode", self.obs_mode]
        for key, value in self.env_kwargs.items():
            args += ["--env-kwarg", f"{key}={value}"]
        return shlex.join([*args, "--repo-id", self.repo_id])


def load_recipe(path: str | Path) -> Recipe:
    """Read a recipe file; a missing or unknown field is an error naming it (nothing is recorded)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"recipe {path} does not exist")
    with path.open("rb") as f:
        try:
            data = tomllib.load(f)
        except tomllib.TOMLDecodeError as err:
            raise ValueError(f"recipe {path} is not valid TOML: {err}") from err
    known = {f.name for f in fields(Recipe)}
    missing = [k for k in Recipe.REQUIRED if k not in data]
    if missing:
        raise ValueError(
            f"recipe {path} is missing the field(s) {missing}; a recipe needs {list(Recipe.REQUIRED)} "
            f"and may set {sorted(known - set(Recipe.REQUIRED))}"
        )
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"recipe {path} has unknown field(s) {unknown}; expected fields in {sorted(known)}")
    return Recipe(**data)
