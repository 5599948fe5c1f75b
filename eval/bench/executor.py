"""The paper harness's executors side by side: one group of cells run one after another in one process
(``--executor local``) and the same group through a Ray started on this machine (``--executor ray --lanes
N``), each from nothing in its own working folder; wall time of each, and the cells each wrote.

    python -m eval.bench.executor --experiment sample-efficiency --profile cpu --tasks Threading \\
        --models A.1 --steps 200 --lanes 2 --out eval/results

Both runs are the harness's own command line (printed), run as a subprocess one after the other, so each pays
the same recording, training and evaluation; the Ray run also pays Ray's start. Same cells: the table says
whether both runs wrote the same cell keys and lists each cell's success under both (one training seed each:
equal settings, not equal numbers, since a training on another core need not be bit-identical).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

from eval.bench.output import add_out_argument, write_result
from eval.provenance import describe, portable_command


def harness_command(args: argparse.Namespace, executor: str, work: Path) -> list[str]:
    cmd = [sys.executable, "-m", "eval.paper", args.experiment, "--profile", args.profile,
           "--work-dir", str(work), "--results-dir", str(work / "results")]  # fmt: skip
    for flag, values in (("--tasks", args.tasks), ("--models", args.models), ("--variants", args.variants)):
        if values:
            cmd += [flag, *values]
    if args.steps:
        cmd += ["--steps", str(args.steps)]
    if executor == "ray":
        cmd += ["--executor", "ray", "--lanes", str(args.lanes)]
    return cmd


def run(args: argparse.Namespace, executor: str) -> tuple[float, dict[str, float], list[str]]:
    """Run the group from nothing under ``executor``: wall seconds, each cell's success and the command."""
    work = args.work / executor
    if work.exists():
        shutil.rmtree(work)
    cmd = harness_command(args, executor, work)
    print(f"\n$ {portable_command(cmd)}", flush=True)
    start = time.perf_counter()
    subprocess.run(cmd, check=True)
    wall = time.perf_counter() - start
    files = (work / "results" / "cells").rglob("*.json")
    cells = {p.stem: json.loads(p.read_text())["success"] for p in files}
    return wall, cells, cmd


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--experiment", default="sample-efficiency")
    parser.add_argument("--profile", default="cpu")
    parser.add_argument("--tasks", nargs="+", default=["Threading"])
    parser.add_argument("--models", nargs="+", default=["A.1"])
    parser.add_argument("--variants", nargs="+")
    parser.add_argument("--steps", type=int, help="training steps instead of the profile's")
    parser.add_argument("--lanes", type=int, default=2, help="CPUs of the Ray started here")
    parser.add_argument("--work", type=Path, default=Path("outputs/bench_executor"), help="working folders")
    add_out_argument(parser)
    args = parser.parse_args(argv)

    walls, cells, commands = {}, {}, {}
    for executor in ("local", "ray"):
        walls[executor], cells[executor], commands[executor] = run(args, executor)
    same = set(cells["local"]) == set(cells["ray"])
    ratio = walls["local"] / walls["ray"]
    made_by = portable_command([sys.executable, "-m", "eval.bench.executor", *(argv or sys.argv[1:])])
    lines = [
        "# The harness's executors side by side", "",
        f"One group of the `{args.profile}` profile's {args.experiment} cells, run from nothing twice on "
        "this machine, one run after the other: in one process, and through a Ray started here with "
        f"{args.lanes} lanes. Made by `{made_by}`.", "",
        "| executor | wall time (min) | cells | command |", "|---|---|---|---|",
    ]  # fmt: skip
    for executor in ("local", "ray"):
        lines.append(f"| {executor} | {walls[executor] / 60:.1f} | {len(cells[executor])} | "
                     f"`{portable_command(commands[executor])}` |")  # fmt: skip
    lines += [
        "", f"Local / Ray wall time: **{ratio:.2f}x**. Same cell keys in both runs: "
        f"{'yes' if same else 'no'}.", "",
        "| cell | success (local) | success (ray) |", "|---|---|---|",
    ]  # fmt: skip
    for key in sorted(set(cells["local"]) | set(cells["ray"])):
        local, ray = cells["local"].get(key), cells["ray"].get(key)
        rates = ["" if rate is None else f"{rate:.0%}" for rate in (local, ray)]
        lines.append(f"| {key} | {rates[0]} | {rates[1]} |")
    lines += ["", describe(), ""]
    text = "\n".join(lines)
    print("\n" + text)
    write_result(args.out, "executor_cpu.md", text)
    if not same:
        raise SystemExit("the two runs wrote different cells; see the table")


if __name__ == "__main__":
    main()
