"""``actionflow-record``: record a gym_actionflow task's scripted expert into a LeRobotDataset (format v3).

    actionflow-record --task StackThree --variant D0 --episodes 50           # -> $HF_LEROBOT_HOME/<repo id>
    actionflow-record datasets/stack_three_d0_50.toml                        # the same, from a recipe file
    actionflow-record datasets/stack_three_d0_50.toml --push-to-hub you/stack_three_d0_50

Only successful expert episodes are kept; failures are counted and reported. Seeds are tried in order from
``--seed``, so a dataset is reproducible from its command. Every finished episode is made durable on disk
before the next one starts: Ctrl-C, a crash or a kill keeps all of them (an episode a kill interrupts while it
is being written is undone), and running the same command again resumes where the recording stopped.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import shlex
import shutil
import signal
import sys
import time
import tomllib
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

FPS = 20
LOG_NAME = "actionflow_recording.json"
"""Recording log beside LeRobot's metadata (``<root>/meta/``): what was recorded, and from which seeds."""


# ---------------------------------------------------------------------------- what to record
@dataclass
class Recipe:
    """What to record. A recipe file (TOML) holds these fields; the command line gives the same ones."""

    task: str
    """Task name (``StackThree``) or gym id (``gym_actionflow/StackThree-v0``)."""
    variant: str
    """Initial-state distribution: D0/D1, or train/test for MugHanging."""
    episodes: int
    """Successful episodes to keep."""
    repo_id: str
    """Dataset repo id; the data goes to ``$HF_LEROBOT_HOME/<repo_id>`` unless a root is given."""
    seed: int = 0
    """First seed; seeds are tried in order until ``episodes`` successes are kept."""
    noise: float = 1.0
    """Expert noise (0: deterministic waypoints; 1: the suite's standard demonstration noise)."""
    obs_mode: str = "state"
    """``state`` (tokens only) or ``pixels`` (adds the wrist camera, stored as video)."""
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    """Further ``gym.make`` keyword arguments (e.g. ``hanger_obs = "point_cloud"``)."""

    REQUIRED = ("task", "variant", "episodes", "repo_id")

    def __post_init__(self) -> None:
        if int(self.episodes) < 1:
            raise ValueError(f"episodes={self.episodes}; expected an integer >= 1")
        if self.obs_mode not in ("state", "pixels"):
            raise ValueError(f"obs_mode={self.obs_mode!r}; expected 'state' or 'pixels'")
        if self.noise < 0:
            raise ValueError(f"noise={self.noise}; expected >= 0")
        self.episodes, self.seed, self.noise = int(self.episodes), int(self.seed), float(self.noise)

    def command(self) -> str:
        """The ``actionflow-record`` command line that reproduces this dataset."""
        args = ["actionflow-record", "--task", self.task, "--variant", self.variant]
        args += ["--episodes", str(self.episodes), "--seed", str(self.seed), "--noise", f"{self.noise:g}"]
        if self.obs_mode != "state":
            args += ["--obs-mode", self.obs_mode]
        for key, value in self.env_kwargs.items():
            args += ["--env-kwarg", f"{key}={value}"]
        return shlex.join([*args, "--repo-id", self.repo_id])


def load_recipe(path: str | Path) -> Recipe:
    """Read a recipe file; a missing or unknown field is an error naming it (nothing is recorded)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"recipe {path} does not exist")
    with path.open("rb") as f:
        try:
            data = tomllib.load(f)
        except tomllib.TOMLDecodeError as err:
            raise ValueError(f"recipe {path} is not valid TOML: {err}") from err
    known = {f.name for f in fields(Recipe)}
    missing = [k for k in Recipe.REQUIRED if k not in data]
    if missing:
        raise ValueError(
            f"recipe {path} is missing the field(s) {missing}; a recipe needs {list(Recipe.REQUIRED)} "
            f"and may set {sorted(known - set(Recipe.REQUIRED))}"
        )
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"recipe {path} has unknown field(s) {unknown}; expected fields in {sorted(known)}")
    return Recipe(**data)


def resolve_task(name: str):
    """The registry row of a task given by name, ``Name-v0`` or full gym id."""
    from gym_actionflow import TASKS

    for task in TASKS:
        if name in (task.name, f"{task.name}-v0", task.env_id):
            return task
    known = ", ".join(task.name for task in TASKS)
    raise ValueError(f"unknown task {name!r}; gym_actionflow has: {known}")


def make_env(recipe: Recipe):
    import gymnasium as gym

    task = resolve_task(recipe.task)
    return gym.make(task.env_id, obs_mode=recipe.obs_mode, **task.kwargs(recipe.variant), **recipe.env_kwargs)


def dataset_features(env) -> dict[str, dict]:
    """LeRobotDataset features of a gym_actionflow env, following the token schema (docs: DESIGN.md)."""
    space = env.observation_space
    pose_names = ["x", "y", "z", "r00", "r10", "r20", "r01", "r11", "r21"]

    def box(key: str, names=None) -> dict:
        return {"dtype": "float32", "shape": tuple(space[key].shape), "names": names}

    features = {
        "observation.token_poses": box("token_poses"),
        "observation.token_features": box("token_features"),
        "observation.state": box("agent_pos", [*pose_names, "gripper_opening"]),
        "observation.environment_state": box("environment_state"),
    }
    if "point_cloud" in space.spaces:
        features["observation.point_cloud"] = box("point_cloud")
    if "pixels" in space.spaces:
        for cam, cam_space in space["pixels"].spaces.items():
            features[f"observation.images.{cam}"] = {
                "dtype": "video",
                "shape": tuple(cam_space.shape),
                "names": ["height", "width", "channels"],
            }
    features["action"] = {"dtype": "float32", "shape": (10,), "names": [*pose_names, "gripper"]}
    return features


def to_frame(obs: dict, action: np.ndarray, task: str) -> dict:
    frame = {
        "observation.token_poses": obs["token_poses"],
        "observation.token_features": obs["token_features"],
        "observation.state": obs["agent_pos"],
        "observation.environment_state": obs["environment_state"],
        "action": np.asarray(action, dtype=np.float32),
        "task": task,
    }
    if "point_cloud" in obs:
        frame["observation.point_cloud"] = obs["point_cloud"]
    for cam, image in obs.get("pixels", {}).items():
        frame[f"observation.images.{cam}"] = image
    return frame


# ---------------------------------------------------------------------------- the recording log
@dataclass
class RecordingLog:
    """Which seeds were tried, kept and failed; lets a rerun resume and the dataset card tell the story."""

    recipe: dict
    kept_seeds: list[int] = field(default_factory=list)
    failed_seeds: list[int] = field(default_factory=list)
    pending_seed: int | None = None
    """Seed of the episode being written: set while LeRobot writes it, so that a kill half-way is undone."""
    seconds: float = 0.0

    @property
    def next_seed(self) -> int:
        tried = self.kept_seeds + self.failed_seeds
        return max(tried) + 1 if tried else self.recipe["seed"]

    @property
    def success_rate(self) -> float:
        tried = len(self.kept_seeds) + len(self.failed_seeds)
        return len(self.kept_seeds) / tried if tried else float("nan")

    def save(self, root: Path) -> None:
        path = root / "meta" / LOG_NAME
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(asdict(self), indent=2))
        tmp.replace(path)  # atomic: the log is never half-written

    @classmethod
    def load(cls, root: Path) -> RecordingLog | None:
        path = root / "meta" / LOG_NAME
        return cls(**json.loads(path.read_text())) if path.is_file() else None


def _same_recording(a: dict, b: dict) -> list[str]:
    keys = ("task", "variant", "seed", "noise", "obs_mode", "env_kwargs", "repo_id")
    return [f"{k}: {a.get(k)!r} on disk vs {b.get(k)!r} now" for k in keys if a.get(k) != b.get(k)]


@contextlib.contextmanager
def _deferred_interrupts() -> Iterator[None]:
    """Hold Ctrl-C / SIGTERM while an episode is written, then deliver it: no half-written episode."""
    received: list[int] = []
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

    def hold(signum, _frame):
        received.append(signum)

    for sig in previous:
        signal.signal(sig, hold)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if received:
            raise KeyboardInterrupt


def _terminate_as_interrupt(signum, _frame):
    raise KeyboardInterrupt


# ---------------------------------------------------------------------------- undoing a half-written episode
PENDING = "actionflow_pending"
"""Folder under ``meta/`` holding what an episode write may change; present only while one is written."""
RESTORED = ("meta/info.json", "meta/stats.json", "meta/tasks.parquet")


def _begin_episode(root: Path) -> None:
    """Note what is on disk before an episode is written, so that a kill half-way through can be undone."""
    pending = root / "meta" / PENDING
    shutil.rmtree(pending, ignore_errors=True)
    pending.mkdir()
    for rel in RESTORED:
        if (root / rel).is_file():
            shutil.copy2(root / rel, pending / Path(rel).name)
    files = sorted(
        p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file() and PENDING not in p.parts
    )
    tmp = pending / "files.tmp"
    tmp.write_text(json.dumps(files))
    tmp.replace(pending / "files.json")  # written last: its presence means the snapshot is complete


def _end_episode(root: Path) -> None:
    shutil.rmtree(root / "meta" / PENDING, ignore_errors=True)


def _roll_back(root: Path) -> None:
    """Remove every file an unfinished episode write added, and put LeRobot's metadata back as it was."""
    pending = root / "meta" / PENDING
    listing = pending / "files.json"
    if listing.is_file():  # else the kill came before the write started: the dataset is untouched
        keep = set(json.loads(listing.read_text())) | {f"meta/{LOG_NAME}"}
        for path in list(root.rglob("*")):
            if path.is_file() and PENDING not in path.parts and path.relative_to(root).as_posix() not in keep:
                path.unlink()
        for rel in RESTORED:
            if (pending / Path(rel).name).is_file():
                shutil.copy2(pending / Path(rel).name, root / rel)
    shutil.rmtree(pending, ignore_errors=True)


# ---------------------------------------------------------------------------- recording
@dataclass
class RecordResult:
    root: Path
    episodes: int
    kept_now: int
    failed_now: int
    seconds: float
    log: RecordingLog


def _open_dataset(recipe: Recipe, root: Path, features: dict):
    """Create the dataset, or reopen one this recipe already started; refuse anything else at ``root``."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    log = RecordingLog.load(root) if root.exists() else None
    if root.exists() and log is None:
        raise FileExistsError(
            f"{root} exists and is not an actionflow-record dataset (no meta/{LOG_NAME}); choose another "
            "--root or --repo-id, or delete it"
        )
    if log is not None:
        diff = _same_recording(log.recipe, asdict(recipe) | {"episodes": None})
        if diff:
            raise ValueError(
                f"{root} holds a different recording ({'; '.join(diff)}); choose another --root or "
                "--repo-id, or delete it"
            )
        if log.pending_seed is not None:  # killed while an episode was written: undo it, it is recorded again
            _roll_back(root)
            log.pending_seed = None
            log.save(root)
        _end_episode(root)  # (killed after the episode was logged: only the note of the write is left)
        info = json.loads((root / "meta" / "info.json").read_text())
        done = int(info.get("total_episodes", 0))
        if done != len(log.kept_seeds):
            raise RuntimeError(
                f"{root}: the dataset has {done} episodes but its recording log lists {len(log.kept_seeds)}; "
                "delete it and record again"
            )
        if done == 0:  # nothing finished: start clean
            shutil.rmtree(root)
        else:
            return LeRobotDataset.resume(recipe.repo_id, root=root), log
    log = RecordingLog(recipe=asdict(recipe) | {"episodes": None})
    ds = LeRobotDataset.create(
        repo_id=recipe.repo_id,
        fps=FPS,
        features=features,
        root=root,
        robot_type="franka_panda",
        use_videos=any(f["dtype"] == "video" for f in features.values()),
    )
    log.save(root)
    return ds, log


def record(recipe: Recipe, root: str | Path | None = None, progress: bool = True) -> RecordResult:
    """Record ``recipe`` into a LeRobotDataset at ``root`` (default ``$HF_LEROBOT_HOME/<repo_id>``)."""
    import datasets
    from gym_actionflow import make_expert, run_episode
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.utils.constants import HF_LEROBOT_HOME
    from tqdm import tqdm

    task = resolve_task(recipe.task)
    if recipe.variant not in task.variants:
        raise ValueError(f"{task.name} has no variant {recipe.variant!r}; expected one of {task.variants}")
    root = Path(root) if root is not None else HF_LEROBOT_HOME / recipe.repo_id
    env = make_env(recipe)
    features = dataset_features(env)
    ds, log = _open_dataset(recipe, root, features)
    description = env.unwrapped.task_description
    max_failures = max(20, recipe.episodes)  # an expert at < 50 % means something is wrong: stop early
    run_start = start = time.time()
    kept_now = failed_now = 0
    previous_term = signal.signal(signal.SIGTERM, _terminate_as_interrupt)
    bar = tqdm(
        total=recipe.episodes,
        initial=min(len(log.kept_seeds), recipe.episodes),
        desc=f"recording {task.name} {recipe.variant}",
        unit="ep",
        disable=not progress,
    )
    try:
        while len(log.kept_seeds) < recipe.episodes:
            if len(log.failed_seeds) > max_failures:
                raise RuntimeError(
                    f"the {task.name} expert failed {len(log.failed_seeds)} times "
                    f"(success rate {log.success_rate:.0%}); stopping. Kept episodes are saved in {root}"
                )
            seed = log.next_seed
            frames: list[dict] = []

            def keep(obs: dict, action: np.ndarray, frames: list[dict] = frames) -> None:
                frames.append(to_frame(obs, action, description))

            episode = run_episode(env, make_expert(env, noise=recipe.noise, seed=seed), seed, on_step=keep)
            if not episode.success:
                log.failed_seeds.append(seed)
                failed_now += 1
                log.save(root)
                bar.set_postfix(failures=len(log.failed_seeds))
                continue
            with _deferred_interrupts():
                _begin_episode(root)
                log.pending_seed = seed
                log.save(root)
                for frame in frames:
                    ds.add_frame(frame)
                datasets.disable_progress_bars()  # LeRobot's loaders turn them back on; one bar is enough
                ds.save_episode()
                ds.finalize()  # parquet footers written: this episode survives anything from here on
                log.kept_seeds.append(seed)
                log.pending_seed = None
                log.seconds += time.time() - start
                start = time.time()
                log.save(root)
                _end_episode(root)
            kept_now += 1
            bar.update(1)
            if len(log.kept_seeds) < recipe.episodes:
                ds = LeRobotDataset.resume(recipe.repo_id, root=root)
    finally:
        bar.close()
        ds.finalize()
        env.close()
        signal.signal(signal.SIGTERM, previous_term)
    return RecordResult(root, len(log.kept_seeds), kept_now, failed_now, time.time() - run_start, log)


# ---------------------------------------------------------------------------- the Hub
def check_hub_credentials() -> None:
    """Fail before recording anything if a push could not succeed."""
    import os

    from huggingface_hub import get_token

    if os.environ.get("HF_HUB_OFFLINE", "0") not in ("0", "", "false", "False"):
        raise RuntimeError("--push-to-hub needs the network, but HF_HUB_OFFLINE is set")
    if get_token() is None:
        raise RuntimeError(
            "--push-to-hub needs Hugging Face credentials: run `hf auth login` or set HF_TOKEN "
            "(nothing was recorded)"
        )


def dataset_card_text(recipe: Recipe, log: RecordingLog) -> str:
    """The dataset description shown on the Hub (template: lerobot_actionflow/templates/dataset_card.md)."""
    task = resolve_task(recipe.task)
    tried = sorted(log.kept_seeds + log.failed_seeds)
    template = resources.files("lerobot_actionflow").joinpath("templates/dataset_card.md").read_text()
    return template.format(
        env_id=task.env_id,
        variant_kwarg=task.variant_kwarg,
        variant=recipe.variant,
        episodes=len(log.kept_seeds),
        seed_range=f"{tried[0]}..{tried[-1]}" if tried else "none",
        failed=", ".join(map(str, log.failed_seeds)) or "none",
        noise=f"{recipe.noise:g}",
        success=f"{log.success_rate:.1%}",
        obs_mode=recipe.obs_mode,
        fps=FPS,
        command=recipe.command(),
    )


def push(recipe: Recipe, root: Path, private: bool = False) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    log = RecordingLog.load(root)
    ds = LeRobotDataset(recipe.repo_id, root=root)
    ds.push_to_hub(
        tags=["actionflow", "gym_actionflow", resolve_task(recipe.task).name],
        private=private,
        dataset_description=dataset_card_text(recipe, log),
        paper="ActionFlow: Equivariant, Accurate, and Efficient Policies with Spatially Symmetric Flow "
        "Matching",
    )


# ---------------------------------------------------------------------------- command line
def _parse_env_kwarg(text: str) -> tuple[str, Any]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"--env-kwarg {text!r}: expected KEY=VALUE")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="actionflow-record", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("recipe", nargs="?", type=Path, help="a recipe file (datasets/*.toml)")
    parser.add_argument("--task", help="task name, e.g. StackThree (see `python -m gym_actionflow -h`)")
    parser.add_argument("--variant", help="D0 / D1, or train / test for MugHanging (default: the first)")
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
        task = resolve_task(given["task"])
        given.setdefault("variant", task.variants[0])
        slug = "".join("_" + c.lower() if c.isupper() else c for c in task.name).lstrip("_")
        given.setdefault("repo_id", f"actionflow/{slug}_{given['variant'].lower()}_{given['episodes']}")
        recipe = Recipe(**given)
    if args.push_to_hub:
        if args.repo_id and args.repo_id != args.push_to_hub:
            parser.error(f"--repo-id {args.repo_id} and --push-to-hub {args.push_to_hub} differ; give one")
        recipe.repo_id = args.push_to_hub
    resolve_task(recipe.task)
    return recipe


def main(argv: list[str] | None = None) -> int:
    import logging

    # Without a system FFmpeg, torchcodec logs a long traceback and LeRobot falls back to pyav: harmless here.
    logging.getLogger("lerobot.utils.import_utils").setLevel(logging.ERROR)
    # A process started in the background by a non-interactive shell inherits SIGINT ignored; Ctrl-C and
    # `kill -INT` must still stop a recording cleanly.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        recipe = recipe_from_args(args, parser)
        if args.push_to_hub:
            check_hub_credentials()
        result = record(recipe, root=args.root, progress=not args.quiet)
    except KeyboardInterrupt:
        print("\nInterrupted: every finished episode is saved; run the same command again to resume.")
        return 130
    except (ValueError, FileNotFoundError, FileExistsError, RuntimeError) as err:
        print(f"actionflow-record: error: {err}", file=sys.stderr)
        return 2
    log = result.log
    rate = f"{log.success_rate:.1%}" if log.kept_seeds or log.failed_seeds else "n/a"
    if result.kept_now == 0 and result.failed_now == 0:
        print(f"{result.episodes} episodes in {result.root}: already complete; expert success {rate}")
    else:
        per_min = 60 * result.kept_now / max(result.seconds, 1e-9)
        print(
            f"{result.episodes} episodes in {result.root} (this run: {result.kept_now} kept, "
            f"{result.failed_now} failed, {per_min:.1f} episodes/min); expert success over all seeds tried: "
            f"{rate}"
        )
    if args.push_to_hub:
        push(recipe, result.root, private=args.private)
        print(f"pushed to https://huggingface.co/datasets/{recipe.repo_id}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
