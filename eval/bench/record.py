"""Recording cost of ``actionflow-record``: per episode as the dataset grows, with 1 and more workers, and
throughput per task.

    OMP_NUM_THREADS=1 python -m eval.bench.record [--scaling-episodes 1000] [--workers 1 2] [--episodes 20]
        [--tasks Stack Coffee ...] [--obs-mode state] [--out eval/results]

Part 1 records ``--scaling-episodes`` Stack D0 episodes into a temporary LeRobotDataset once per worker count
and times every kept episode (the moment it is journaled: one episode's simulation, wait and dataset write).
The cost per episode early and late is the mean over the first 100 episodes (from episode 1 to 101) and over
the last 100 (from episode N - 100 to the end of the recording); both windows hold checkpoints (finalize +
reopen), whose cost is also timed alone. The median interval over 10 episodes around episode 10 and episode N,
without a checkpoint, is given too, and the same means in CPU time of the recording process. Part 2 records
``--episodes`` episodes of each task's first variant with one process (``--episodes 0`` skips it). Writes
``<out>/record_cpu.md`` (``record_pixels_cpu.md`` with ``--obs-mode pixels``; default out: ``outputs/bench``).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from gym_actionflow import TASKS

from eval.bench.output import add_out_argument, write_result
from eval.provenance import describe, portable_command
from lerobot_actionflow.tools.record import Recipe, journal, record, recorder

WINDOW = 100


def timed_record(recipe: Recipe, root: Path, workers: int) -> dict:
    """Record ``recipe``; return the wall time, the wall and CPU times (of the recording process) from the
    start at which each episode was kept and the recording ended, and the cost of each checkpoint."""
    kept: list[tuple[float, float]] = []
    checkpoints: list[tuple[int, float]] = []
    write, checkpoint = journal.write, recorder._Checkpointed.checkpoint

    def write_and_time(root_: Path, episode) -> None:
        write(root_, episode)
        kept.append((time.perf_counter(), time.process_time()))

    def timed_checkpoint(self, reopen: bool) -> None:
        start = time.perf_counter()
        checkpoint(self, reopen)
        if reopen:  # the checkpoints during the recording; the last one does not reopen
            checkpoints.append((self.ds.meta.total_episodes, time.perf_counter() - start))

    journal.write, recorder._Checkpointed.checkpoint = write_and_time, timed_checkpoint
    try:
        start, cpu_start = time.perf_counter(), time.process_time()
        result = record(recipe, root=root, progress=False, workers=workers)
        end = (time.perf_counter(), time.process_time())
    finally:
        journal.write, recorder._Checkpointed.checkpoint = write, checkpoint
    times = np.asarray([*kept, end]) - [start, cpu_start]  # [episodes + 1, (wall, cpu)]
    return {"seconds": times[-1, 0], "wall": times[:, 0], "cpu": times[:, 1], "checkpoints": checkpoints,
            "failed": len(result.log.failed_seeds)}  # fmt: skip


def early_and_late(times: np.ndarray) -> tuple[float, float]:
    """Mean seconds per episode over the first and the last ``WINDOW`` episodes (``times``: at each kept
    episode, then at the end)."""
    return (times[WINDOW] - times[0]) / WINDOW, (times[-1] - times[-1 - WINDOW]) / WINDOW


def medians(wall: np.ndarray) -> tuple[float, float]:
    """Median interval between kept episodes over episodes 5..15 and the last 10."""
    return float(np.median(np.diff(wall[4:15]))), float(np.median(np.diff(wall[-12:-1])))


def scaling(episodes: int, workers: list[int], obs_mode: str) -> list[str]:
    recipe = Recipe(task="Stack", variant="D0", episodes=episodes, repo_id="bench/stack", obs_mode=obs_mode)
    rows = []
    for n in workers:
        with tempfile.TemporaryDirectory() as tmp:
            run = timed_record(recipe, Path(tmp) / "stack", n)
        early, late = early_and_late(run["wall"])
        cpu_early, cpu_late = early_and_late(run["cpu"])
        median_early, median_late = medians(run["wall"])
        (first_at, first), (last_at, last) = run["checkpoints"][0], run["checkpoints"][-1]
        rows.append(
            (n, run["seconds"], early, late, median_early, median_late, cpu_early, cpu_late, run["failed"])
        )
        print(
            f"workers {n}: {episodes} episodes in {run['seconds']:.1f} s; per episode, first {WINDOW}: "
            f"{early:.3f} s, last {WINDOW}: {late:.3f} s (ratio {late / early:.2f}); medians without "
            f"checkpoint {median_early:.3f} / {median_late:.3f} s; recording-process CPU per episode "
            f"{cpu_early:.3f} / {cpu_late:.3f} s (ratio {cpu_late / cpu_early:.2f}); "
            f"{len(run['checkpoints'])} checkpoints, {first:.2f} s at {first_at} episodes, {last:.2f} s at "
            f"{last_at}; first episode kept after {run['wall'][0]:.1f} s",
            flush=True,
        )
    lines = [
        f"## Cost per episode as the dataset grows (Stack D0, {episodes} episodes)",
        "",
        f"Mean seconds per kept episode over the first {WINDOW} episodes and over the last {WINDOW} (to the "
        "end of the recording), checkpoints included (every 50 episodes, every tenth of the dataset beyond "
        "500, and at the end). In brackets: the median over 10 episodes near episode 10 and near the last, "
        "without a checkpoint. CPU: the same means in CPU time of the recording process (less sensitive to "
        "other jobs than wall time; with workers it only writes the dataset). Wall time includes starting "
        "the workers.",
        "",
        "| workers | wall time | per episode, first 100 | per episode, last 100 | ratio | CPU, first 100 | "
        "CPU, last 100 | CPU ratio | episodes/min | failed seeds |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for n, seconds, early, late, median_early, median_late, cpu_early, cpu_late, failed in rows:
        lines.append(
            f"| {n} | {seconds:.0f} s ({seconds / 60:.1f} min) | {early:.3f} s ({median_early:.3f}) | "
            f"{late:.3f} s ({median_late:.3f}) | {late / early:.2f} | {cpu_early:.3f} s | {cpu_late:.3f} s | "
            f"{cpu_late / cpu_early:.2f} | {60 * episodes / seconds:.0f} | {failed} |"
        )
    return lines


def throughput(episodes: int, tasks: list[str], obs_mode: str) -> list[str]:
    rows = []
    for name in tasks:
        task = next(t for t in TASKS if t.name == name)
        recipe = Recipe(
            task=name, variant=task.variants[0], episodes=episodes, repo_id=f"bench/{name}", obs_mode=obs_mode
        )
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            result = record(recipe, root=Path(tmp) / name, progress=False)
            seconds = time.perf_counter() - start
        per_min = 60 * result.episodes / seconds
        rows.append((name, task.variants[0], result.episodes, len(result.log.failed_seeds), seconds, per_min))
        print(f"{name}: {result.episodes} episodes, {seconds:.1f} s, {per_min:.1f} episodes/min", flush=True)
    lines = [
        f"## Throughput per task ({episodes} episodes, one process)",
        "",
        "Expert noise 1; failed seeds are tried and dropped, and their time is included.",
        "",
        "| task | variant | episodes kept | failed seeds | seconds | episodes/min |",
        "|---|---|---|---|---|---|",
    ]
    return lines + [f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4]:.1f} | {r[5]:.1f} |" for r in rows]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--scaling-episodes", type=int, default=1000, help="0 skips part 1")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--episodes", type=int, default=20, help="per task in part 2; 0 skips it")
    parser.add_argument("--tasks", nargs="*", default=[t.name for t in TASKS])
    parser.add_argument("--obs-mode", default="state", choices=("state", "pixels"))
    add_out_argument(parser)
    args = parser.parse_args(argv)
    if args.scaling_episodes and args.scaling_episodes < 2 * WINDOW + 1:
        parser.error(f"--scaling-episodes {args.scaling_episodes}: expected 0 or at least {2 * WINDOW + 1}")

    argv = sys.argv[1:] if argv is None else argv
    threads = "OMP_NUM_THREADS=" + os.environ.get("OMP_NUM_THREADS", "")
    command = threads + " " + portable_command(["python", "-m", "eval.bench.record", *argv])
    load = os.getloadavg()
    lines = [
        f"# actionflow-record cost ({args.obs_mode} observations)",
        "",
        f"`{command}` on {platform.processor() or platform.machine()} with {os.cpu_count()} cores.",
        "",
    ]
    if args.scaling_episodes:
        lines += scaling(args.scaling_episodes, args.workers, args.obs_mode) + [""]
    if args.episodes:
        lines += throughput(args.episodes, args.tasks, args.obs_mode) + [""]
    after = os.getloadavg()
    lines.append(
        f"Load average (1 min) {load[0]:.1f} at the start and {after[0]:.1f} at the end: other jobs share "
        "the cores, so the figures are those of a contended machine."
    )
    lines += ["", describe()]
    name = "record_cpu.md" if args.obs_mode == "state" else "record_pixels_cpu.md"
    write_result(args.out, name, "\n".join(lines))


if __name__ == "__main__":
    main()
