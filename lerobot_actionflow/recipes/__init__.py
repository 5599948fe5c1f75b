"""Task recipes: how to train and evaluate each gym_actionflow task, written once.

A recipe file per task (``<task>.toml`` beside this module, shipped with the package) holds what a task needs
beyond ``ActionFlowConfig``'s defaults: training steps, the data loader, ``--policy.*`` settings, and the
evaluation variants. What to *record* is each dataset's recipe (``datasets/*.toml``), which may override any
of it in its own ``[train]`` / ``[eval]`` tables. The main job (``tools/demo.py``), the paper harness
(``eval/paper``) and ``actionflow-recipe`` read recipes; nothing else spells a training flag or a layout seed.

    recipe = task_recipe("MugHanging")
    recipe.train.flags()      # ['--policy.action_smoothing=0.5', '--num_workers=2', '--steps=6000', ...]
    recipe.eval.first_seed    # 100000: the development layouts
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from typing import Any

LAYOUTS = {"dev": 100_000, "heldout": 200_000}
"""First seed of each range of evaluation layouts. Recordings use small seeds (from 0); development and
ablation evaluate on 100000-199999; published tables on the held-out layouts from 200000, which no tuning
touches."""
EVAL_SEED = LAYOUTS["dev"]
"""``lerobot-eval --seed`` of development evaluations: every evaluated layout is one no recording used."""


def refuse_held_out(seeds, tool: str) -> None:
    """Raise if a tuning or diagnostic ``tool`` would look at held-out layouts (seeds from 200000): what a
    diagnosis sees shapes the next setting, so the held-out layouts stay for the published tables only."""
    held = sorted(s for s in seeds if s >= LAYOUTS["heldout"])
    if held:
        raise ValueError(
            f"{tool}: seeds {held[:3]}{'...' if len(held) > 3 else ''} are held-out layouts (from "
            f"{LAYOUTS['heldout']}), kept for published tables; diagnose and tune on the development "
            f"layouts, seeds {LAYOUTS['dev']}-{LAYOUTS['heldout'] - 1}"
        )

LOADERS: dict[str, tuple[str, ...]] = {
    # LeRobot's streaming dataset with one worker: files read in order through a 1000-frame shuffle buffer,
    # about 2.5 ms a sample against 10-18 ms for the map-style dataset; 4.2x the samples/s of the map-style
    # loader on this project's 2-core CPU (eval/results/train_cpu_main_job.md; docs/training.md).
    "stream": ("--dataset.streaming=true", "--num_workers=1"),
    # LeRobot's map-style dataset (its default) with two workers: every frame drawn from a fresh permutation
    # each epoch, at about 4x the streaming loader's data cost on a CPU.
    "map": ("--num_workers=2",),
}
"""``lerobot-train`` flags of each data loader."""


def _flag_value(value: Any) -> str:
    """A value as ``lerobot-train`` parses it: ``true``, ``0.5``, ``[64,128]``, ``cnn``."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list | tuple | dict):
        return json.dumps(value, separators=(",", ":"))
    return str(value)


def _check(name: str, value: Any, kind: type | tuple[type, ...], where: str, minimum: float | None = None):
    """A recipe field of the right type (a bool is not an int) and at least ``minimum``."""
    kinds = kind if isinstance(kind, tuple) else (kind,)
    ok = isinstance(value, kinds) and (bool in kinds or not isinstance(value, bool))
    ok = ok and not (isinstance(value, float) and not math.isfinite(value))
    ok = ok and (minimum is None or value >= minimum)
    if not ok:
        names = " or ".join(k.__name__ for k in kinds)
        bound = f" >= {minimum}" if minimum is not None else ""
        raise ValueError(f"{name}={value!r} in {where}; expected {names}{bound}")


@dataclass(frozen=True)
class TrainSettings:
    """How ``lerobot-train`` trains ActionFlow on a task's data."""

    steps: int = 2000
    batch_size: int = 32
    loader: str = "stream"
    """A key of :data:`LOADERS`."""
    policy: dict[str, Any] = field(default_factory=dict)
    """``--policy.<field>=<value>`` settings beyond ``ActionFlowConfig``'s defaults (the checkpoint's config
    keeps them, so ``lerobot-eval`` runs with them)."""

    def policy_flags(self) -> list[str]:
        return [f"--policy.{k}={_flag_value(v)}" for k, v in self.policy.items()]

    def loader_flags(self) -> list[str]:
        return list(LOADERS[self.loader])

    def flags(self) -> list[str]:
        """Every ``lerobot-train`` flag of the recipe: policy settings, loader, steps and batch size."""
        return [*self.policy_flags(), *self.loader_flags(), f"--steps={self.steps}",
                f"--batch_size={self.batch_size}"]  # fmt: skip


@dataclass(frozen=True)
class EvalSettings:
    """How ``lerobot-eval`` evaluates a trained policy."""

    variants: tuple[str, ...] = ()
    """Variants (layout distributions) evaluated; empty: the training variant."""
    episodes: int = 50
    batch_size: int = 10
    layouts: str = "dev"
    """A key of :data:`LAYOUTS`: ``dev`` for development, ``heldout`` for published tables."""

    @property
    def first_seed(self) -> int:
        return LAYOUTS[self.layouts]


@dataclass(frozen=True)
class TaskRecipe:
    task: str
    train: TrainSettings = TrainSettings()
    eval: EvalSettings = EvalSettings()
    notes: str = ""
    """Why the settings are what they are (the recipe file's ``notes``), with the figures behind them."""

    def eval_variants(self, trained_on: str) -> tuple[str, ...]:
        return self.eval.variants or (trained_on,)

    def with_overrides(self, table: dict[str, Any], where: str) -> TaskRecipe:
        """This recipe with a file's ``[train]`` / ``[eval]`` tables applied on top (each field checked)."""
        train, evaluation = _settings(table, where)
        merged_policy = {**self.train.policy, **train.pop("policy", {})}
        return replace(
            self,
            train=replace(self.train, **train, policy=merged_policy),
            eval=replace(self.eval, **evaluation),
        )


def _settings(table: dict[str, Any], where: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """The ``[train]`` and ``[eval]`` tables of a recipe file, every field checked."""
    unknown = sorted(set(table) - {"train", "eval"})
    if unknown:
        raise ValueError(f"{where} has unknown table(s) {unknown}; expected [train] and [eval]")
    train, evaluation = dict(table.get("train", {})), dict(table.get("eval", {}))
    for name, given, known in (("train", train, TrainSettings), ("eval", evaluation, EvalSettings)):
        expected = [f.name for f in fields(known)]
        extra = sorted(set(given) - set(expected))
        if extra:
            raise ValueError(
                f"[{name}] in {where} has unknown field(s) {extra}; expected fields in {expected}"
            )
    for key in ("steps", "batch_size"):
        if key in train:
            _check(f"train.{key}", train[key], int, where, 1)
    if "loader" in train and train["loader"] not in LOADERS:
        raise ValueError(f"train.loader={train['loader']!r} in {where}; expected one of {tuple(LOADERS)}")
    if "policy" in train:
        if not isinstance(train["policy"], dict):
            raise ValueError(
                f"train.policy={train['policy']!r} in {where}; expected a table of config fields"
            )
        _check_policy_fields(train["policy"], where)
    for key in ("episodes", "batch_size"):
        if key in evaluation:
            _check(f"eval.{key}", evaluation[key], int, where, 1)
    if "layouts" in evaluation and evaluation["layouts"] not in LAYOUTS:
        raise ValueError(
            f"eval.layouts={evaluation['layouts']!r} in {where}; expected one of {tuple(LAYOUTS)}"
        )
    if "variants" in evaluation:
        variants = evaluation["variants"]
        if not isinstance(variants, list) or not all(isinstance(v, str) for v in variants):
            raise ValueError(f"eval.variants={variants!r} in {where}; expected a list of variant names")
        evaluation["variants"] = tuple(variants)
    return train, evaluation


def _check_policy_fields(policy: dict[str, Any], where: str) -> None:
    """``[train.policy]`` names ActionFlowConfig fields (checked where LeRobot is importable)."""
    try:
        from lerobot_actionflow.configuration_actionflow import ActionFlowConfig
    except ImportError:
        return
    known = {f.name for f in fields(ActionFlowConfig)}
    unknown = sorted(set(policy) - known)
    if unknown:
        raise ValueError(f"train.policy in {where} names unknown ActionFlowConfig field(s) {unknown}")


def snake(name: str) -> str:
    """``StackThree`` -> ``stack_three`` (the spelling of recipe files and repo ids)."""
    return "".join("_" + c.lower() if c.isupper() else c for c in name).lstrip("_")


def task_recipe(task: str) -> TaskRecipe:
    """The recipe of ``task`` (a name, ``Name-v0`` or gym id), from its file beside this module."""
    from gym_actionflow import find_task

    name = find_task(task).name
    resource = resources.files(__package__) / f"{snake(name)}.toml"
    if not resource.is_file():
        return TaskRecipe(name)
    where = f"lerobot_actionflow/recipes/{resource.name}"
    data = tomllib.loads(resource.read_text())
    if data.pop("task", name) != name:
        raise ValueError(f"{where} is the recipe of another task; expected task = {name!r}")
    notes = data.pop("notes", "")
    return TaskRecipe(name, notes=notes.strip()).with_overrides(data, where)
