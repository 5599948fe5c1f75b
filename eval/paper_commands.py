"""The command lines of a cell's stages (``actionflow-record``, ``lerobot-train``, ``lerobot-eval``, and the
replay baseline) and the seed rule that keeps evaluated layouts apart from recorded ones.

The commands are the main job's (``lerobot_actionflow/tools/demo.py``: its loader flags and first evaluation
seed), so a cell printed by the harness can be pasted and run by hand.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable
from pathlib import Path

from paper_plan import Cell, Dataset, Training

from lerobot_actionflow.tools.demo import EVAL_SEED, cli, loader_flags

REPLAY_SCRIPT = Path(__file__).resolve().parent / "paper_replay.py"


def repo_id(dataset: Dataset) -> str:
    return f"paper/{dataset.key}"


def record_command(dataset: Dataset, root: Path, workers: int = 1) -> list[str]:
    kwargs = [a for k, v in dataset.env_kwargs for a in ("--env-kwarg", f"{k}={v}")]
    return [
        cli("actionflow-record"), "--task", dataset.task, "--variant", dataset.variant,
        "--episodes", str(dataset.episodes), "--seed", str(dataset.seed), "--noise", f"{dataset.noise:g}",
        *kwargs, "--repo-id", repo_id(dataset), "--root", str(root), "--workers", str(workers), "--quiet",
    ]  # fmt: skip


def train_command(training: Training, data_root: Path, out: Path) -> list[str]:
    """``lerobot-train`` as the main job runs it (its loader for the task, as ``--loader auto``); ActionFlow's
    cosine decay spans the run (as the README's flags), diffusion keeps LeRobot's scheduler, which spans
    ``--steps`` by itself."""
    steps = training.steps
    decay = [f"--policy.scheduler_decay_steps={steps}"] if training.policy_type == "actionflow" else []
    return [
        cli("lerobot-train"), f"--policy.type={training.policy_type}", f"--policy.device={training.device}",
        "--policy.push_to_hub=false", *training.flags, *decay,
        f"--dataset.repo_id={repo_id(training.dataset)}", f"--dataset.root={data_root}",
        *loader_flags(training.dataset.task),
        f"--steps={steps}", f"--batch_size={training.batch_size}",
        f"--save_freq={max(steps // training.checkpoints, 1)}", f"--log_freq={max(steps // 20, 1)}",
        f"--seed={training.seed}", f"--output_dir={out}",
    ]  # fmt: skip


def env_flags(cell: Cell) -> list[str]:
    """``--env.*`` flags that make ``lerobot-eval``'s env the recorded one (task, layout, env keywords)."""
    kwargs = [f"--env.{k}={v}" for k, v in cell.dataset.env_kwargs]
    task, variant = cell.dataset.task, cell.eval_variant
    return ["--env.type=actionflow", f"--env.task={task}-v0", f"--env.variant={variant}", *kwargs]


def eval_command(cell: Cell, checkpoint: Path, out: Path) -> list[str]:
    device = cell.training.device if cell.training else "cpu"
    return [
        cli("lerobot-eval"), f"--policy.path={checkpoint}", f"--policy.device={device}", *cell.eval_flags,
        *env_flags(cell), f"--eval.n_episodes={cell.episodes}", f"--eval.batch_size={cell.batch_size}",
        "--eval.use_async_envs=false", f"--seed={EVAL_SEED}", f"--output_dir={out}",
    ]  # fmt: skip


def replay_command(cell: Cell, data_root: Path, out: Path) -> list[str]:
    offset = f"{cell.replay_offset_mm:g}"
    return [
        sys.executable,
        str(REPLAY_SCRIPT),
        "--root",
        str(data_root),
        "--offset-mm",
        offset,
        "--out",
        str(out),
    ]


# ---------------------------------------------------------------------------- seeds
MAX_TRIES_PER_EPISODE = 3
"""Planning bound on the seeds a recording tries per kept episode (the experts succeed on 99-100 %)."""


def eval_seeds(episodes: int, batch_size: int) -> range:
    """The layouts ``lerobot-eval --seed=EVAL_SEED`` resets: it steps whole batches of envs seeded
    ``EVAL_SEED + i`` and keeps the first ``episodes``, so the last batch's extra envs count too."""
    return range(EVAL_SEED, EVAL_SEED + math.ceil(episodes / batch_size) * batch_size)


def planned_record_seeds(dataset: Dataset) -> range:
    return range(dataset.seed, dataset.seed + MAX_TRIES_PER_EPISODE * dataset.episodes)


def check_disjoint(recorded: Iterable[int], evaluated: range, what: str) -> None:
    """Raise if a recorded layout (seed) would also be evaluated: the success would be on training data."""
    shared = sorted(set(recorded) & set(evaluated))
    if shared:
        raise ValueError(
            f"{what}: seeds {shared[:5]}{'...' if len(shared) > 5 else ''} are both recorded and evaluated; "
            f"evaluation uses seeds {evaluated.start}-{evaluated.stop - 1} "
            f"(lerobot-eval --seed={EVAL_SEED}): "
            "record from a lower --seed or with fewer episodes"
        )


def check_plan(cells: Iterable[Cell]) -> None:
    """Before anything runs: no cell's evaluation may reach the seeds its dataset may record."""
    for cell in cells:
        if cell.training is not None:
            check_disjoint(planned_record_seeds(cell.dataset), eval_seeds(cell.episodes, cell.batch_size),
                           cell.key)  # fmt: skip


def recorded_seeds(data_root: Path) -> list[int]:
    """Every seed the recording tried (kept or failed), from its log."""
    from lerobot_actionflow.tools.record.log import RecordingLog

    log = RecordingLog.load(data_root)
    if log is None:
        raise FileNotFoundError(f"{data_root} has no recording log; record it with actionflow-record first")
    return log.kept_seeds + log.failed_seeds
