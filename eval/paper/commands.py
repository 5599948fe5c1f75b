"""The command lines of a cell's stages (``actionflow-record``, ``lerobot-train``, ``lerobot-eval``, and the
replay baseline) and the seed rule that keeps evaluated layouts apart from recorded ones.

The commands are the task recipe's (``lerobot_actionflow/recipes``: its loader, ``--policy.*`` settings and
first evaluation seed), built by the same functions as the main job's, so a cell printed by the harness can be
pasted and run by hand.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path

from eval.paper.plan import Cell, Dataset, Training
from lerobot_actionflow.recipes import LAYOUTS, task_recipe
from lerobot_actionflow.recipes import commands as recipe_commands

REPLAY_MODULE = "eval.paper.replay"
"""The replay baseline, run as ``python -m eval.paper.replay`` from the repository root."""


def repo_id(dataset: Dataset) -> str:
    return f"paper/{dataset.key}"


def record_command(dataset: Dataset, root: Path, workers: int = 1) -> list[str]:
    kwargs = [a for k, v in dataset.env_kwargs for a in ("--env-kwarg", f"{k}={v}")]
    return [
        "actionflow-record", "--task", dataset.task, "--variant", dataset.variant,
        "--episodes", str(dataset.episodes), "--seed", str(dataset.seed), "--noise", f"{dataset.noise:g}",
        *kwargs, "--repo-id", repo_id(dataset), "--root", str(root), "--workers", str(workers), "--quiet",
    ]  # fmt: skip


def train_command(training: Training, data_root: Path, out: Path) -> list[str]:
    """``lerobot-train`` with the task recipe's loader and ActionFlow settings (the model's and the
    profile's flags after them), the training's steps, batch size and checkpoints."""
    steps = training.steps
    recipe = task_recipe(training.dataset.task)
    recipe = replace(recipe, train=replace(recipe.train, batch_size=training.batch_size))
    extra = [*training.flags, f"--save_freq={max(steps // training.checkpoints, 1)}",
             f"--log_freq={max(steps // 20, 1)}"]  # fmt: skip
    return recipe_commands.train_command(
        recipe, repo_id(training.dataset), data_root, out, steps=steps, device=training.device,
        seed=training.seed, policy_type=training.policy_type, extra=extra,
    )  # fmt: skip


def env_flags(cell: Cell) -> list[str]:
    """``--env.*`` flags that make ``lerobot-eval``'s env the recorded one (task, layout, env keywords)."""
    kwargs = [f"--env.{k}={v}" for k, v in cell.dataset.env_kwargs]
    task, variant = cell.dataset.task, cell.eval_variant
    return ["--env.type=actionflow", f"--env.task={task}-v0", f"--env.variant={variant}", *kwargs]


def eval_command(cell: Cell, checkpoint: Path, out: Path) -> list[str]:
    device = cell.training.device if cell.training else "cpu"
    recipe = task_recipe(cell.dataset.task)
    recipe = replace(recipe, eval=replace(recipe.eval, layouts=cell.layouts))
    return recipe_commands.eval_command(
        recipe, cell.eval_variant, checkpoint, out, env_kwargs=dict(cell.dataset.env_kwargs),
        episodes=cell.episodes, batch_size=cell.batch_size, device=device, extra=cell.eval_flags,
    )  # fmt: skip


def replay_command(cell: Cell, data_root: Path, out: Path) -> list[str]:
    offset = f"{cell.replay_offset_mm:g}"
    return [sys.executable, "-m", REPLAY_MODULE, "--root", str(data_root), "--offset-mm", offset,
            "--out", str(out)]  # fmt: skip


# ---------------------------------------------------------------------------- seeds
MAX_TRIES_PER_EPISODE = 3
"""Planning bound on the seeds a recording tries per kept episode (the experts succeed on 99-100 %)."""


def eval_seeds(episodes: int, batch_size: int, layouts: str = "dev") -> range:
    """The layouts ``lerobot-eval --seed=S`` resets (``S`` the first seed of ``layouts``, 100000 or 200000):
    it steps whole batches of envs seeded ``S + i`` and keeps the first ``episodes``, so the last batch's
    extra envs count too."""
    first = LAYOUTS[layouts]
    return range(first, first + math.ceil(episodes / batch_size) * batch_size)


def planned_record_seeds(dataset: Dataset) -> range:
    return range(dataset.seed, dataset.seed + MAX_TRIES_PER_EPISODE * dataset.episodes)


def check_disjoint(recorded: Iterable[int], evaluated: range, what: str) -> None:
    """Raise if a recorded layout (seed) would also be evaluated: the success would be on training data."""
    shared = sorted(set(recorded) & set(evaluated))
    if shared:
        raise ValueError(
            f"{what}: seeds {shared[:5]}{'...' if len(shared) > 5 else ''} are both recorded and evaluated; "
            f"evaluation uses seeds {evaluated.start}-{evaluated.stop - 1} "
            f"(lerobot-eval --seed={evaluated.start}): "
            "record from a lower --seed or with fewer episodes"
        )


def check_plan(cells: Iterable[Cell]) -> None:
    """Before anything runs: no cell's evaluation may reach the seeds its dataset may record."""
    for cell in cells:
        if cell.training is not None:
            evaluated = eval_seeds(cell.episodes, cell.batch_size, cell.layouts)
            check_disjoint(planned_record_seeds(cell.dataset), evaluated, cell.key)


def recorded_seeds(data_root: Path) -> list[int]:
    """Every seed the recording tried (kept or failed), from its log."""
    from lerobot_actionflow.tools.record.log import RecordingLog

    log = RecordingLog.load(data_root)
    if log is None:
        raise FileNotFoundError(f"{data_root} has no recording log; record it with actionflow-record first")
    return log.kept_seeds + log.failed_seeds
