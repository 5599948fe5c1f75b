"""Who runs a plan's cells: this process, one cell after another (``local``, the default), or Ray (``ray``),
which runs every dataset, training and evaluation as a task of its own on as many lanes as it has.

With Ray each stage is a task that asks for what it uses: a recording ``--workers`` CPUs, a training or an
evaluation one CPU thread on ``cpu`` (the one-thread setting of every figure here) or one CPU and one GPU on
``cuda``. A training waits for its dataset, a cell for its training (a replay cell for its dataset), and each
is recorded or trained once however many cells read it. The stages are the local run's own functions
(:mod:`eval.paper.run`), so a cluster resumes exactly as one process does and writes the same JSON: a
finished dataset, training or cell is never redone, and a cell whose JSON exists is not even scheduled.

``--address`` joins a running cluster (``ray start --head`` on one node, ``ray start --address=HEAD:6379`` on
the others); without it Ray starts on this machine with ``--lanes`` CPUs (default: all cores) and stops at
the end. On a cluster every node needs this repository installed and the working and results folders on a
shared filesystem at the same path: tasks run in the submitting process's working folder.
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Sequence

from tqdm import tqdm

from eval.paper.plan import Cell, Dataset, Paths, Training

EXECUTORS = ("local", "ray")
INSTALL_RAY = 'pip install -e ".[ray]"'


def run_local(
    cells: Sequence[Cell], paths: Paths, workers: int, harness_command: str
) -> list[tuple[dict, bool]]:
    """Each cell in order in this process: its result and whether it ran now (False: its JSON existed)."""
    from eval.paper.run import run_cell  # imports LeRobot: not needed for --dry-run

    done = []
    bar = tqdm(cells, desc=cells[0].experiment if cells else "cells", unit="cell", file=sys.stdout)
    for cell in bar:
        bar.set_postfix_str(cell.key[:60])
        done.append(run_cell(cell, paths, workers, harness_command))
    bar.close()
    return done


# ---------------------------------------------------------------------------- Ray
def _enter(cwd: str) -> None:
    """Run a task in the submitting process's working folder, where the plan's relative paths point."""
    try:
        os.chdir(cwd)
    except OSError as err:
        raise RuntimeError(
            f"working folder {cwd} is not on this node ({err}); a cluster needs the working and results "
            "folders on a shared filesystem at the same path on every node"
        ) from err


def _record_stage(cwd: str, dataset: Dataset, paths: Paths, workers: int) -> dict:
    from eval.paper.run import record

    _enter(cwd)
    return record(dataset, paths, workers)


def _train_stage(cwd: str, training: Training, paths: Paths, _dataset: dict) -> dict:
    from eval.paper.run import train

    _enter(cwd)
    return train(training, paths)


def _cell_stage(cwd: str, cell: Cell, paths: Paths, workers: int, harness_command: str, _upstream: dict):
    from eval.paper.run import run_cell

    _enter(cwd)
    return run_cell(cell, paths, workers, harness_command)


def needs(device: str) -> dict[str, float]:
    """The Ray resources of a training or an evaluation on ``device``: one CPU thread, and a GPU on cuda."""
    return {"num_cpus": 1, "num_gpus": 1} if device.startswith("cuda") else {"num_cpus": 1}


def _import_ray():
    try:
        import ray
    except ModuleNotFoundError as err:
        raise RuntimeError(f"--executor ray needs Ray, an optional extra: {INSTALL_RAY}") from err
    return ray


def run_ray(
    cells: Sequence[Cell],
    paths: Paths,
    workers: int,
    harness_command: str,
    address: str | None = None,
    lanes: int | None = None,
) -> list[tuple[dict, bool]]:
    """Every cell as Ray tasks in dependency order; the results in the order of ``cells``.

    A failed stage fails the cells that need it; the others still run, and the failures are raised together
    at the end, each with its cell's key and the end of its log."""
    import json

    ray = _import_ray()
    if address is not None and lanes is not None:
        raise ValueError("--lanes sizes a Ray started here; with --address the cluster says what it has")
    started_here = not ray.is_initialized()
    if started_here:
        local = {"num_cpus": lanes or os.cpu_count()} if address is None else {}
        ray.init(address=address, include_dashboard=False, log_to_driver=False, logging_level=logging.WARNING,
                 **local)  # fmt: skip
    try:
        cwd = os.getcwd()
        results: dict[int, tuple[dict, bool]] = {}
        pending: dict = {}
        datasets: dict[Dataset, object] = {}
        trainings: dict[Training, object] = {}
        record_task = ray.remote(_record_stage).options(num_cpus=workers)
        for i, cell in enumerate(cells):
            path = paths.cell(cell)
            if path.is_file():
                results[i] = (json.loads(path.read_text()), False)
                continue
            if cell.dataset not in datasets:
                datasets[cell.dataset] = record_task.remote(cwd, cell.dataset, paths, workers)
            upstream = datasets[cell.dataset]
            device = "cpu"
            if cell.training is not None:
                device = cell.training.device
                if cell.training not in trainings:
                    train_task = ray.remote(_train_stage).options(**needs(device))
                    trainings[cell.training] = train_task.remote(cwd, cell.training, paths, upstream)
                upstream = trainings[cell.training]
            cell_task = ray.remote(_cell_stage).options(**needs(device))
            pending[cell_task.remote(cwd, cell, paths, workers, harness_command, upstream)] = i
        failures: list[str] = []
        bar = tqdm(total=len(cells), initial=len(results), desc="cells (ray)", unit="cell", file=sys.stdout)
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            i = pending.pop(ready[0])
            try:
                results[i] = ray.get(ready[0])
            except Exception as err:  # a stage raised: keep the others running, report it at the end
                failures.append(f"{cells[i].key}: {getattr(err, 'cause', None) or err}")
            bar.set_postfix_str(cells[i].key[:60])
            bar.update()
        bar.close()
    finally:
        if started_here:
            ray.shutdown()
    if failures:
        raise RuntimeError(f"{len(failures)} of {len(cells)} cells failed:\n" + "\n\n".join(failures))
    return [results[i] for i in range(len(cells))]


def plan_lanes(cells: Sequence[Cell], lanes: int) -> str:
    """How the plan spreads over ``lanes`` GPUs or CPU lanes, in training steps and evaluation episodes (the
    units a reader turns into hours with their own machine's rates)."""
    trainings = sorted({c.training for c in cells if c.training is not None}, key=lambda t: -t.steps)
    loads = [0] * lanes
    for training in trainings:  # longest first onto the least loaded lane: a bound a scheduler can reach
        loads[loads.index(min(loads))] += training.steps
    episodes = sum(c.episodes * (c.training.checkpoints if c.training else 1) for c in cells)
    devices = sorted({t.device for t in trainings}) or ["cpu"]
    return (
        f"on {lanes} lane{'' if lanes == 1 else 's'} ({', '.join(devices)}): {len(trainings)} trainings, "
        "the busiest lane trains "
        f"{max(loads)} steps of {sum(loads)} in all; {episodes} evaluation episodes, {-(-episodes // lanes)} "
        "per lane"
    )


def resolve_executor(name: str, address: str | None, lanes: int | None) -> None:
    """Refuse a flag combination that cannot mean anything, before the plan runs."""
    if name not in EXECUTORS:
        raise ValueError(f"--executor {name!r}; expected one of {EXECUTORS}")
    if name == "local" and (address is not None or lanes is not None):
        raise ValueError("--address and --lanes are for --executor ray")
    if lanes is not None and lanes < 1:
        raise ValueError(f"--lanes {lanes}; expected at least 1")
