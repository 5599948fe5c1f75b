"""``actionflow-generate`` per task and variant: the generation success rate (episodes kept / tried) from 10
expert demonstrations, beside MimicGen's published rates, and the generation speed with 1 and 2 workers.

    OMP_NUM_THREADS=1 python -m eval.bench.generate --attempts 50 --out eval/results

Sources: 10 scripted-expert demonstrations per task (noise 1, seeds from 0) on its first variant (D0;
``train`` for MugHanging), recorded under ``--sources`` if missing. Each row tries ``--attempts`` layouts
from seed 1000 (the generator's choices were tuned on seeds 0-9) in this process, without writing a dataset;
D1 / D2 and MugHanging ``test`` are generated from those D0 / ``train`` sources, as MimicGen does. The speed
rows run the real command (dataset writing included) on Stack D1 with 1 and 2 workers.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

from eval.bench.output import add_out_argument, write_result
from eval.provenance import describe, portable_command

ROWS: tuple[tuple[str, str, dict], ...] = (
    ("Stack", "D0", {}), ("Stack", "D1", {}),
    ("StackThree", "D0", {}), ("StackThree", "D1", {}),
    ("ThreePieceAssembly", "D0", {}), ("ThreePieceAssembly", "D1", {}), ("ThreePieceAssembly", "D2", {}),
    ("Coffee", "D0", {}), ("Coffee", "D1", {}), ("Coffee", "D2", {}),
    ("Threading", "D0", {}), ("Threading", "D1", {}), ("Threading", "D2", {}),
    ("MugHanging", "train", {"mug_yaw": "slight"}), ("MugHanging", "test", {"mug_yaw": "slight"}),
    ("Lightbulb", "D0", {}), ("Lightbulb", "D0", {"socket_fit": "paper"}),
    ("RobosuiteLift", "D0", {}), ("RobosuiteCan", "D0", {}), ("RobosuiteSquare", "D0", {}),
    ("RobosuiteToolHang", "D0", {}),
)  # fmt: skip
"""(task, variant, env keywords) of each row; sources are recorded on the task's first variant."""
SOURCE_ENV = {"MugHanging": {"mug_yaw": "slight"}}
"""Env keywords of a task's source recording (MugHanging: the paper's protocol)."""
MIMICGEN = {
    ("Stack", "D0"): 94.3, ("Stack", "D1"): 90.0, ("StackThree", "D0"): 71.3, ("StackThree", "D1"): 68.9,
    ("ThreePieceAssembly", "D0"): 35.6, ("ThreePieceAssembly", "D1"): 35.5,
    ("ThreePieceAssembly", "D2"): 31.3,
    ("Coffee", "D0"): 78.2, ("Coffee", "D1"): 63.5, ("Coffee", "D2"): 27.7,
    ("Threading", "D0"): 51.0, ("Threading", "D1"): 39.2, ("Threading", "D2"): 21.6,
}  # fmt: skip
"""MimicGen's data generation rates (%), its paper's appendix Table P.1 (arXiv 2310.17596v1) as quoted by
summaries of the paper (robosuite, 10 human source demonstrations, nearest-neighbour source selection on
Stack and Stack Three); not read from the paper itself here."""
FIRST_SEED = 1000


def source_root(sources: Path, task: str) -> Path:
    """The task's 10-demonstration source, recorded by ``actionflow-record`` if it is not there."""
    from gym_actionflow import find_task

    root = sources / f"src_{task}"
    if not (root / "meta" / "info.json").is_file():
        kwargs = [a for k, v in SOURCE_ENV.get(task, {}).items() for a in ("--env-kwarg", f"{k}={v}")]
        cmd = [str(Path(sys.executable).parent / "actionflow-record"), "--task", task,
               "--variant", find_task(task).variants[0], "--episodes", "10", "--seed", "0", "--noise", "1",
               *kwargs, "--repo-id", f"local/src_{task}", "--root", str(root), "--quiet"]  # fmt: skip
        print(f"$ {portable_command(cmd)}", flush=True)
        subprocess.run(cmd, check=True)
    return root


def rate(task: str, variant: str, env_kwargs: dict, source_dir: Path, attempts: int) -> tuple[int, float]:
    """Successes over ``attempts`` generated episodes from seed :data:`FIRST_SEED`, and seconds per try."""
    import gymnasium as gym
    from gym_actionflow import find_task

    from lerobot_actionflow.tools.generate import load_source, run_generated

    source = load_source(source_dir, task)
    spec = find_task(task)
    env = gym.make(spec.env_id, **spec.kwargs(variant), **env_kwargs)
    start = time.perf_counter()
    kept = sum(run_generated(env, source, seed)[0] for seed in range(FIRST_SEED, FIRST_SEED + attempts))
    env.close()
    return kept, (time.perf_counter() - start) / attempts


def speed(
    source_dir: Path, work: Path, workers: int, episodes: int, executor: str = "local"
) -> tuple[float, str]:
    """Generated episodes per minute of the real command (Stack D1), dataset writing included; with
    ``executor="ray"`` simulated by Ray actors (Ray's start-up included)."""
    name = f"speed_{'ray' if executor == 'ray' else 'w'}{workers}"
    root = work / name
    if root.exists():
        import shutil

        shutil.rmtree(root)
    cmd = [str(Path(sys.executable).parent / "actionflow-generate"), str(source_dir), "--task", "Stack",
           "--variant", "D1", "--episodes", str(episodes), "--seed", str(FIRST_SEED),
           "--workers", str(workers), "--repo-id", f"local/{name}", "--root", str(root),
           "--quiet"]  # fmt: skip
    if executor != "local":
        cmd += ["--executor", executor]
    print(f"$ {portable_command(cmd)}", flush=True)
    start = time.perf_counter()
    subprocess.run(cmd, check=True)
    return episodes / ((time.perf_counter() - start) / 60), portable_command(cmd)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--attempts", type=int, default=50, help="generated episodes tried per row")
    parser.add_argument("--speed-episodes", type=int, default=50, help="episodes of each speed run")
    parser.add_argument("--tasks", nargs="+", help="only these tasks")
    parser.add_argument("--sources", type=Path, default=Path("outputs/gen"), help="source datasets' folder")
    parser.add_argument(
        "--source", action="append", default=[], metavar="TASK=PATH",
        help="generate TASK from this dataset instead of its expert source (e.g. a policy's rollouts, "
        "recorded by actionflow-record --policy); repeatable",
    )  # fmt: skip
    parser.add_argument(
        "--parts", nargs="+", choices=("rates", "speed"), default=["rates", "speed"],
        help="the generation rates per task, the speed with 1 and 2 workers, or both (default)",
    )  # fmt: skip
    parser.add_argument(
        "--ray", action="store_true", help="the speed part also runs 2 Ray actors (--executor ray; needs Ray)"
    )
    add_out_argument(parser)
    args = parser.parse_args(argv)
    given = dict(text.split("=", 1) for text in args.source)

    made_by = portable_command([sys.executable, "-m", "eval.bench.generate", *(argv or sys.argv[1:])])
    lines = [
        "# Generating demonstrations (actionflow-generate)", "",
        f"Made by `{made_by}`. Sources: 10 scripted-expert demonstrations per task (noise 1, seeds 0-9) on "
        f"its first variant; each row tries {args.attempts} layouts from seed {FIRST_SEED}, generated from "
        "those sources (D1 / D2 and MugHanging `test` from D0 / `train` sources). MimicGen's column: its "
        "paper's appendix Table P.1 as quoted by summaries of the paper (robosuite, 10 *human* source "
        "demonstrations), not read from the paper here.", "",
        *[f"Source of {task} instead: `{path}`." for task, path in given.items()], "",
    ]  # fmt: skip
    if "rates" in args.parts:
        lines += ["| task | variant | env keywords | kept / tried | generation rate | MimicGen | s per try |",
                  "|---|---|---|---|---|---|---|"]  # fmt: skip
    for task, variant, env_kwargs in ROWS if "rates" in args.parts else ():
        if args.tasks and task not in args.tasks:
            continue
        source = Path(given[task]) if task in given else source_root(args.sources, task)
        kept, seconds = rate(task, variant, env_kwargs, source, args.attempts)
        published = MIMICGEN.get((task, variant))
        keywords = ", ".join(f"{k}={v}" for k, v in env_kwargs.items()) or "-"
        theirs = f"{published:g} %" if published else ""
        lines.append(f"| {task} | {variant} | {keywords} | {kept} / {args.attempts} | "
                     f"{kept / args.attempts:.0%} | {theirs} | {seconds:.2f} |")  # fmt: skip
        print(lines[-1], flush=True)
    if "speed" in args.parts and (not args.tasks or "Stack" in args.tasks):
        lines += ["", "| workers | generated episodes / min (Stack D1, dataset written) | command |",
                  "|---|---|---|"]  # fmt: skip
        stack = source_root(args.sources, "Stack")
        runs = [(1, "local"), (2, "local")] + [(2, "ray")] * args.ray
        for workers, executor in runs:
            per_min, cmd = speed(stack, args.sources, workers, args.speed_episodes, executor)
            label = f"{workers} Ray actors" if executor == "ray" else str(workers)
            lines.append(f"| {label} | {per_min:.0f} | `{cmd}` |")
            print(lines[-1], flush=True)
    lines += ["", describe(), ""]
    name = "generate_speed_cpu.md" if args.parts == ["speed"] else "generate_cpu.md"
    write_result(args.out, name, "\n".join(lines))


if __name__ == "__main__":
    main()
