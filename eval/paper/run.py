"""Running a cell of the paper benchmark: record its dataset, train its model, evaluate, write its JSON.

Each stage is resumable on its own and never leaves a half result where a finished one is expected:
- a dataset is recorded in place by ``actionflow-record``, which resumes an interrupted recording itself; a
  marker file beside it (``<key>.json``) says it is complete, so later cells skip even the command;
- a training writes to ``<key>.partial`` (deleted first if an earlier run was interrupted) and is renamed to
  ``<key>`` when ``lerobot-train`` has finished;
- a cell's JSON is written to a temporary file and renamed: it exists only for a finished cell, and a cell
  whose JSON exists is never run again.

A cell's JSON holds its commands as portable shell lines (console scripts by their bare names, paths relative
to the working directory) and the provenance of the process that ran it (commit, packages, machine).
"""

from __future__ import annotations

import json
import math
import shutil
import time
from pathlib import Path

from eval.paper.commands import (
    check_disjoint,
    eval_command,
    eval_seeds,
    record_command,
    recorded_seeds,
    replay_command,
    train_command,
)
from eval.paper.plan import Cell, Dataset, Paths, Training
from eval.provenance import portable_command, provenance
from lerobot_actionflow.tools.run import run


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` so that ``path`` is either absent or complete (a kill leaves only a ``.tmp``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    tmp.replace(path)


def _shell(cmd: list[str], swap: tuple[Path, Path] | None = None) -> str:
    """A command as a portable shell line; ``swap`` replaces a temporary output folder with the final one."""
    if swap:
        cmd = [arg.replace(str(swap[0]), str(swap[1])) for arg in cmd]
    return portable_command(cmd)


def _threads(device: str) -> dict[str, str]:
    # On a small CPU the trainer shares the cores with its loader worker: one thread each (README).
    return {"OMP_NUM_THREADS": "1"} if device == "cpu" else {}


def record(dataset: Dataset, paths: Paths, workers: int = 1) -> dict:
    """Record ``dataset`` unless its marker says it is complete; the marker holds the command and seeds."""
    root = paths.data(dataset)
    marker = root.with_name(root.name + ".json")
    if marker.is_file():
        return json.loads(marker.read_text())
    cmd = record_command(dataset, root, workers)
    start = time.time()
    run(cmd, log=paths.log(f"record_{dataset.key}"))
    seeds = recorded_seeds(root)
    info = {"command": _shell(cmd), "seconds": round(time.time() - start, 1),
            "seeds_tried": [min(seeds), max(seeds)], "n_seeds_tried": len(seeds)}  # fmt: skip
    write_json(marker, info)
    return info


def train(training: Training, paths: Paths) -> dict:
    """Train unless the finished training folder exists; returns its command, time and folder."""
    out = paths.train(training)
    done = out / "paper_training.json"
    if done.is_file():
        return json.loads(done.read_text())
    partial = out.with_name(out.name + ".partial")
    for stale in (partial, out):  # an interrupted run: start it again from nothing
        if stale.exists():
            shutil.rmtree(stale)
    cmd = train_command(training, paths.data(training.dataset), partial)
    start = time.time()
    run(cmd, log=paths.log(f"train_{training.key}"), **_threads(training.device))
    info = {"command": _shell(cmd, (partial, out)), "seconds": round(time.time() - start, 1)}
    write_json(partial / "paper_training.json", info)
    partial.rename(out)
    return info


def checkpoints(train_dir: Path) -> dict[int, Path]:
    """The saved checkpoints of a training by step (``checkpoints/<step>/pretrained_model``)."""
    found = {
        int(p.name): p / "pretrained_model" for p in (train_dir / "checkpoints").iterdir() if p.name.isdigit()
    }
    if not found:
        raise FileNotFoundError(f"{train_dir}/checkpoints holds no step folder; did lerobot-train save?")
    return dict(sorted(found.items()))


def _evaluate(cell: Cell, paths: Paths) -> dict:
    """Every saved checkpoint of the cell's training through ``lerobot-eval``: the last is the reported
    number; with several, the best of them is added (the published protocols' best-of-evaluations).

    The checkpoints are evaluated after training rather than by ``lerobot-train --env_eval_freq``: LeRobot's
    evaluation during training seeds its envs from the training ``--seed`` (1, 2, 3...), which are seeds the
    recordings used, so its layouts would be training layouts."""
    assert cell.training is not None
    train_info = train(cell.training, paths)
    out = paths.eval(cell)
    if out.exists():
        shutil.rmtree(out)
    periodic, commands, seconds = {}, {}, 0.0
    for step, ckpt in checkpoints(paths.train(cell.training)).items():
        cmd = eval_command(cell, ckpt, out / str(step))
        start = time.time()
        run(cmd, log=paths.log(f"eval_{cell.key}"), **_threads(cell.training.device))
        seconds += time.time() - start
        overall = json.loads((out / str(step) / "eval_info.json").read_text())["overall"]
        periodic[step] = {"success": overall["pc_success"] / 100, "n": overall["n_episodes"]}
        commands[step] = _shell(cmd)
    last = max(periodic)
    best = max(periodic, key=lambda s: (periodic[s]["success"], s))
    result = {"success": periodic[last]["success"], "n_episodes": periodic[last]["n"],
              "commands": {"train": train_info["command"], "eval": commands[last]},
              "seconds": {"train": train_info["seconds"], "eval": round(seconds, 1)}}  # fmt: skip
    if len(periodic) > 1:
        result["periodic"] = {str(s): v["success"] for s, v in periodic.items()}
        label = f"best of {len(periodic)} evaluations during training"
        result["best_of_periodic"] = {"success": periodic[best]["success"], "step": best, "label": label}
    return result


def _replay(cell: Cell, paths: Paths) -> dict:
    out = paths.eval(cell) / "replay.json"
    cmd = replay_command(cell, paths.data(cell.dataset), out)
    start = time.time()
    run(cmd, log=paths.log(f"replay_{cell.key}"))
    info = json.loads(out.read_text())
    return {"success": info["success"], "n_episodes": info["n"], "commands": {"replay": _shell(cmd)},
            "seconds": {"replay": round(time.time() - start, 1)}}  # fmt: skip


def run_cell(cell: Cell, paths: Paths, workers: int = 1, harness_command: str = "") -> tuple[dict, bool]:
    """The cell's result, and whether it ran now (False: its JSON existed and nothing was run)."""
    path = paths.cell(cell)
    if path.is_file():
        return json.loads(path.read_text()), False
    data = record(cell.dataset, paths, workers)
    seeds = eval_seeds(cell.episodes, cell.batch_size, cell.layouts)
    if cell.training is not None:  # a replay is on the recorded layouts by definition
        check_disjoint(recorded_seeds(paths.data(cell.dataset)), seeds, cell.key)
    body = _evaluate(cell, paths) if cell.training is not None else _replay(cell, paths)
    body["commands"] = {"record": data["command"], **body["commands"]}
    body["seconds"] = {"record": data["seconds"], **body["seconds"]}
    training, dataset = cell.training, cell.dataset
    result = {
        "experiment": cell.experiment, "profile": cell.profile, "group": cell.group, "task": dataset.task,
        "variant": dataset.variant, "demos": dataset.episodes, "env_kwargs": dict(dataset.env_kwargs),
        "model": cell.model, "note": cell.note, "eval_variant": cell.eval_variant, "k": cell.k,
        "schedule": cell.schedule, "replay_offset_mm": cell.replay_offset_mm,
        "steps": training and training.steps, "batch_size": training and training.batch_size,
        "seed": training and training.seed, "device": training.device if training else "cpu",
        "record_seeds": data["seeds_tried"], "layouts": None if training is None else cell.layouts,
        "eval_seeds": None if training is None else [seeds.start, seeds.start + cell.episodes - 1],
        **body, "harness_command": harness_command, "key": cell.key, "provenance": provenance(),
    }  # fmt: skip
    if not math.isfinite(result["success"]):
        raise ValueError(f"{cell.key}: success {result['success']}; expected a rate in [0, 1]")
    write_json(path, result)
    return result, True
