"""``actionflow-record``: record a gym_actionflow task's scripted expert into a LeRobotDataset (format v3).

    actionflow-record --task StackThree --variant D0 --episodes 50           # -> $HF_LEROBOT_HOME/<repo id>
    actionflow-record datasets/stack_three_d0_50.toml                        # the same, from a recipe file
    actionflow-record datasets/stack_three_d0_50.toml --push-to-hub you/stack_three_d0_50

    actionflow-record datasets/stack_d0_200.toml --workers 3                  # simulate in 3 processes

Only successful expert episodes are kept; failures are counted and reported. Seeds are tried in order from
``--seed``, so a dataset is reproducible from its command, with any number of --workers. Every kept episode is
durable before the next one is simulated: it goes to a journal beside the dataset (meta/actionflow_journal/)
and the dataset is finalized every 50 episodes (every tenth of it beyond 500) and when the recording stops.
Ctrl-C, a crash or a kill keeps all of them (whatever a kill interrupts while it is written is undone), and
running the same command again resumes where the recording stopped, replaying the journal instead of
simulating those episodes again.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

from gym_actionflow import find_task

from lerobot_actionflow.tools.record.hub import check_hub_credentials, push
from lerobot_actionflow.tools.record.recipe import Recipe, load_recipe
from lerobot_actionflow.tools.record.recorder import record


def _parse_env_kwarg(text: str) -> tuple[str, Any]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"--env-kwarg {text!r}: expected KEY=VALUE")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def _workers(text: str) -> int:
    try:
        workers = int(text)
    except ValueError:
        workers = 0
    if workers < 1:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected an integer >= 1 (1 simulates in the recording process, N >= 2 in N workers)"
        )
    return workers


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="actionflow-record", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("recipe", nargs="?", type=Path, help="a recipe file (datasets/*.toml)")
    parser.add_argument("--task", help="task name, e.g. StackThree (see `python -m gym_actionflow -h`)")
    parser.add_argument(
        "--variant", help="D0 / D1 / D2, or train / test / scene_moved for MugHanging (default: the first)"
    )
    parser.add_argument("--episodes", type=int, help="successful episodes to keep")
    parser.add_argument("--seed", type=int, help="first seed (default 0)")
    parser.add_argument("--noise", type=float, help="expert noise (default 1)")
    parser.add_argument("--obs-mode", choices=("state", "pixels"), help="pixels adds the wrist camera")
    parser.add_argument(
        "--env-kwarg", action="append", type=_parse_env_kwarg, default=[], metavar="KEY=VALUE",
        help="extra gym.make keyword, repeatable (e.g. hanger_obs=point_cloud)",
    )  # fmt: skip
    parser.add_argument("--repo-id", help="dataset repo id (default: actionflow/<task>_<variant>_<episodes>)")
    parser.add_argument("--root", type=Path, help="dataset directory (default: $HF_LEROBOT_HOME/<repo id>)")
    parser.add_argument("--push-to-hub", metavar="REPO_ID", help="upload to the Hub with a dataset card")
    parser.add_argument("--private", action="store_true", help="with --push-to-hub: a private repository")
    parser.add_argument(
        "--workers", type=_workers, default=1, metavar="N",
        help="processes simulating episodes while this one writes the dataset (default 1: this process does "
        "both, taking one core and leaving the others to what else runs, e.g. training). On a free machine, "
        "use about as many as free cores; the dataset is the same for any N",
    )  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def recipe_from_args(args: argparse.Namespace, parser: argparse.ArgumentParser) -> Recipe:
    given = {
        "task": args.task, "variant": args.variant, "episodes": args.episodes, "seed": args.seed,
        "noise": args.noise, "obs_mode": args.obs_mode, "repo_id": args.repo_id,
    }  # fmt: skip
    given = {k: v for k, v in given.items() if v is not None}
    if args.env_kwarg:
        given["env_kwargs"] = dict(args.env_kwarg)
    if args.recipe is not None:
        base = asdict(load_recipe(args.recipe))
        recipe = Recipe(**(base | given | {"env_kwargs": base["env_kwargs"] | given.get("env_kwargs", {})}))
    else:
        if "task" not in given or "episodes" not in given:
            parser.error("give a recipe file, or at least --task and --episodes")
        task = find_task(given["task"])
        given.setdefault("variant", task.variants[0])
        slug = "".join("_" + c.lower() if c.isupper() else c for c in task.name).lstrip("_")
        given.setdefault("repo_id", f"actionflow/{slug}_{given['variant'].lower()}_{given['episodes']}")
        recipe = Recipe(**given)
    if args.push_to_hub:
        if args.repo_id and args.repo_id != args.push_to_hub:
            parser.error(f"--repo-id {args.repo_id} and --push-to-hub {args.push_to_hub} differ; give one")
        recipe.repo_id = args.push_to_hub
    find_task(recipe.task)
    return recipe


def main(argv: list[str] | None = None) -> int:
    # A process started in the background by a non-interactive shell inherits SIGINT ignored; Ctrl-C and
    # `kill -INT` must still stop a recording cleanly.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        recipe = recipe_from_args(args, parser)
        if args.push_to_hub:
            check_hub_credentials()
        result = record(recipe, root=args.root, progress=not args.quiet, workers=args.workers)
    except KeyboardInterrupt:
        print("\nInterrupted: every finished episode is saved; run the same command again to resume.")
        return 130
    except (ValueError, FileNotFoundError, FileExistsError, RuntimeError) as err:
        print(f"actionflow-record: error: {err}", file=sys.stderr)
        return 2
    log = result.log
    rate = f"{log.success_rate:.1%}" if log.kept_seeds or log.failed_seeds else "n/a"
    if result.kept_now == 0 and result.failed_now == 0 and not result.replayed:
        print(f"{result.episodes} episodes in {result.root}: already complete; expert success {rate}")
    else:
        per_min = 60 * result.kept_now / max(result.seconds, 1e-9)
        replayed = f", {result.replayed} replayed from the journal" if result.replayed else ""
        print(
            f"{result.episodes} episodes in {result.root} (this run: {result.kept_now} kept, "
            f"{result.failed_now} failed{replayed}, {per_min:.1f} episodes/min); expert success over all "
            f"seeds tried: {rate}"
        )
    if args.push_to_hub:
        push(recipe, result.root, private=args.private)
        print(f"pushed to https://huggingface.co/datasets/{recipe.repo_id}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
