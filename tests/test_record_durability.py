"""actionflow-record in linear time and in parallel: checkpoints instead of finalizing every episode, the
journal that keeps the episodes in between, and worker processes that must not change the dataset."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_actionflow.tools.record import LOG_NAME, Recipe, record
from lerobot_actionflow.tools.record.journal import JOURNAL
from lerobot_actionflow.tools.record.simulate import episodes, make_env, simulate

# Expert noise 3 makes Stack fail on seed 8 (on the Panda-like physics of f2f1b96): failures must be logged in
# order whatever the workers.
RECIPE = Recipe(task="Stack", variant="D0", episodes=9, repo_id="local/dur", noise=3.0)
KEPT, FAILED = [0, 1, 2, 3, 4, 5, 6, 7, 9], [8]
EVERY = 2  # checkpoint every 2 episodes: 5 episodes cross two checkpoints and end between them


def _env(tmp: Path) -> dict[str, str]:
    return {**os.environ, "HF_HUB_OFFLINE": "1", "HF_LEROBOT_HOME": str(tmp / "hf_lerobot")}


def _columns(root: Path) -> dict[str, np.ndarray]:
    table = LeRobotDataset(RECIPE.repo_id, root=root).hf_dataset.with_format("numpy")[:]
    return {key: np.stack(values) for key, values in table.items()}


def _assert_same_dataset(root: Path, reference: Path) -> None:
    ours, ref = _columns(root), _columns(reference)
    assert ours.keys() == ref.keys()
    for key in ref:
        np.testing.assert_array_equal(ours[key], ref[key], err_msg=key)
    log, ref_log = (json.loads((r / "meta" / LOG_NAME).read_text()) for r in (root, reference))
    assert (log["kept_seeds"], log["failed_seeds"]) == (ref_log["kept_seeds"], ref_log["failed_seeds"])
    ds = LeRobotDataset(RECIPE.repo_id, root=root)
    assert ds.num_episodes == len(KEPT) and len(ds) == sum(ds.meta.episodes["length"])
    assert not (root / "meta" / JOURNAL).exists() and not (root / "meta" / "actionflow_pending").exists()


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """The recipe recorded in one go, in this process."""
    root = tmp_path_factory.mktemp("ref") / "ds"
    result = record(RECIPE, root=root, progress=False, workers=1, checkpoint_every=EVERY)
    assert (result.log.kept_seeds, result.log.failed_seeds) == (KEPT, FAILED)
    return root


def test_episodes_are_not_finalized_one_by_one(tmp_path, monkeypatch):
    """Finalizing and reopening after every episode makes each episode cost more the larger the dataset;
    between checkpoints episodes are only appended."""
    calls = {"finalize": 0, "resume": 0}
    finalize, resume = LeRobotDataset.finalize, LeRobotDataset.resume.__func__

    def count_finalize(self):
        calls["finalize"] += 1
        return finalize(self)

    def count_resume(cls, *args, **kwargs):
        calls["resume"] += 1
        return resume(cls, *args, **kwargs)

    monkeypatch.setattr(LeRobotDataset, "finalize", count_finalize)
    monkeypatch.setattr(LeRobotDataset, "resume", classmethod(count_resume))
    recipe = Recipe(task="Stack", variant="D0", episodes=3, repo_id="local/few")
    record(recipe, root=tmp_path / "few", progress=False)
    assert calls == {"finalize": 1, "resume": 0}  # the default checkpoint interval is far above 3
    calls.update(finalize=0, resume=0)
    record(recipe, root=tmp_path / "few2", progress=False, checkpoint_every=1)
    assert calls == {"finalize": 3, "resume": 2}


def test_two_workers_record_the_same_dataset_as_one(reference, tmp_path):
    """Seeds are handed to the workers in order and their episodes consumed in order: the same kept and failed
    seeds and bit-identical frames, with the same checkpoints."""
    result = record(RECIPE, root=tmp_path / "w2", progress=False, workers=2, checkpoint_every=EVERY)
    assert (result.log.kept_seeds, result.log.failed_seeds) == (KEPT, FAILED)
    _assert_same_dataset(tmp_path / "w2", reference)

    def files(root: Path) -> list[str]:
        return sorted(p.relative_to(root).as_posix() for p in root.rglob("*.parquet"))

    assert files(tmp_path / "w2") == files(reference)


def test_workers_render_the_wrist_camera_as_this_process_does():
    """Each worker has its own env and offscreen renderer: its images are exactly the in-process ones."""
    recipe = Recipe(task="Stack", variant="D0", episodes=1, repo_id="local/px", obs_mode="pixels")
    env = make_env(recipe)
    here = simulate(env, recipe, 0)
    env.close()
    source = episodes(recipe, 0, workers=2)
    try:
        there = next(source)
    finally:
        source.close()
    assert there.seed == 0 and there.success and here.success
    assert "observation.images.wrist" in there.columns
    assert there.columns.keys() == here.columns.keys()
    for key in here.columns:
        np.testing.assert_array_equal(there.columns[key], here.columns[key], err_msg=key)


@pytest.mark.parametrize("image_storage", ["image", "video"])
def test_pixels_are_recorded_with_workers(tmp_path, image_storage):
    """Camera frames are stored as asked: PNG frames (the default) in data files kept small (each episode of
    this one takes a new file), or video."""
    recipe = Recipe(task="Stack", variant="D0", episodes=2, repo_id="local/pxw", obs_mode="pixels",
                    image_storage=image_storage)  # fmt: skip
    result = record(recipe, root=tmp_path / "px", progress=False, workers=2)
    assert result.episodes == 2
    ds = LeRobotDataset("local/pxw", root=tmp_path / "px")
    keys = ds.meta.image_keys if image_storage == "image" else ds.meta.video_keys
    assert keys == ["observation.images.wrist"] and ds.num_episodes == 2
    if image_storage == "image":
        assert ds.meta.video_keys == [] and ds.meta.data_files_size_in_mb == 1
    image = ds[len(ds) - 1]["observation.images.wrist"]
    assert image.shape == (3, 84, 84) and 0 <= image.min() <= image.max() <= 1


KILL = """
import multiprocessing, os, sys
from pathlib import Path
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot_actionflow.tools.record import Recipe, journal, record, recorder

root, point, count, workers = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
calls = []

def dying(original):
    def call(*args, **kwargs):
        result = original(*args, **kwargs)
        calls.append(1)
        if len(calls) == count:  # a kill: no Python cleanup, no finalize
            pids = [str(p.pid) for p in multiprocessing.active_children()]
            (root.parent / "children.txt").write_text(" ".join(pids))
            os._exit(9)
        return result
    return call

if point == "save_episode":
    LeRobotDataset.save_episode = dying(LeRobotDataset.save_episode)
elif point == "finalize":
    LeRobotDataset.finalize = dying(LeRobotDataset.finalize)
elif point == "commit":
    recorder.commit = dying(recorder.commit)
elif point == "journal":
    journal.write = dying(journal.write)
recipe = Recipe(task="Stack", variant="D0", episodes=5, repo_id="local/dur", noise=3.0)
if __name__ == "__main__":
    record(recipe, root=root, progress=False, workers=workers, checkpoint_every=2)
"""


def _kill_at(tmp_path: Path, point: str, count: int, workers: int) -> Path:
    root = tmp_path / "killed"
    res = subprocess.run(
        [sys.executable, "-c", KILL, str(root), point, str(count), str(workers)],
        env=_env(tmp_path), capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert res.returncode == 9, res.stderr[-3000:]
    return root


def _gone(pid: int) -> bool:
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return True
    return "\nState:\tZ" in status  # exited, not yet reaped


def test_a_killed_parallel_recording_resumes_to_the_same_dataset(reference, tmp_path):
    """Killed right after LeRobot wrote episode 3 (after a checkpoint at 2, before the next): the dataset has
    an unfinalized data file, the journal that episode. Its workers exit by themselves; the rerun rolls the
    dataset back to the checkpoint, replays the journal (not simulating that episode again) and ends equal to
    the recording that was never interrupted."""
    root = _kill_at(tmp_path, "save_episode", 3, workers=2)
    log = json.loads((root / "meta" / LOG_NAME).read_text())
    assert log["kept_seeds"] == KEPT[:3] and log["failed_seeds"] == [s for s in FAILED if s < KEPT[2]]
    assert sorted(p.name for p in (root / "meta" / JOURNAL).iterdir()) == [f"{KEPT[2]}.npz"]
    unfinalized = root / "data" / "chunk-000" / "file-001.parquet"
    assert unfinalized.is_file() and unfinalized.read_bytes()[-4:] != b"PAR1"
    children = [int(p) for p in (tmp_path / "children.txt").read_text().split()]
    assert len(children) == 2
    deadline = time.time() + 30
    while time.time() < deadline and not all(_gone(pid) for pid in children):
        time.sleep(0.2)
    assert all(_gone(pid) for pid in children), "workers outlived the killed recording"

    result = record(RECIPE, root=root, progress=False, workers=2, checkpoint_every=EVERY)
    later_failures = sum(seed > KEPT[2] for seed in FAILED)
    assert result.replayed == 1 and result.kept_now == len(KEPT) - 3 and result.failed_now == later_failures
    _assert_same_dataset(root, reference)


@pytest.mark.parametrize(
    ("point", "count", "replayed"),
    [
        ("finalize", 1, 2),  # finalized at the first checkpoint, not committed: rolled back, both replayed
        ("commit", 1, 0),  # committed, journal not emptied: its entries are in the dataset already
        ("journal", 3, 0),  # journaled, not logged: the entry is dropped and the seed simulated again
    ],
)
def test_a_kill_at_any_step_of_the_protocol_resumes_to_the_same_dataset(
    reference, tmp_path, point, count, replayed
):
    root = _kill_at(tmp_path, point, count, workers=1)
    result = record(RECIPE, root=root, progress=False, checkpoint_every=EVERY)
    assert result.replayed == replayed
    _assert_same_dataset(root, reference)


def test_a_journal_missing_an_episode_is_refused(reference, tmp_path):
    """If the log lists kept seeds beyond the finalized dataset that the journal lacks, resuming would skip
    episodes: refuse, saying what is wrong."""
    root = _kill_at(tmp_path, "save_episode", 3, workers=1)
    (root / "meta" / JOURNAL / f"{KEPT[2]}.npz").unlink()
    with pytest.raises(RuntimeError, match=rf"the journal lacks seeds \[{KEPT[2]}\]; delete it"):
        record(RECIPE, root=root, progress=False, checkpoint_every=EVERY)


def test_bad_worker_counts_are_clear_errors(tmp_path):
    with pytest.raises(ValueError, match=r"workers=0; expected an integer >= 1"):
        record(RECIPE, root=tmp_path / "x", workers=0)
    with pytest.raises(ValueError, match=r"checkpoint_every=0; expected an integer >= 1"):
        record(RECIPE, root=tmp_path / "x", checkpoint_every=0)
    res = subprocess.run(
        [str(Path(sys.executable).parent / "actionflow-record"), "--task", "Stack", "--episodes", "1",
         "--workers", "0", "--root", str(tmp_path / "x")],
        env=_env(tmp_path), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2 and "--workers: '0': expected an integer >= 1" in res.stderr, res.stderr
    assert not (tmp_path / "x").exists()
