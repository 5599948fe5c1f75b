"""The recording loop: run a task's scripted expert from consecutive seeds and write the successful episodes
into a LeRobotDataset (format v3), converted through the token schema (:mod:`lerobot_actionflow.schema`)."""

from __future__ import annotations

import json
import shutil
import signal
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from lerobot_actionflow import schema
from lerobot_actionflow.tools.record.durability import (
    begin_episode,
    deferred_interrupts,
    end_episode,
    roll_back,
    terminate_as_interrupt,
)
from lerobot_actionflow.tools.record.log import LOG_NAME, RecordingLog, same_recording
from lerobot_actionflow.tools.record.recipe import Recipe

FPS = 20


@dataclass
class RecordResult:
    root: Path
    episodes: int
    kept_now: int
    failed_now: int
    seconds: float
    log: RecordingLog


def make_env(recipe: Recipe):
    """The env a recipe records (``gym.make`` with its task, variant, obs mode and extra keywords)."""
    import gymnasium as gym
    from gym_actionflow import find_task

    task = find_task(recipe.task)
    return gym.make(task.env_id, **task.kwargs(recipe.variant, recipe.obs_mode), **recipe.env_kwargs)


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
        diff = same_recording(log.recipe, asdict(recipe) | {"episodes": None})
        if diff:
            raise ValueError(
                f"{root} holds a different recording ({'; '.join(diff)}); choose another --root or "
                "--repo-id, or delete it"
            )
        if log.pending_seed is not None:  # killed while an episode was written: undo it, it is recorded again
            roll_back(root)
            log.pending_seed = None
            log.save(root)
        end_episode(root)  # (killed after the episode was logged: only the note of the write is left)
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
    from gym_actionflow import find_task, make_expert, run_episode
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.utils.constants import HF_LEROBOT_HOME
    from tqdm import tqdm

    task = find_task(recipe.task)
    task.kwargs(recipe.variant, recipe.obs_mode)  # a bad variant or obs mode fails before anything is written
    root = Path(root) if root is not None else HF_LEROBOT_HOME / recipe.repo_id
    env = make_env(recipe)
    features = schema.dataset_features(schema.observation_shapes(env.observation_space))
    ds, log = _open_dataset(recipe, root, features)
    description = env.unwrapped.task_description
    max_failures = max(20, recipe.episodes)  # an expert at < 50 % means something is wrong: stop early
    run_start = start = time.time()
    kept_now = failed_now = 0
    previous_term = signal.signal(signal.SIGTERM, terminate_as_interrupt)
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
                frames.append(schema.dataset_frame(obs, action, description))

            episode = run_episode(env, make_expert(env, noise=recipe.noise, seed=seed), seed, on_step=keep)
            if not episode.success:
                log.failed_seeds.append(seed)
                failed_now += 1
                log.save(root)
                bar.set_postfix(failures=len(log.failed_seeds))
                continue
            with deferred_interrupts():
                begin_episode(root)
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
                end_episode(root)
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
