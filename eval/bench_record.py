"""Recording throughput of ``actionflow-record``: successful expert episodes per minute, per task.

    python eval/bench_record.py [--episodes 20] [--tasks Stack Coffee ...] [--obs-mode state]

Each task's first variant is recorded into a temporary LeRobotDataset (expert noise 1, seeds from 0), in one
process, with every episode made durable before the next (as the tool always does). Writes
``eval/results/record_cpu.md``.
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

from gym_actionflow import TASKS

from lerobot_actionflow.tools.record import Recipe, record

RESULTS = Path(__file__).parent / "results" / "record_cpu.md"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--tasks", nargs="*", default=[t.name for t in TASKS])
    parser.add_argument("--obs-mode", default="state", choices=("state", "pixels"))
    args = parser.parse_args()

    rows = []
    for name in args.tasks:
        task = next(t for t in TASKS if t.name == name)
        recipe = Recipe(
            task=name, variant=task.variants[0], episodes=args.episodes, repo_id=f"bench/{name}",
            obs_mode=args.obs_mode,
        )  # fmt: skip
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            result = record(recipe, root=Path(tmp) / name, progress=False)
            seconds = time.perf_counter() - start
        log = result.log
        per_min = 60 * result.episodes / seconds
        rows.append((name, task.variants[0], result.episodes, len(log.failed_seeds), seconds, per_min))
        print(
            f"{name}: {result.episodes} episodes in {seconds:.1f} s = {per_min:.1f} episodes/min", flush=True
        )

    lines = [
        f"# actionflow-record throughput ({args.obs_mode} observations)",
        "",
        f"`python eval/bench_record.py --episodes {args.episodes} --obs-mode {args.obs_mode}` on "
        f"{platform.processor() or platform.machine()}, one process. Expert noise 1; failed seeds are tried "
        "and dropped, and their time is included.",
        "",
        "| task | variant | episodes kept | failed seeds | seconds | episodes/min |",
        "|---|---|---|---|---|---|",
    ]
    lines += [f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4]:.1f} | {r[5]:.1f} |" for r in rows]
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    out = RESULTS if args.obs_mode == "state" else RESULTS.with_name("record_pixels_cpu.md")
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
