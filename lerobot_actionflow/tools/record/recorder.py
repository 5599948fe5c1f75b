"""The recording loop: run a task's scripted expert from consecutive seeds and write the successful episodes
into a LeRobotDataset (format v3), converted through the token schema (:mod:`lerobot_actionflow.schema`).

An episode costs the same at episode 10 and at episode 1000: the dataset stays open and episodes are appended
with ``save_episode``; it is finalized and reopened only at a checkpoint, every ``checkpoint_every`` episodes
or every tenth of the dataset if that is more, and at the end. Kept episodes between checkpoints are durable
through the journal (:mod:`.durability`).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from lerobot_actionflow import schema
from lerobot_actionflow.tools.record import journal
from lerobot_actionflow.tools.record.card import write_card
from lerobot_actionflow.tools.record.durability import (
    commit,
    deferred_interrupts,
    roll_back,
    snapshot,
    terminate_as_interrupt,
)
from lerobot_actionflow.tools.record.log import LOG_NAME, RecordingLog, same_recording
from lerobot_actionflow.tools.record.recipe import Recipe
from lerobot_actionflow.tools.record.simulate import EXECUTORS, Episode, episodes, make_env

FPS = 20
CHECKPOINT_EVERY = 50
"""Episodes between checkpoints (finalize + reopen), at least. More only cost a longer journal replay after a
kill."""
CHECKPOINT_SHARE = 10
"""...and at least a tenth of the dataset: reopening reads all of the dataset's metadata (~2 s at 1000 Stack
episodes), so checkpoints spaced in proportion to the dataset keep their cost per episode constant."""

__all__ = ["CHECKPOINT_EVERY", "CHECKPOINT_SHARE", "FPS", "RecordResult", "make_env", "record"]


@dataclass
class RecordResult:
    root: Path
    episodes: int
    kept_now: int
    failed_now: int
    seconds: float
    log: RecordingLog
    replayed: int = 0
    """Episodes an interrupted run had kept, written into the dataset from the journal by this run."""


def _total_episodes(root: Path) -> int:
    return int(json.loads((root / "meta" / "info.json").read_text()).get("total_episodes", 0))


def _restore(root: Path, log: RecordingLog) -> list[int]:
    """Bring the dataset at ``root`` back to its last checkpoint; return the kept seeds the journal holds
    beyond it, to replay in this order."""
    roll_back(root)
    done = _total_episodes(root)
    journaled = set(journal.seeds(root))
    replay = log.kept_seeds[done:]
    missing = [seed for seed in replay if seed not in journaled]
    if done > len(log.kept_seeds) or missing:
        raise RuntimeError(
            f"{root}: the dataset has {done} finished episodes and its recording log lists "
            f"{len(log.kept_seeds)} kept seeds, but the journal lacks seeds {missing}; delete it and record "
            "again"
        )
    journal.discard(root, journaled - set(replay))  # already finalized, or journaled but never logged
    return replay


def _features(env, image_storage: str) -> dict[str, dict]:
    """The dataset's features: the env's observation keys through the schema, the token rows named by the
    env's ``token_names`` (and the feature columns by its ``scalar_names``) where it has them, and each
    camera's pose (the env's ``camera_poses``) in its feature's ``info``, so a dataset says where its images
    were taken."""
    unwrapped = env.unwrapped
    features = schema.dataset_features(
        schema.observation_shapes(env.observation_space),
        token_names=getattr(unwrapped, "token_names", None),
        scalar_names=getattr(unwrapped, "scalar_names", ()),
        image_storage=image_storage,
    )
    poses = getattr(unwrapped, "camera_poses", {})
    for camera in getattr(unwrapped, "cameras", ()):
        pose = poses[camera]
        info = schema.camera_info(pose.frame, pose.pose9(), pose.quaternion(), pose.fovy)
        features[schema.policy_key(f"{schema.PIXELS}/{camera}")]["info"] = info
    return features


GENERATION_FAILURES = 20
"""Generated episodes, and a policy's rollouts, may fail this many times as often as an expert's before a run
gives up (success rates down to about 5 %)."""

IMAGE_DATA_FILE_MB = 1
"""Data file size (MB) of datasets with PNG frames: LeRobot's streaming loader interleaves up to 16 files
(shards) at random, so a dataset in many small files is read in a far better mixed order than one in a few
(LeRobot's default is 100 MB: one file for a 100-episode 80 px dataset, read in order through a 1000-frame
shuffle buffer)."""


def check_root(root: Path) -> None:
    """Fail before anything is written if the dataset folder could not be created at ``root``: its nearest
    existing folder must let us create a folder in it (tried, and removed at once: permission bits do not
    tell for root, read-only mounts or /proc)."""
    advice = "choose a --root in a folder you can write to (default: $HF_LEROBOT_HOME/<repo id>)"
    try:
        existing = root
        while not existing.exists():
            existing = existing.parent
        if not existing.is_dir():
            raise ValueError(f"--root {root}: {existing} is a file, not a folder; {advice}")
        os.rmdir(tempfile.mkdtemp(prefix=".actionflow_probe_", dir=existing))
    except OSError as err:
        raise ValueError(
            f"--root {root}: cannot create the dataset folder there ({err.strerror or err}); {advice}"
        ) from None


def _open_dataset(recipe: Recipe, root: Path, features: dict):
    """Create the dataset, or reopen one this recipe already started (rolled back to its last checkpoint);
    refuse anything else at ``root``. Returns the dataset, its log and the seeds to replay from the
    journal."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    log = RecordingLog.load(root) if root.exists() else None
    if root.exists() and log is None:
        raise FileExistsError(
            f"{root} exists and is not an actionflow-record dataset (no meta/{LOG_NAME}); choose another "
            "--root or --repo-id, or delete it"
        )
    if log is not None:
        diff = same_recording(log.recipe, asdict(recipe) | {"episodes": None})
        if diff:
            raise ValueError(
                f"{root} holds a different recording ({'; '.join(diff)}); choose another --root or "
                "--repo-id, or delete it"
            )
        replay = _restore(root, log)
        ds = LeRobotDataset.resume(recipe.repo_id, root=root)
    else:
        log, replay = RecordingLog(recipe=asdict(recipe) | {"episodes": None}), []
        ds = LeRobotDataset.create(
            repo_id=recipe.repo_id,
            fps=FPS,
            features=features,
            root=root,
            robot_type="franka_panda",
            use_videos=any(f["dtype"] == "video" for f in features.values()),
            data_files_size_in_mb=IMAGE_DATA_FILE_MB if any(f["dtype"] == "image" for f in features.values())
            else None,
        )
        log.save(root)
    snapshot(root)
    return ds, log, replay


class _Checkpointed:
    """The open dataset: episodes are appended (:meth:`add`); :meth:`checkpoint` finalizes it, commits,
    empties the journal and reopens it for more."""

    def __init__(self, ds, root: Path, repo_id: str, every: int):
        self.ds, self.root, self.repo_id, self.every = ds, root, repo_id, every
        self.since = 0
        self.closed = False

    def add(self, episode: Episode) -> None:
        import datasets

        for frame in episode.frames():
            self.ds.add_frame(frame)
        datasets.disable_progress_bars()  # LeRobot's loaders turn them back on; one bar is enough
        self.ds.save_episode()
        self.since += 1

    @property
    def due(self) -> bool:
        return self.since >= max(self.every, self.ds.meta.total_episodes // CHECKPOINT_SHARE)

    def checkpoint(self, reopen: bool) -> None:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        if self.closed:  # the last checkpoint did not reopen: nothing was written since
            return
        self.ds.finalize()  # parquet footers and metadata written: the dataset holds every kept episode
        commit(self.root)
        journal.clear(self.root)
        self.since = 0
        self.closed = not reopen
        if reopen:
            self.ds = LeRobotDataset.resume(self.repo_id, root=self.root)
            snapshot(self.root)


@contextlib.contextmanager
def _skip_empty_image_embedding():
    """LeRobot 0.6's ``save_episode`` maps ``datasets``' ``embed_table_storage`` over the episode one row at a
    time, whether or not a column holds images to embed: ~70 % of its cost on a dataset without image columns
    (camera streams are videos here, not parquet columns). Skip it exactly when it changes nothing: when no
    feature of the table needs embedding."""
    try:
        from datasets.features.features import require_storage_embed
        from lerobot.datasets import dataset_writer

        original = dataset_writer.embed_images
    except (ImportError, AttributeError):  # another LeRobot layout: record without the shortcut
        yield
        return

    def embed_images(dataset):
        if any(require_storage_embed(feature) for feature in dataset.features.values()):
            return original(dataset)
        return dataset

    dataset_writer.embed_images = embed_images
    try:
        yield
    finally:
        dataset_writer.embed_images = original


def record(
    recipe: Recipe,
    root: str | Path | None = None,
    progress: bool = True,
    workers: int = 1,
    checkpoint_every: int = CHECKPOINT_EVERY,
    executor: str = "local",
    address: str | None = None,
) -> RecordResult:
    """Record ``recipe`` into a LeRobotDataset at ``root`` (default ``$HF_LEROBOT_HOME/<repo_id>``), or finish
    recording it there.

    ``workers`` processes simulate the episodes (1: this process does); the dataset is the same for any
    number. ``executor="ray"`` simulates in ``workers`` Ray actors instead, on a Ray started here or on the
    cluster at ``address``; the dataset is still written here, and is the same again.

    Episodes are made final in the dataset every ``checkpoint_every`` episodes (or every tenth of the
    dataset if that is more) and when the recording stops, also on Ctrl-C or SIGTERM; after a kill or a
    crash, the next run replays the kept episodes from the journal.
    """
    from gym_actionflow import find_task
    from lerobot.utils.constants import HF_LEROBOT_HOME
    from tqdm import tqdm

    if int(workers) != workers or workers < 1:
        raise ValueError(
            f"workers={workers!r}; expected an integer >= 1 (1 simulates in the recording process)"
        )
    if executor not in EXECUTORS:
        raise ValueError(f"executor={executor!r}; expected one of {EXECUTORS}")
    if address is not None and executor != "ray":
        raise ValueError(f"address={address!r} is a Ray cluster's; pass executor='ray' with it")
    if int(checkpoint_every) != checkpoint_every or checkpoint_every < 1:
        raise ValueError(f"checkpoint_every={checkpoint_every!r}; expected an integer >= 1")
    task = find_task(recipe.task)
    # A bad variant, obs mode, layout or camera fails before anything is written.
    task.kwargs(recipe.variant, recipe.obs_mode, recipe.obs_layout, recipe.cameras)
    root = Path(root) if root is not None else HF_LEROBOT_HOME / recipe.repo_id
    env = make_env(recipe)  # an env keyword it does not take, or a bad value, fails here: nothing written yet
    features = _features(env, recipe.image_storage)
    try:
        check_root(root)
    except Exception:
        env.close()
        raise
    if workers > 1 or executor == "ray":
        env.close()  # the workers simulate, each on its own env
        env = None
    ds, log, replay = _open_dataset(recipe, root, features)
    dataset = _Checkpointed(ds, root, recipe.repo_id, checkpoint_every)
    # An expert at < 50 % means something is wrong: stop early. Generated episodes fail more often by nature
    # (MimicGen's rates run from under 10 % to 100 %): they may fail up to GENERATION_FAILURES times as often.
    # A policy's rollouts likewise.
    generated = recipe.source is not None
    learned = generated or recipe.policy is not None
    max_failures = max(20, recipe.episodes) * (GENERATION_FAILURES if learned else 1)
    who = "generation" if generated else ("the policy" if learned else f"the {task.name} expert")
    run_start = start = time.time()
    kept_now = failed_now = 0
    half_written = False  # an exception in a LeRobot write: leave the rest to the next run's roll-back
    previous_term = signal.signal(signal.SIGTERM, terminate_as_interrupt)
    bar = tqdm(
        total=recipe.episodes,
        initial=min(len(log.kept_seeds), recipe.episodes),
        desc=f"recording {task.name} {recipe.variant}",
        unit="ep",
        disable=not progress,
    )
    source = episodes(recipe, log.next_seed, workers, env, executor, address)
    try:
        with _skip_empty_image_embedding(), contextlib.closing(source):
            for seed in replay:
                with deferred_interrupts():
                    half_written = True
                    dataset.add(journal.read(root, seed))
                    if dataset.due:
                        dataset.checkpoint(reopen=True)
                    half_written = False
            while len(log.kept_seeds) < recipe.episodes:
                if len(log.failed_seeds) > max_failures:
                    raise RuntimeError(
                        f"{who} failed {len(log.failed_seeds)} times "
                        f"(success rate {log.success_rate:.0%}); stopping. Kept episodes are saved in {root}"
                    )
                episode = next(source)
                if not episode.success:
                    log.failed_seeds.append(episode.seed)
                    failed_now += 1
                    log.save(root)
                    bar.set_postfix(failures=len(log.failed_seeds))
                    continue
                with deferred_interrupts():
                    journal.write(root, episode)
                    log.kept_seeds.append(episode.seed)
                    if episode.segments is not None:
                        log.segments[str(episode.seed)] = list(episode.segments)
                    log.seconds += time.time() - start
                    start = time.time()
                    log.save(root)  # the episode is durable from here on
                    half_written = True
                    dataset.add(episode)
                    if dataset.due:
                        dataset.checkpoint(reopen=len(log.kept_seeds) < recipe.episodes)
                    half_written = False
                kept_now += 1
                bar.update(1)
    finally:
        bar.close()
        if not half_written:
            with deferred_interrupts():
                dataset.checkpoint(reopen=False)
                if generated:  # which source episode each segment replayed: a function of the seeds
                    from lerobot_actionflow.tools.generate import cached_source, write_generation_file

                    done = log.kept_seeds[: _total_episodes(root)]
                    write_generation_file(root, cached_source(recipe.source, recipe.task), done, log.segments)
                write_card(root)  # the folder describes itself, pushed or not
        if env is not None:
            env.close()
        signal.signal(signal.SIGTERM, previous_term)
    return RecordResult(
        root, len(log.kept_seeds), kept_now, failed_now, time.time() - run_start, log, replayed=len(replay)
    )
