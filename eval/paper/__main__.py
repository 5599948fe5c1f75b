"""The paper's three experiments as one resumable benchmark, through LeRobot's standard commands.

    python -m eval.paper sample-efficiency [--profile cpu|gpu|smoke] [--tasks Coffee] [--models A.1 DP]
                                           [--variants D2]              # only the groups trained on D2
                                           [--demos 50] [--seeds 1 2 3] # one dataset size, 3 trainings
    python -m eval.paper inference-steps   [--profile ...] [--tasks Threading]
    python -m eval.paper generalisation    [--profile ...] [--tasks MugHanging Lightbulb]
    python -m eval.paper report            [--profile ...]      # rebuild tables and plots from the JSON
    python -m eval.paper <experiment> --dry-run                 # list the datasets, trainings and cells
    python -m eval.paper <experiment> --layouts dev --results-dir outputs/tuning   # tuning (dev layouts)
    python -m eval.paper <experiment> --results-dir eval/results/paper   # add to the committed results
    python -m eval.paper <experiment> --executor ray [--lanes 2]         # every stage a Ray task, here
    python -m eval.paper <experiment> --executor ray --address HEAD:6379 # ... on a running Ray cluster

Experiments (the paper's claims; ``eval/paper/profiles.py`` has each profile's matrix):
- ``sample-efficiency``: ActionFlow A.1 (IPA) / A.2 (multi-token) / A.3 (single token) and LeRobot's
  Diffusion Policy against the number of demonstrations, on the MimicGen tasks (D0) and the published
  protocol (D1 / D2).
- ``inference-steps``: one training each of the SE(3) flow (A.1), the Euclidean flow and Diffusion Policy,
  evaluated at K in {1, 2, 4, 10, 100}: flows on uniform and exponential time grids
  (``lerobot-eval --policy.num_inference_steps=K --policy.time_schedule=...``), diffusion with DDIM
  (``--policy.noise_scheduler_type=DDIM --policy.num_inference_steps=K``).
- ``generalisation``: MugHanging trained on ``train`` layouts (hanger pose or hanger point cloud) and
  evaluated on ``train`` and ``test`` layouts; Lightbulb, beside replaying the demonstrations exactly and
  1.5 mm off.

Profiles: ``cpu`` (state observations, sized for a 2-core CPU, the diffusion UNet shrunk to 64-128-256 and
labelled so next to every number), ``gpu`` (1000 demonstrations, long training, 3 seeds, 10 checkpoints per
training evaluated: final and best-of reported, labelled), ``smoke`` (tiny: checks the harness in minutes).

Every cell prints and runs ``actionflow-record``, ``lerobot-train`` and ``lerobot-eval`` (their output goes to
``outputs/paper/logs/``), so any cell can be redone by hand. A dataset is recorded once for all the cells that
read it and a training once for all its evaluations. A finished cell (its JSON under
``<results-dir>/cells/<profile>/<experiment>/``) is never run again: rerun the same command after an
interruption and it continues. Each cell records the commit, package versions and machine that made it
(``eval/provenance.py``) and no absolute path.

Layouts: cells are evaluated on the held-out layouts (``lerobot-eval --seed=200000``) that no tuning
touches; ``--layouts dev`` evaluates on the development layouts (from 100000), where settings are chosen, and
is refused into the committed results. A held-out cell reuses its development twin's training (trainings do
not depend on the layouts), so re-evaluating published checkpoints costs evaluations only. Reports list
development cells apart. Evaluation seeds are checked against the seeds every recording tried, before and
after recording. Tables and plots go to
``<results-dir>/<profile>_<experiment>.{md,png}``. The results folder defaults to ``outputs/paper/results``
(git-ignored); the committed results are ``--results-dir eval/results/paper``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from eval.paper.commands import check_plan
from eval.paper.executor import EXECUTORS, plan_lanes, resolve_executor, run_local, run_ray
from eval.paper.plan import EXPERIMENTS, Cell, Paths, build
from eval.paper.profiles import MODELS, PROFILES
from eval.provenance import portable_command

PROGRAM = ("python", "-m", "eval.paper")
COMMITTED = Path(__file__).resolve().parents[1] / "results" / "paper"
"""The committed results (``--results-dir eval/results/paper``): held-out cells only from now on."""


def describe(cells: list[Cell]) -> str:
    """The plan in a few lines: what would be recorded, trained and evaluated."""
    datasets = {c.dataset for c in cells}
    trainings = {c.training for c in cells if c.training is not None}
    steps = sum(t.steps for t in trainings)
    episodes = sum(c.episodes * (c.training.checkpoints if c.training else 1) for c in cells)
    demos = sum(d.episodes for d in datasets)
    lines = [f"{len(cells)} cells: {len(datasets)} datasets ({demos} demonstrations), "
             f"{len(trainings)} trainings ({steps} steps), {episodes} evaluation episodes"]  # fmt: skip
    lines += [f"  {c.key}" for c in cells]
    return "\n".join(lines)


def run_experiment(experiment: str, args: argparse.Namespace, harness_command: str) -> list[dict]:
    profile = PROFILES[args.profile]
    cells = build(experiment, profile, args.tasks, args.models, args.steps, args.variants, args.layouts,
                  args.seeds, args.demos)
    check_plan(cells)
    resolve_executor(args.executor, args.address, args.lanes)
    print(describe(cells), flush=True)
    if args.executor == "ray" and args.address is None:
        print(plan_lanes(cells, args.lanes or os.cpu_count() or 1), flush=True)
    if args.dry_run:
        return []
    paths = Paths(args.work_dir, args.results_dir)
    workers = profile.record_workers
    if args.executor == "ray":
        done = run_ray(cells, paths, workers, harness_command, args.address, args.lanes)
    else:
        done = run_local(cells, paths, workers, harness_command)
    ran = sum(fresh for _, fresh in done)
    print(f"{experiment}: {ran} cells run now, {len(cells) - ran} already finished")
    return [result for result, _ in done]


def report(args: argparse.Namespace, experiments: tuple[str, ...]) -> None:
    from eval.paper.report import write

    command = portable_command([*PROGRAM, "report", "--profile", args.profile, *results_flag(args)])
    for experiment in experiments:
        written = write(args.results_dir, args.profile, experiment, command)
        if written:
            print(f"{experiment}: {written[0]} and {written[1]}")


def results_flag(args: argparse.Namespace) -> list[str]:
    """``--results-dir DIR`` unless it is the default, so that a printed command rebuilds the same files."""
    return [] if args.results_dir == Paths.results else ["--results-dir", str(args.results_dir)]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("experiment", choices=(*EXPERIMENTS, "report"))
    parser.add_argument("--profile", choices=sorted(PROFILES), default="cpu")
    parser.add_argument("--tasks", nargs="+", help="only these tasks (e.g. Threading Coffee)")
    parser.add_argument("--models", nargs="+", help=f"only these models, of {[*MODELS, 'replay']}")
    parser.add_argument("--variants", nargs="+", help="only the groups trained on these variants (e.g. D2)")
    parser.add_argument("--steps", type=int, help="training steps instead of the profile's")
    parser.add_argument(
        "--seeds", type=int, nargs="+",
        help="training seeds instead of the profile's (e.g. 1 2 3: each training run once per seed)",
    )  # fmt: skip
    parser.add_argument("--demos", type=int, nargs="+", help="only the datasets of this many demonstrations")
    parser.add_argument("--dry-run", action="store_true", help="print the plan and run nothing")
    parser.add_argument(
        "--layouts", choices=("heldout", "dev"), default="heldout",
        help="evaluation layouts: heldout (seeds from 200000, the published tables; default) or dev (from "
        "100000, for tuning: refused into the committed results)",
    )  # fmt: skip
    parser.add_argument(
        "--executor", choices=EXECUTORS, default="local",
        help="local: one cell after another here; ray: every stage a Ray task (eval/paper/executor.py)",
    )  # fmt: skip
    parser.add_argument("--address", help="with --executor ray: join this Ray cluster (HEAD:6379)")
    parser.add_argument(
        "--lanes", type=int,
        help="with --executor ray: the CPUs a Ray started here may use (default: all cores); with --dry-run, "
        "the lanes (GPUs) to spread the plan over",
    )  # fmt: skip
    parser.add_argument("--work-dir", type=Path, default=Paths.work, help="datasets, checkpoints, logs")
    parser.add_argument("--results-dir", type=Path, default=Paths.results, help="cells' JSON, tables, plots")
    args = parser.parse_args(argv)
    harness_command = portable_command([*PROGRAM, *(argv if argv is not None else sys.argv[1:])])
    if args.results_dir == Paths.results and not args.dry_run:
        print(f"results: {Paths.results} (the default, git-ignored); the committed ones are "
              "--results-dir eval/results/paper")
    if args.experiment == "report":
        report(args, EXPERIMENTS)
        return
    if args.layouts == "dev" and args.results_dir.resolve() == COMMITTED.resolve():
        parser.error(
            f"--layouts dev into {COMMITTED}: the development layouts are where settings are tuned, so their "
            "cells are not a published result; evaluate with --layouts heldout, or write tuning cells to "
            "another --results-dir"
        )
    try:
        run_experiment(args.experiment, args, harness_command)
    except ValueError as err:  # a bad plan (--tasks, --models) or a seed overlap: say it, run nothing more
        parser.error(str(err))
    if not args.dry_run:
        report(args, (args.experiment,))


if __name__ == "__main__":
    main()
