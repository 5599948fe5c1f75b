"""What to record: a :class:`Recipe` (task, variant, episodes, seed, noise, ...), from a TOML file or the
command line, and the command line that reproduces it.

Every field is checked here (:func:`check_fields`) before anything is recorded: a recording that starts from a
bad value would create its folder and log that value as part of the recording's identity, and the corrected
rerun would then be refused as "a different recording". An error names where the value came from (a flag, a
recipe file's field, or the ``Recipe`` field), the value seen and what was expected.
"""

from __future__ import annotations

import inspect
import math
import shlex
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

Label = Callable[[str], str]
"""Where a field's value came from, for error messages: ``noise -> "--noise"`` or ``"noise in x.toml"``; an
env keyword is asked for as ``env_kwargs.<key>``."""


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
    """``state`` (no image) or ``pixels`` (adds the cameras, stored as ``image_storage``)."""
    obs_layout: str = "tokens"
    """``tokens`` (token keys, ``observation.state``, object poses) or ``lerobot`` (``observation.state`` and
    ``observation.images.*`` only: a plain LeRobot dataset; needs ``obs_mode = "pixels"``)."""
    cameras: list[str] | None = None
    """With ``obs_mode = "pixels"``: the cameras, from ``front`` (static) and ``wrist``; None = the wrist
    camera."""
    image_storage: str = "image"
    """With ``obs_mode = "pixels"``: ``image`` (each frame a PNG in the parquet data files, which are kept
    small so that LeRobot's streaming loader interleaves many of them) or ``video`` (smaller AV1 files,
    decoded at every sample)."""
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    """Further ``gym.make`` keyword arguments (e.g. ``hanger_obs = "point_cloud"``)."""
    source: str | None = None
    """A source dataset's folder: the episodes are generated from its demonstrations
    (``actionflow-generate``, :mod:`lerobot_actionflow.tools.generate`) instead of the scripted expert's."""
    policy: str | None = None
    """A trained policy's checkpoint (a ``pretrained_model`` folder): its rollouts are recorded instead of the
    scripted expert's, the successful ones only (``actionflow-record --policy``)."""

    REQUIRED = ("task", "variant", "episodes", "repo_id")

    def __post_init__(self) -> None:
        check_fields({f.name: getattr(self, f.name) for f in fields(self)})
        self.noise = float(self.noise)

    def eval_env_kwargs(self) -> dict[str, Any]:
        """The env settings an evaluation of a policy trained on this recording needs (``lerobot-eval
        --env.<key>=<value>``): the observation mode, layout and cameras it recorded, and its env keywords."""
        defaults = {f.name: f.default for f in fields(self)}
        observation = {k: getattr(self, k) for k in ("obs_mode", "obs_layout", "cameras")}
        return {k: v for k, v in observation.items() if v != defaults[k]} | dict(self.env_kwargs)

    def command(self) -> str:
        """The ``actionflow-record`` (or, for generated episodes, ``actionflow-generate``) command line that
        reproduces this dataset."""
        if self.source is not None:
            args = ["actionflow-generate", self.source, "--task", self.task, "--variant", self.variant]
            args += ["--episodes", str(self.episodes), "--seed", str(self.seed), "--noise", f"{self.noise:g}"]
            if self.obs_mode != "state":
                args += ["--obs-mode", self.obs_mode]
            if self.cameras is not None:
                args += ["--cameras", *self.cameras]
            for key, value in self.env_kwargs.items():
                args += ["--env-kwarg", f"{key}={value}"]
            return shlex.join([*args, "--repo-id", self.repo_id])
        args = ["actionflow-record", "--task", self.task, "--variant", self.variant]
        args += ["--episodes", str(self.episodes), "--seed", str(self.seed), "--noise", f"{self.noise:g}"]
        if self.obs_mode != "state":
            args += ["--obs-mode", self.obs_mode]
        if self.obs_layout != "tokens":
            args += ["--obs-layout", self.obs_layout]
        if self.cameras is not None:
            args += ["--cameras", *self.cameras]
        if self.obs_mode == "pixels" and self.image_storage != "image":
            args += ["--image-storage", self.image_storage]
        for key, value in self.env_kwargs.items():
            args += ["--env-kwarg", f"{key}={value}"]
        if self.policy is not None:
            args += ["--policy", self.policy]
        return shlex.join([*args, "--repo-id", self.repo_id])


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)  # True is an int to Python, not a count


def env_keywords(env_class: type) -> set[str] | None:
    """The keyword arguments ``env_class(...)`` accepts, following ``**kwargs`` passed up to the base
    classes; None when the class does not say (an ``__init__`` that takes ``**kwargs`` for itself)."""
    names: set[str] = set()
    for cls in env_class.__mro__:
        if "__init__" not in vars(cls) or cls is object:
            continue
        params = inspect.signature(vars(cls)["__init__"]).parameters.values()
        names |= {p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
        if not any(p.kind is p.VAR_KEYWORD for p in params):
            return names - {"self"}
    return None


OWN_FIELDS = ("variant", "obs_mode", "obs_layout", "cameras")
"""Env keywords that are recipe fields of their own, never ``env_kwargs``."""


def _check_env_kwargs(task, env_kwargs: object, label: Label) -> None:
    from gym_actionflow.registry import load

    if not isinstance(env_kwargs, Mapping):
        raise ValueError(
            f"{label('env_kwargs')}: got {env_kwargs!r}; expected a table of gym.make keywords "
            '(e.g. [env_kwargs] hanger_obs = "point_cloud")'
        )
    accepted = env_keywords(load(task.entry_point)) if env_kwargs else None
    for key in env_kwargs:
        where = label(f"env_kwargs.{key}")
        if key in OWN_FIELDS:
            flag = "--" + key.replace("_", "-")
            raise ValueError(f"{where}: {key} is a field of its own; give it as {key} ({flag})")
        if accepted is not None and key not in accepted:
            options = ", ".join(sorted(accepted - set(OWN_FIELDS)))
            raise ValueError(
                f"{where}: {task.env_id} takes no keyword {key!r}; expected one of its keywords: {options}"
            )


def check_fields(values: Mapping[str, Any], label: Label = str) -> None:
    """Check a recipe's fields (those present in ``values``): types strict (``True`` is not a count, 2.7
    is not an integer), numbers finite and in range, the task known, the variant and obs mode one of the
    task's, the observation layout and cameras ones the env has and takes together with the obs mode (a field
    left out counts as its default), the env keywords ones the task's env takes. A ValueError names
    ``label(field)``, the value seen and what was expected."""
    from gym_actionflow import find_task
    from gym_actionflow.registry import CAMERAS, OBS_LAYOUTS, OBS_MODES, check_observation
    from huggingface_hub.utils import validate_repo_id

    from lerobot_actionflow.schema import IMAGE_STORAGES

    def fail(key: str, expected: str) -> None:
        raise ValueError(f"{label(key)}: got {values[key]!r}; expected {expected}")

    task = None
    if "task" in values:
        if not isinstance(values["task"], str):
            fail("task", "a task name such as 'StackThree'")
        try:
            task = find_task(values["task"])
        except ValueError as err:
            raise ValueError(f"{label('task')}: {err}") from None
    if "variant" in values:
        choices = task.variants if task is not None else ()
        if not isinstance(values["variant"], str) or (task is not None and values["variant"] not in choices):
            fail("variant", f"one of {choices} for {task.name}" if task else "a variant name such as 'D0'")
    for key, low in (("episodes", 1), ("seed", 0)):
        if key in values and (not _is_int(values[key]) or values[key] < low):
            fail(key, f"an integer >= {low}")
    if "noise" in values:
        noise = values["noise"]
        if not (_is_int(noise) or isinstance(noise, float)) or not math.isfinite(noise) or noise < 0:
            fail("noise", "a finite number >= 0 (0: deterministic expert, 1: the standard noise)")
    if "obs_mode" in values and values["obs_mode"] not in OBS_MODES:
        fail("obs_mode", f"one of {OBS_MODES} ('pixels' adds the cameras)")
    if "image_storage" in values and values["image_storage"] not in IMAGE_STORAGES:
        fail("image_storage", f"one of {IMAGE_STORAGES} (how camera frames are stored)")
    if "obs_layout" in values and values["obs_layout"] not in OBS_LAYOUTS:
        fail("obs_layout", f"one of {OBS_LAYOUTS} ('lerobot': observation.state and the cameras only)")
    cameras = values.get("cameras")
    if cameras is not None and (
        not isinstance(cameras, list | tuple)
        or not cameras
        or not all(isinstance(c, str) and c in CAMERAS for c in cameras)
        or len(set(cameras)) != len(cameras)
    ):
        fail("cameras", f"a list of distinct camera names from {CAMERAS}, e.g. ['front', 'wrist']")
    if {"obs_mode", "obs_layout", "cameras"} & set(values):
        try:
            check_observation(values.get("obs_mode", "state"), values.get("obs_layout", "tokens"), cameras)
        except ValueError as err:  # a combination: named by the field that asks for more than the obs mode
            key = "cameras" if str(err).startswith("cameras") or "obs_layout" not in values else "obs_layout"
            raise ValueError(f"{label(key)}: {err}") from None
    if "repo_id" in values:
        try:
            validate_repo_id(values["repo_id"])
        except Exception:  # huggingface_hub's HFValidationError, or a TypeError for a non-string
            fail("repo_id", "a Hub repo id such as 'you/stack_d0_200' (letters, digits, '-', '_', '.')")
    if "env_kwargs" in values and task is not None:
        _check_env_kwargs(task, values["env_kwargs"], label)
    if values.get("source") is not None and not isinstance(values["source"], str):
        fail("source", "the path of a source dataset's folder, or none")
    if values.get("policy") is not None:
        if not isinstance(values["policy"], str):
            fail("policy", "the path of a trained policy's pretrained_model folder, or none")
        if not (Path(values["policy"]) / "config.json").is_file():
            fail("policy", "a pretrained_model folder with its config.json (lerobot-train's checkpoints/*/)")
        if values.get("source") is not None:
            fail("policy", "no source with it: an episode comes from a policy or from a source, not both")


TRAINING_TABLES = ("train", "eval")
"""Tables of a dataset recipe that say how to train and evaluate on it (``lerobot_actionflow.recipes``), not
what to record."""


def load_recipe(path: str | Path) -> Recipe:
    """Read a recipe file's record fields; a missing, unknown or bad field is an error naming it and the
    file (nothing is recorded). Its ``[train]`` / ``[eval]`` tables are :func:`read_recipe_file`'s."""
    return read_recipe_file(path)[0]


def read_recipe_file(path: str | Path) -> tuple[Recipe, dict[str, Any]]:
    """A recipe file's record fields, checked, and its ``[train]`` / ``[eval]`` tables as written."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"recipe {path} does not exist")
    with path.open("rb") as f:
        try:
            data = tomllib.load(f)
        except tomllib.TOMLDecodeError as err:
            raise ValueError(f"recipe {path} is not valid TOML: {err}") from err
    tables = {k: data.pop(k) for k in TRAINING_TABLES if k in data}
    known = {f.name for f in fields(Recipe)}
    missing = [k for k in Recipe.REQUIRED if k not in data]
    if missing:
        raise ValueError(
            f"recipe {path} is missing the field(s) {missing}; a recipe needs {list(Recipe.REQUIRED)} "
            f"and may set {sorted(known - set(Recipe.REQUIRED))}"
        )
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(
            f"recipe {path} has unknown field(s) {unknown}; expected fields in {sorted(known)} and the "
            f"tables {list(TRAINING_TABLES)}"
        )
    check_fields(data, recipe_label(path))
    return Recipe(**data), tables


def recipe_label(path: str | Path) -> Label:
    """Labels of a recipe file's fields: ``noise in datasets/x.toml``, ``env_kwargs.foo in
    datasets/x.toml``."""
    return lambda key: f"{key} in {path}"
