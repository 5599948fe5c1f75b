"""``actionflow-record``: record a gym_actionflow task's scripted expert into a LeRobotDataset (format v3).

    actionflow-record --task StackThree --variant D0 --episodes 50           # -> $HF_LEROBOT_HOME/<repo id>
    actionflow-record datasets/stack_three_d0_50.toml                        # the same, from a recipe file
    actionflow-record datasets/stack_three_d0_50.toml --push-to-hub you/stack_three_d0_50

    actionflow-record datasets/stack_d0_200.toml --workers 3                  # simulate in 3 processes
    actionflow-record datasets/stack_d0_200.toml --executor ray --workers 64 --address HEAD:6379  # a cluster
    actionflow-record datasets/stack_d0_lerobot_100.toml                      # LeRobot layout, 2 cameras
    actionflow-record push ~/.cache/huggingface/lerobot/actionflow/stack_d0_200 --to you/stack_d0_200
    actionflow-record --task Stack --episodes 10 --policy outputs/train/checkpoints/last/pretrained_model

Only successful expert episodes are kept; failures are counted and reported. Seeds are tried in order from
``--seed``, so a dataset is reproducible from its command, with any number of --workers, here or as Ray actors
(--executor ray). Every kept episode is durable before the next one is simulated: it goes to a journal beside
the dataset (meta/actionflow_journal/) and the dataset is finalized every 50 episodes (every tenth of it
beyond 500) and when the recording stops. Ctrl-C, a crash or a kill keeps all of them (whatever a kill
interrupts while it is written is undone), and running the same command again resumes where the recording
stopped, replaying the journal instead of simulating those episodes again.

Every flag and recipe field is checked before anything is written. The folder holds its dataset card
(README.md) from the moment the recording stops; `push ROOT --to REPO_ID` uploads the folder as it is, card
included, to a Hub dataset repo (also what --push-to-hub does after recording). The Hub repo is where a copy
goes, not part of the recording: pushing changes nothing local.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

from lerobot_actionflow.tools.record.hub import check_hub_credentials, check_pushable, push
from lerobot_actionflow.tools.record.recipe import Recipe, check_fields, load_recipe, recipe_label
from lerobot_actionflow.tools.record.recorder import record
from lerobot_actionflow.tools.record.simulate import EXECUTORS

PROG = "actionflow-record"
FLAGS = {
    "task": "--task", "variant": "--variant", "episodes": "--episodes", "seed": "--seed", "noise": "--noise",
    "obs_mode": "--obs-mode", "obs_layout": "--obs-layout", "cameras": "--cameras", "repo_id": "--repo-id",
    "image_storage": "--image-storage", "policy": "--policy",
}  # fmt: skip
"""Recipe field -> the flag that sets it, to name the flag in an error about its value."""
INPUT_ERRORS = (ValueError, FileNotFoundError, FileExistsError, RuntimeError)
"""What a bad input raises: a one-line error and exit code 2, no traceback."""


def _parse_env_kwarg(text: str) -> tuple[str, Any]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"got {text!r}; expected KEY=VALUE")
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


def _repo_id(text: str) -> str:
    from huggingface_hub.utils import validate_repo_id

    try:
        validate_repo_id(text)
    except Exception:  # HFValidationError
        raise argparse.ArgumentTypeError(
            f"got {text!r}; expected a Hub repo id such as you/stack_d0_200 (letters, digits, '-', '_', '.')"
        ) from None
    return text


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"`{PROG} push -h` tells how to upload a recorded dataset.",
    )  # fmt: skip
    parser.add_argument("recipe", nargs="?", type=Path, help="a recipe file (datasets/*.toml)")
    parser.add_argument("--task", help="task name, e.g. StackThree (see `python -m gym_actionflow -h`)")
    parser.add_argument(
        "--variant", help="D0 / D1 / D2, or train / test / scene_moved for MugHanging (default: the first)"
    )
    parser.add_argument("--episodes", type=int, help="successful episodes to keep (>= 1)")
    parser.add_argument("--seed", type=int, help="first seed (>= 0, default 0)")
    parser.add_argument("--noise", type=float, help="expert noise (finite, >= 0; default 1)")
    parser.add_argument("--obs-mode", choices=("state", "pixels"), help="pixels adds the cameras")
    parser.add_argument(
        "--obs-layout", choices=("tokens", "lerobot"),
        help="tokens (default: token keys, observation.state, object poses) or lerobot (observation.state "
        "and observation.images.* only, a plain LeRobot dataset; needs --obs-mode pixels)",
    )  # fmt: skip
    parser.add_argument(
        "--cameras", nargs="+", metavar="CAMERA",
        help="with --obs-mode pixels: the cameras, from front (static) and wrist (default: wrist)",
    )  # fmt: skip
    parser.add_argument(
        "--image-storage", choices=("image", "video"),  # schema.IMAGE_STORAGES (imports torch)
        help="with --obs-mode pixels: image (default: PNG frames in small parquet files, fast to train from "
        "with --dataset.streaming=true) or video (smaller AV1 files, decoded at every sample)",
    )  # fmt: skip
    parser.add_argument(
        "--env-kwarg", action="append", type=_parse_env_kwarg, default=[], metavar="KEY=VALUE",
        help="extra gym.make keyword, repeatable (e.g. hanger_obs=point_cloud)",
    )  # fmt: skip
    parser.add_argument(
        "--policy", metavar="CHECKPOINT",
        help="record this trained policy's rollouts instead of the scripted expert's, the successful ones "
        "only (a pretrained_model folder; its observation settings must match the recording's)",
    )  # fmt: skip
    parser.add_argument("--repo-id", help="dataset repo id (default: actionflow/<task>_<variant>_<episodes>)")
    parser.add_argument("--root", type=Path, help="dataset directory (default: $HF_LEROBOT_HOME/<repo id>)")
    parser.add_argument(
        "--push-to-hub", metavar="REPO_ID", type=_repo_id,
        help=f"then upload the folder to this Hub dataset repo, as `{PROG} push ROOT --to REPO_ID` does (not "
        "part of the recording: the same folder can be pushed again, or elsewhere)",
    )  # fmt: skip
    parser.add_argument("--private", action="store_true", help="with --push-to-hub: a private repository")
    parser.add_argument(
        "--workers", type=_workers, default=1, metavar="N",
        help="processes simulating episodes while this one writes the dataset (default 1: this process does "
        "both, taking one core and leaving the others to what else runs, e.g. training). On a free machine, "
        "use about as many as free cores; the dataset is the same for any N",
    )  # fmt: skip
    add_executor_arguments(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    """``--executor`` and ``--address``: where the episodes are simulated (the dataset is written here)."""
    parser.add_argument(
        "--executor", choices=EXECUTORS, default="local",
        help="local (default): this process or --workers processes here; ray: --workers Ray actors of one "
        "CPU each, on a Ray started here or on the cluster at --address (pip install '.[ray]'). The dataset "
        "is the same either way",
    )  # fmt: skip
    parser.add_argument(
        "--address", metavar="HOST:PORT", help="with --executor ray: join this Ray cluster (e.g. HEAD:6379)"
    )


def executor_kwargs(args: argparse.Namespace, parser: argparse.ArgumentParser) -> dict:
    """``record()``'s executor and address from the parsed flags (--address alone is a usage error)."""
    if args.address is not None and args.executor != "ray":
        parser.error(f"--address {args.address}: a Ray cluster's address; add --executor ray")
    return {"executor": args.executor, "address": args.address}


def build_push_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=f"{PROG} push",
        description="Upload a recorded dataset folder as it is, with its card (README.md), to a Hugging "
        "Face Hub dataset repo. Nothing local changes (the dataset's own repo id included), so the same "
        "folder can be pushed again or to another repo. Needs `hf auth login` or HF_TOKEN.",
    )  # fmt: skip
    parser.add_argument("root", type=Path, help="the dataset folder (its --root, or $HF_LEROBOT_HOME/<id>)")
    parser.add_argument("--to", required=True, type=_repo_id, metavar="REPO_ID", help="Hub repo, e.g. you/x")
    parser.add_argument("--private", action="store_true", help="create the repository private")
    return parser


def recipe_from_args(args: argparse.Namespace, parser: argparse.ArgumentParser) -> Recipe:
    """The recipe of a command line: the recipe file's fields, overridden by the flags given. Every value is
    checked here, an error naming the flag it came from or the field and the file."""
    given = {key: getattr(args, key) for key in FLAGS if getattr(args, key) is not None}
    labels = {key: FLAGS[key] for key in given}
    if args.env_kwarg:
        given["env_kwargs"] = dict(args.env_kwarg)
        labels |= {f"env_kwargs.{key}": f"--env-kwarg {key}" for key in given["env_kwargs"]}
    if args.recipe is not None:
        base = asdict(load_recipe(args.recipe))
        values = base | given | {"env_kwargs": base["env_kwargs"] | given.get("env_kwargs", {})}
        source = recipe_label(args.recipe)
    else:
        if "task" not in given or "episodes" not in given:
            parser.error("give a recipe file, or at least --task and --episodes")
        values, source = dict(given), str
    check_fields(values, lambda key: labels.get(key) or source(key))
    if args.recipe is None:  # the defaults of the command line
        from gym_actionflow import find_task

        task = find_task(values["task"])
        values.setdefault("variant", task.variants[0])
        slug = "".join("_" + c.lower() if c.isupper() else c for c in task.name).lstrip("_")
        values.setdefault("repo_id", f"actionflow/{slug}_{values['variant'].lower()}_{values['episodes']}")
    return Recipe(**values)


def _upload(root: Path, repo_id: str, private: bool) -> int:
    """Push, reporting a failed upload (network, Hub refusal) in one line: exit code 1."""
    import httpx
    from huggingface_hub.errors import HfHubHTTPError

    try:
        url = push(root, repo_id, private=private)
    except (HfHubHTTPError, httpx.HTTPError, OSError) as err:
        print(f"{PROG}: error: uploading {root} to {repo_id} failed: {err}", file=sys.stderr)
        return 1
    print(f"pushed {root} to {url}")
    return 0


def push_main(argv: list[str]) -> int:
    """``actionflow-record push ROOT --to REPO_ID [--private]``."""
    args = build_push_parser().parse_args(argv)
    try:
        check_pushable(args.root)
        check_hub_credentials(f"{PROG} push")
    except INPUT_ERRORS as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 2
    return _upload(args.root, args.to, args.private)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["push"]:
        return push_main(argv[1:])
    # A process started in the background by a non-interactive shell inherits SIGINT ignored; Ctrl-C and
    # `kill -INT` must still stop a recording cleanly.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        recipe = recipe_from_args(args, parser)
        if args.push_to_hub:
            check_hub_credentials()
        where = executor_kwargs(args, parser)
        result = record(recipe, root=args.root, progress=not args.quiet, workers=args.workers, **where)
    except KeyboardInterrupt:
        print("\nInterrupted: every finished episode is saved; run the same command again to resume.")
        return 130
    except INPUT_ERRORS as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 2
    log = result.log
    rate = f"{log.success_rate:.1%}" if log.kept_seeds or log.failed_seeds else "n/a"
    who = "policy" if recipe.policy is not None else "expert"
    if result.kept_now == 0 and result.failed_now == 0 and not result.replayed:
        print(f"{result.episodes} episodes in {result.root}: already complete; {who} success {rate}")
    else:
        per_min = 60 * result.kept_now / max(result.seconds, 1e-9)
        replayed = f", {result.replayed} replayed from the journal" if result.replayed else ""
        print(
            f"{result.episodes} episodes in {result.root} (this run: {result.kept_now} kept, "
            f"{result.failed_now} failed{replayed}, {per_min:.1f} episodes/min); {who} success over all "
            f"seeds tried: {rate}"
        )
    if args.push_to_hub:
        return _upload(result.root, args.push_to_hub, args.private)
    return 0


if __name__ == "__main__":
    sys.exit(main())
