"""The matrix of the paper benchmark: the datasets, trainings and evaluation cells of each experiment.

Three stages, each keyed by everything that changes its output, so that equal keys are shared: a dataset
(task, variant, episodes, expert noise, first seed, env keywords) is recorded once for every training that
reads it; a training (dataset, model, flags, steps, batch, seed, device) once for every evaluation of it (the
inference-steps experiment evaluates one training at ten settings); a cell is one evaluation, one number.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from eval.paper.profiles import MODELS, Group, Profile
from lerobot_actionflow.recipes import LAYOUTS, task_recipe

EXPERIMENTS = ("sample-efficiency", "inference-steps", "generalisation")


def _digest(obj: object) -> str:
    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:8]


def snake(name: str) -> str:
    """``StackThree`` -> ``stack_three`` (the recipes' and repo ids' spelling)."""
    return "".join("_" + c.lower() if c.isupper() else c for c in name).lstrip("_")


@dataclass(frozen=True)
class Dataset:
    task: str
    variant: str
    episodes: int
    noise: float = 1.0
    seed: int = 0
    """First recording seed; the recorder tries seeds in order until ``episodes`` succeed."""
    env_kwargs: tuple[tuple[str, str], ...] = ()

    @property
    def key(self) -> str:
        kwargs = "".join(f"_{k}-{v}" for k, v in self.env_kwargs)
        name = f"{snake(self.task)}_{self.variant.lower()}_{self.episodes}ep"
        return f"{name}_noise{self.noise:g}_seed{self.seed}{kwargs}"


@dataclass(frozen=True)
class Training:
    dataset: Dataset
    model: str
    steps: int
    batch_size: int
    seed: int
    device: str
    flags: tuple[str, ...]
    """The model's ``lerobot-train`` flags and the profile's extras for its policy type."""
    checkpoints: int
    recipe_flags: tuple[str, ...] = ()
    """The task recipe's ``--policy.*`` settings this training gets (none for diffusion); part of the key."""

    @property
    def policy_type(self) -> str:
        return MODELS[self.model].policy_type

    @property
    def key(self) -> str:
        return f"{self.dataset.key}__{self.model}_{self.steps}steps_seed{self.seed}_{_digest(asdict(self))}"


@dataclass(frozen=True)
class Cell:
    """One evaluation: a training's checkpoint(s) on ``eval_variant`` with ``eval_flags`` (evaluation-time
    overrides such as ``--policy.num_inference_steps``), or a replay baseline when ``training`` is None."""

    experiment: str
    profile: str
    group: str
    dataset: Dataset
    training: Training | None
    eval_variant: str
    episodes: int
    batch_size: int
    eval_flags: tuple[str, ...] = ()
    k: int | None = None
    schedule: str | None = None
    replay_offset_mm: float | None = None
    note: str = ""
    layouts: str = "heldout"
    """Which evaluation layouts (``lerobot_actionflow.recipes.LAYOUTS``): ``heldout`` (from 200000) for the
    published tables, ``dev`` (from 100000) for tuning. A replay is on its recorded layouts whatever this
    says."""

    @property
    def model(self) -> str:
        if self.training is not None:
            return self.training.model
        return "replay" if not self.replay_offset_mm else f"replay {self.replay_offset_mm:g} mm off"

    @property
    def key(self) -> str:
        setting = f"_k{self.k}_{self.schedule}" if self.k is not None else ""
        name = self.model.replace(" ", "_")
        fields = asdict(self)
        # Development cells and replays keep the keys they had before held-out layouts existed.
        if fields.pop("layouts") == "dev" or self.training is None:
            return f"{self.dataset.key}__{name}__{self.eval_variant}{setting}_{_digest(fields)}"
        return f"{self.dataset.key}__{name}__{self.eval_variant}{setting}_heldout_{_digest(asdict(self))}"


@dataclass(frozen=True)
class Paths:
    """Where each stage writes: working files (datasets, checkpoints, logs) under ``work``; the cells' JSON,
    tables and plots under ``results``. Both default to git-ignored folders; the committed results are
    ``Paths(results=Path("eval/results/paper"))`` (``--results-dir eval/results/paper``)."""

    work: Path = Path("outputs/paper")
    results: Path = Path("outputs/paper/results")

    def data(self, dataset: Dataset) -> Path:
        return self.work / "data" / dataset.key

    def train(self, training: Training) -> Path:
        return self.work / "train" / training.key

    def eval(self, cell: Cell) -> Path:
        return self.work / "eval" / cell.key

    def log(self, name: str) -> Path:
        return self.work / "logs" / f"{name}.log"

    def cells(self, profile: str, experiment: str) -> Path:
        return self.results / "cells" / profile / experiment

    def cell(self, cell: Cell) -> Path:
        return self.cells(cell.profile, cell.experiment) / f"{cell.key}.json"


def group_steps(profile: Profile, experiment: str, group: Group) -> int:
    """A group's training steps: its own, its task recipe's (``steps="recipe"``) or the profile's."""
    if group.steps == "recipe":
        return task_recipe(group.task).train.steps
    return group.steps or profile.steps[experiment]


def _trainings(
    profile: Profile, experiment: str, group: Group, models: set[str] | None, steps: int | None,
    seeds: tuple[int, ...] | None = None, demos_wanted: set[int] | None = None,
):
    """(dataset, training) pairs of a group, for the models, training seeds (default: the profile's) and
    dataset sizes (default: the group's) asked for."""
    base = steps or group_steps(profile, experiment, group)
    for demos in group.demos:
        if demos_wanted is not None and demos not in demos_wanted:
            continue
        dataset = Dataset(group.task, group.variant, demos, env_kwargs=group.env_kwargs)
        for name in group.models:
            if models is not None and name not in models:
                continue
            model = MODELS[name]
            n = base if steps else max(base, profile.min_steps.get(model.policy_type, 0))
            flags = model.flags + profile.policy_flags.get(model.policy_type, ())
            # The task recipe's ActionFlow settings, which train_command passes (not to diffusion).
            recipe = tuple(task_recipe(group.task).train.policy_flags()) if model.flow else ()
            for seed in seeds or profile.seeds:
                yield dataset, Training(dataset, name, n, profile.batch_size, seed, profile.device, flags,
                                        profile.checkpoints, recipe)  # fmt: skip


DDPM_STEPS = 100
"""LeRobot's Diffusion Policy trains with 100 DDPM steps and, by default, samples with all of them."""


def _settings(experiment: str, model: str, profile: Profile) -> list[dict]:
    """The evaluations of one training: a plain one, or (inference steps) every K on every time grid for a
    flow and every K of DDIM for diffusion (plus its default DDPM sampler), as evaluation-time overrides of
    the trained policy's config."""
    if experiment != "inference-steps":
        return [{}]
    ks = profile.inference_ks
    if MODELS[model].flow:
        flags = ("--policy.num_inference_steps={k}", "--policy.time_schedule={s}")
        return [dict(k=k, schedule=s, eval_flags=tuple(f.format(k=k, s=s) for f in flags))
                for k in ks for s in profile.schedules]  # fmt: skip
    flags = ("--policy.noise_scheduler_type=DDIM", "--policy.num_inference_steps={k}")
    ddim = [dict(k=k, schedule="DDIM", eval_flags=tuple(f.format(k=k) for f in flags)) for k in ks]
    # The same training under the sampler it was trained with (LeRobot's default: DDPM, every one of its
    # 100 training steps), so a low DDIM row is told apart from a weak training.
    ddpm_flags = ("--policy.noise_scheduler_type=DDPM", f"--policy.num_inference_steps={DDPM_STEPS}")
    ddpm = dict(k=DDPM_STEPS, schedule="DDPM", eval_flags=ddpm_flags)
    return [*ddim, ddpm]


def _only(groups: Sequence[Group], field: str, wanted: list[str] | None, where: str) -> list[Group]:
    """The groups whose ``field`` (``task``, ``variant``) is in ``wanted`` (all if None); a wanted value no
    group has is refused by name (``--tasks`` / ``--variants``)."""
    if not wanted:
        return list(groups)
    known = {getattr(g, field) for g in groups}
    if set(wanted) - known:
        missing = sorted(set(wanted) - known)
        raise ValueError(f"--{field}s {missing}: no such group in {where}; its {field}s are {sorted(known)}")
    return [g for g in groups if getattr(g, field) in wanted]


def build(
    experiment: str,
    profile: Profile,
    tasks: list[str] | None = None,
    models: list[str] | None = None,
    steps: int | None = None,
    variants: list[str] | None = None,
    layouts: str = "heldout",
    seeds: list[int] | None = None,
    demos: list[int] | None = None,
) -> list[Cell]:
    """Every cell of ``experiment`` under ``profile``, restricted to ``tasks``, ``models``, training
    ``variants`` (``D0``, ``D2``...) and dataset sizes ``demos`` if given, trained with each of ``seeds``
    (default: the profile's) and evaluated on ``layouts`` (``heldout`` or ``dev``)."""
    if layouts not in LAYOUTS:
        raise ValueError(f"layouts {layouts!r}; expected one of {tuple(LAYOUTS)}")
    if experiment not in EXPERIMENTS:
        raise ValueError(f"experiment {experiment!r}; expected one of {EXPERIMENTS}")
    unknown = sorted(set(models or ()) - set(MODELS) - {"replay"})
    if unknown:
        raise ValueError(f"unknown model(s) {unknown}; expected names in {[*MODELS, 'replay']}")
    groups = getattr(profile, experiment.replace("-", "_"))
    where = f"{experiment} ({profile.name})"
    groups = _only(groups, "task", tasks, where)
    groups = _only(groups, "variant", variants, where + (f" for {', '.join(tasks)}" if tasks else ""))
    wanted = set(models) if models else None
    if seeds is not None and (not seeds or len(set(seeds)) != len(seeds) or min(seeds) < 0):
        raise ValueError(f"--seeds {seeds}: expected distinct training seeds >= 0")
    known = {n for g in groups for n in g.demos}
    if demos and set(demos) - known:
        raise ValueError(f"--demos {sorted(set(demos) - known)}: no group of {where} trains on that many "
                         f"demonstrations; its sizes are {sorted(known)}")  # fmt: skip
    seeds_, sizes = (tuple(seeds) if seeds else None), (set(demos) if demos else None)
    common = dict(experiment=experiment, profile=profile.name, episodes=profile.eval_episodes,
                  batch_size=profile.eval_batch_size, layouts=layouts)  # fmt: skip
    cells: list[Cell] = []
    for group in groups:
        title = group.title or f"{group.task} {group.variant}"
        for dataset, training in _trainings(profile, experiment, group, wanted, steps, seeds_, sizes):
            note = profile.notes.get(training.policy_type, "")
            for variant in group.eval_variants or (group.variant,):
                base = dict(
                    common, group=title, dataset=dataset, training=training, eval_variant=variant, note=note
                )
                cells += [
                    Cell(**base, **setting) for setting in _settings(experiment, training.model, profile)
                ]
        if wanted is None or "replay" in wanted:
            for offset in group.replay_offsets_mm:
                dataset = Dataset(group.task, group.variant, group.demos[0], env_kwargs=group.env_kwargs)
                replay = {**common, "episodes": dataset.episodes, "group": title, "dataset": dataset}
                cells.append(
                    Cell(**replay, training=None, eval_variant=group.variant, replay_offset_mm=offset)
                )
    return cells
