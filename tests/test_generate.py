"""actionflow-generate (MimicGen's protocol): the cut into subtasks, the linking motion and the object-centric
transform against independent references, exact replay of a source on its own layout, and the real command
from a tiny expert recording (D0 sources, D1 layouts), with its card, provenance file and bad-input errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gym_actionflow import find_task
from gym_actionflow.registry import ROUND, TASKS
from scipy.spatial.transform import Rotation, Slerp

from lerobot_actionflow.tools import generate
from lerobot_actionflow.tools.generate import (
    SETTLE_RADIUS,
    Segment,
    SegmentPlayer,
    Source,
    link,
    load_source,
    split,
    to_matrix,
    to_pose9,
)
from lerobot_actionflow.tools.record.recipe import Recipe
from lerobot_actionflow.tools.record.recorder import record


def _pose(rng: np.random.Generator, scale: float = 0.3) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    m[:3, 3] = rng.uniform(-scale, scale, 3)
    return m


def _actions(positions: np.ndarray, grips: np.ndarray) -> np.ndarray:
    pairs = zip(positions, grips, strict=True)
    rows = [np.concatenate([to_pose9(_hom(np.eye(3), p)), [g]]) for p, g in pairs]
    return np.array(rows)


def _hom(rot: np.ndarray, pos: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rot, pos
    return m


def test_an_episode_is_cut_after_each_gripper_change_once_the_hand_has_moved_on():
    """Close at frame 3, hold while the fingers close, lift: the cut comes at the first target
    SETTLE_RADIUS from the close, so the grasp and its lift stay in the first subtask."""
    z = [0.3, 0.2, 0.1, 0.05, 0.05, 0.051, 0.06, 0.05 + SETTLE_RADIUS + 0.001, 0.2, 0.3]
    positions = np.array([[0.0, 0.0, v] for v in z])
    grips = np.array([-1, -1, -1, 1, 1, 1, 1, 1, 1, 1.0])
    assert split(_actions(positions, grips), 2) == [(0, 7), (7, 10)]
    assert split(_actions(positions, grips), 3) is None  # one change: not a three-subtask episode
    assert split(_actions(positions, -np.ones(10)), 1) == [(0, 10)]


def test_the_link_is_a_straight_evenly_timed_line_and_the_rotation_geodesic():
    """Against scipy's Slerp: every intermediate rotation on the geodesic at its time, the position on the
    line; the number of steps is set by the slower of the two at the experts' speeds."""
    rng = np.random.default_rng(0)
    start, end = _pose(rng), _pose(rng)
    path = link(start, end)
    np.testing.assert_allclose(path[-1], end, atol=1e-9)
    angle = Rotation.from_matrix(start[:3, :3].T @ end[:3, :3]).magnitude()
    distance = np.linalg.norm(end[:3, 3] - start[:3, 3])
    assert len(path) == int(np.ceil(max(distance / generate.LINK_SPEED, angle / generate.LINK_ROT_SPEED)))
    slerp = Slerp([0, 1], Rotation.from_matrix([start[:3, :3], end[:3, :3]]))
    for k, m in enumerate(path, start=1):
        s = k / len(path)
        np.testing.assert_allclose(m[:3, :3], slerp(s).as_matrix(), atol=1e-8)
        np.testing.assert_allclose(m[:3, 3], (1 - s) * start[:3, 3] + s * end[:3, 3], atol=1e-12)


class _FakeEnv:
    """What the player reads of an env: the TCP pose and the objects' poses."""

    def __init__(self, tcp: np.ndarray, objects: dict[str, np.ndarray]):
        self.unwrapped = self
        self._tcp, self._objects = tcp, objects

    def tcp_pose(self):
        return self._tcp[:3, 3], self._tcp[:3, :3]

    def object_poses(self):
        return {k: (m[:3, 3], m[:3, :3]) for k, m in self._objects.items()}


def _played(player: SegmentPlayer, env=None) -> list[np.ndarray]:
    """Every action of the player, each stepped in ``env`` if given."""
    out = []
    while (action := player.act()) is not None:
        out.append(action)
        if env is not None:
            env.step(action)
    return out


def test_a_segment_moves_rigidly_with_its_object_and_a_carried_object_retraces_its_path():
    """A random SE(3) motion of the reference object moves every target of the segment by exactly that
    motion (after the linking steps); with a carried object sitting differently in the hand, the carried
    object's implied world poses, not the hand's, are the source's moved by the same motion."""
    rng = np.random.default_rng(1)
    src_obj, src_in_hand, now_in_hand = _pose(rng), _pose(rng, 0.05), _pose(rng, 0.05)
    targets = [_pose(rng) for _ in range(6)]
    actions = np.array([np.concatenate([to_pose9(t), [1.0]]) for t in targets])
    motion = _pose(rng)
    new_obj = motion @ src_obj
    tcp = targets[0]  # the hand already at the segment's start: no link beyond one step
    plain = Segment(0, "box", src_obj, actions)
    played = _played(SegmentPlayer(_FakeEnv(tcp, {"box": new_obj}), Source("s", "T", [[plain]]), seed=0))
    moved = played[-(len(targets) + generate.HOLD_STEPS) : -generate.HOLD_STEPS]
    for action, target in zip(moved, targets, strict=True):
        np.testing.assert_allclose(to_matrix(action[:9]), motion @ target, atol=1e-6)

    carried = Segment(0, "box", src_obj, actions, carried="cup", in_hand=src_in_hand)
    env = _FakeEnv(tcp, {"box": new_obj, "cup": tcp @ now_in_hand})
    played = _played(SegmentPlayer(env, Source("s", "T", [[carried]]), seed=0))
    moved = played[-(len(targets) + generate.HOLD_STEPS) : -generate.HOLD_STEPS]
    for action, target in zip(moved, targets, strict=True):
        cup_world = to_matrix(action[:9]) @ now_in_hand
        np.testing.assert_allclose(cup_world, motion @ target @ src_in_hand, atol=1e-6)


def test_a_symmetric_object_is_taken_at_the_equivalent_pose_that_turns_the_hand_least():
    """A cube turned by 100 degrees about its vertical axis: with four-fold symmetry the segment turns the
    hand by 10 degrees (the equivalent pose 90 degrees back), against the full 100 without symmetry; every
    target is still the source's moved rigidly by one equivalent motion of the cube."""
    from gym_actionflow.experts.base import top_down
    from gym_actionflow.geometry import yaw_matrix

    src_obj = _hom(np.eye(3), np.array([0.1, 0.0, 0.02]))
    new_obj = _hom(yaw_matrix(np.radians(100)), np.array([-0.1, 0.1, 0.02]))
    hand = _hom(top_down(0.0), np.array([0.0, 0.0, 0.3]))
    targets = [_hom(top_down(0.0), src_obj[:3, 3] + [0, 0, z]) for z in (0.1, 0.05, 0.0)]
    actions = np.array([np.concatenate([to_pose9(t), [-1.0]]) for t in targets])

    def turn_of_first_target(symmetry: int) -> float:
        segment = Segment(0, "cube", src_obj, actions, symmetry=symmetry)
        player = SegmentPlayer(_FakeEnv(hand, {"cube": new_obj}), Source("s", "T", [[segment]]), seed=0)
        played = _played(player)[-(len(targets) + generate.HOLD_STEPS) : -generate.HOLD_STEPS]
        moved = [to_matrix(a[:9]) for a in played]
        motion = moved[0] @ np.linalg.inv(targets[0])
        for m, t in zip(moved, targets, strict=True):
            np.testing.assert_allclose(m, motion @ t, atol=1e-9)
        np.testing.assert_allclose(motion[:3, 3] + motion[:3, :3] @ src_obj[:3, 3], new_obj[:3, 3], atol=1e-9)
        return np.degrees(Rotation.from_matrix(hand[:3, :3].T @ moved[0][:3, :3]).magnitude())

    assert turn_of_first_target(4) == pytest.approx(10.0, abs=1e-6)
    assert turn_of_first_target(1) == pytest.approx(100.0, abs=1e-6)
    assert turn_of_first_target(ROUND) == pytest.approx(0.0, abs=0.5)  # a round object: any yaw is its own


def test_every_task_declares_subtasks_naming_tokens_its_env_has():
    """Every task can be generated: a subtask's reference and carried objects are tokens of the task's env
    (else no source could hold them)."""
    import importlib.util

    for spec in TASKS:
        assert spec.subtasks, spec.name
        if spec.simulator == "robosuite" and importlib.util.find_spec("robosuite") is None:
            continue
        env = gym.make(spec.env_id, **spec.kwargs())
        names = env.unwrapped.token_names
        env.close()
        for sub in spec.subtasks:
            assert sub.object in names and (sub.carried is None or sub.carried in names), (spec.name, sub)


@pytest.fixture(scope="module")
def stack_source(tmp_path_factory) -> Path:
    """Three Stack D0 expert demonstrations (the standard noise), recorded by actionflow-record."""
    root = tmp_path_factory.mktemp("gen") / "src"
    record(Recipe("Stack", "D0", 3, "local/stack_src3", seed=0, noise=1.0), root, progress=False)
    return root


def test_a_source_replayed_on_its_own_layout_is_the_source(stack_source, monkeypatch):
    """On the layout of source episode 0, its segments are the nearest (their links one step to where the
    hand already is), and with the single nearest drawn the generated actions are the recorded ones (the
    transforms are the identity)."""
    source = load_source(stack_source, "Stack")
    assert [len(c) for c in source.segments] == [3, 3, 3] and source.skipped == {}
    env = gym.make(find_task("Stack").env_id, variant="D0")
    env.reset(seed=0)
    monkeypatch.setattr(generate, "NEAREST", 1)
    player = SegmentPlayer(env, source, seed=0)
    played = np.array(_played(player, env))[: -generate.HOLD_STEPS]
    assert player.played == [0, 0, 0]  # the episode recorded from seed 0
    recorded = np.concatenate([c[0].actions for c in source.segments])
    env.close()
    assert played.shape == recorded.shape
    np.testing.assert_allclose(played, recorded, atol=1e-6)


def test_generate_writes_a_dataset_for_layouts_the_sources_never_showed(stack_source, tmp_path, capsys):
    """The real command, D0 sources -> D1 layouts: a LeRobotDataset of successes with the source's schema,
    its card naming the source and the generation rate, the source episode of every segment, and a rerun
    that adds nothing."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    out = tmp_path / "gen"
    argv = [str(stack_source), "--task", "Stack", "--variant", "D1", "--episodes", "2", "--seed", "1000",
            "--root", str(out), "--quiet"]  # fmt: skip
    assert generate.main(argv) == 0
    ds = LeRobotDataset("local/stack_d1_gen2", root=out)
    assert ds.meta.total_episodes == 2
    source_ds = LeRobotDataset("local/stack_src3", root=stack_source)
    assert set(ds.meta.features) == set(source_ds.meta.features)
    card = (out / "README.md").read_text()
    assert "generated with `actionflow-generate`" in card and str(stack_source) in card
    assert "generation success rate" in card and "actionflow-generate " in card
    info = json.loads((out / "meta" / generate.GENERATION_FILE).read_text())
    log = json.loads((out / "meta" / "actionflow_recording.json").read_text())
    assert [e["seed"] for e in info["episodes"]] == log["kept_seeds"]
    assert all(len(e["segments"]) == 3 and set(e["segments"]) <= {0, 1, 2} for e in info["episodes"])
    assert log["recipe"]["source"] == str(stack_source) and log["recipe"]["variant"] == "D1"
    capsys.readouterr()
    assert generate.main(argv) == 0  # finished: nothing generated again
    assert "2 episodes generated" in capsys.readouterr().out
    assert LeRobotDataset("local/stack_d1_gen2", root=out).meta.total_episodes == 2
    other = [*argv[:4], "D0", *argv[5:]]  # the same --root, another recording: refused, nothing written
    assert generate.main(other) == 2
    assert "holds a different recording" in capsys.readouterr().err


def test_a_robosuite_task_is_generated_from_its_expert_recording(tmp_path):
    """Square on robosuite (grasp the nut, fit it over the peg; the episode ends before the release): two
    expert demonstrations cut into two subtasks each, and most episodes generated on new layouts succeed (the
    bench's rate from 10 sources: 94 %)."""
    pytest.importorskip("robosuite")
    root = tmp_path / "src"
    record(Recipe("RobosuiteSquare", "D0", 2, "local/square_src2", seed=0, noise=1.0), root, progress=False)
    source = load_source(root, "RobosuiteSquare")
    assert [len(c) for c in source.segments] == [2, 2] and source.skipped == {}
    env = gym.make(find_task("RobosuiteSquare").env_id, variant="D0")
    kept = [generate.run_generated(env, source, seed)[0] for seed in (1000, 1001, 1002)]
    env.close()
    assert sum(kept) >= 2, kept


def test_bad_sources_are_refused_by_name(stack_source, tmp_path, monkeypatch):
    """Another task's recording, an empty dataset, a folder that is no dataset, a task that declares no
    subtasks, a recording without a way to tell successes, and one whose every episode failed: each a
    ValueError saying what was found."""
    import dataclasses

    from gym_actionflow import registry

    with pytest.raises(ValueError, match="is a recording of Stack, not Threading"):
        load_source(stack_source, "Threading")
    with pytest.raises(ValueError, match="no meta/info.json"):
        load_source(tmp_path, "Stack")
    without = tuple(dataclasses.replace(t, subtasks=()) if t.name == "Stack" else t for t in registry.TASKS)
    with monkeypatch.context() as patch:
        patch.setattr(registry, "TASKS", without)
        with pytest.raises(ValueError, match="Stack declares no subtasks"):
            load_source(stack_source, "Stack")
    empty = tmp_path / "empty"
    shutil.copytree(stack_source, empty)
    info = json.loads((empty / "meta" / "info.json").read_text())
    (empty / "meta" / "info.json").write_text(json.dumps(info | {"total_episodes": 0}))
    with pytest.raises(ValueError, match="holds no episode"):
        load_source(empty, "Stack")
    unknown = tmp_path / "unknown"
    shutil.copytree(stack_source, unknown)
    (unknown / "meta" / "actionflow_recording.json").unlink()
    with pytest.raises(ValueError, match="neither which episodes succeeded"):
        load_source(unknown, "Stack")
    failed = _with_success_column(stack_source, tmp_path / "failed", value=False)
    with pytest.raises(ValueError, match="no usable successful episode.*did not end in success"):
        load_source(failed, "Stack")
    kept = _with_success_column(stack_source, tmp_path / "kept", value=True)
    assert len(load_source(kept, "Stack").episodes) == 3  # a recording that says its episodes succeeded


def _with_success_column(source: Path, root: Path, value: bool) -> Path:
    """A copy of ``source`` as another tool would leave it: no recording log, a next.success column."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    shutil.copytree(source, root)
    (root / "meta" / "actionflow_recording.json").unlink()
    for file in (root / "data").rglob("*.parquet"):
        table = pq.read_table(file)
        column = pa.array([[value]] * table.num_rows, type=pa.list_(pa.bool_()))
        pq.write_table(table.append_column(generate.SUCCESS_KEY, column), file)
    info = json.loads((root / "meta" / "info.json").read_text())
    info["features"][generate.SUCCESS_KEY] = {"dtype": "bool", "shape": [1], "names": None}
    (root / "meta" / "info.json").write_text(json.dumps(info))
    return root


FIXTURE_POLICY = Path(__file__).parent / "fixtures" / "policy_ipa_se3"
"""A tiny saved ActionFlow policy on three tokens (Stack's eef, cube_a, cube_b), untrained."""


def test_a_policy_is_recorded_through_the_recorder_and_only_its_successes_kept(tmp_path, monkeypatch):
    """``actionflow-record --policy``: the checkpoint drives the env from each seed; an untrained policy's
    failures are logged as failed seeds, none kept, and the run stops with an error naming the policy. A
    missing checkpoint, or a policy together with a source, is refused before anything is written."""
    from lerobot_actionflow.tools.record import recorder
    from lerobot_actionflow.tools.record.cli import main as record_main

    monkeypatch.setattr(recorder, "GENERATION_FAILURES", 0.05)  # give up after two failures
    root = tmp_path / "rollouts"
    with pytest.raises(RuntimeError, match="the policy failed 2 times"):
        record(Recipe("Stack", "D0", 1, "local/pol", policy=str(FIXTURE_POLICY)), root, progress=False)
    log = json.loads((root / "meta" / "actionflow_recording.json").read_text())
    assert log["kept_seeds"] == [] and log["failed_seeds"] == [0, 1]
    assert log["recipe"]["policy"] == str(FIXTURE_POLICY)
    card = (root / "README.md").read_text()
    assert "Successful rollouts of a trained policy" in card and "--policy" in card
    with pytest.raises(ValueError, match="config.json"):
        Recipe("Stack", "D0", 1, "local/pol", policy=str(tmp_path))
    with pytest.raises(ValueError, match="not both"):
        Recipe("Stack", "D0", 1, "local/pol", policy=str(FIXTURE_POLICY), source=str(tmp_path))
    assert record_main(["--task", "Stack", "--episodes", "1", "--policy", str(tmp_path / "none")]) == 2


def test_generation_through_ray_actors_is_the_local_generation(stack_source, tmp_path, monkeypatch):
    """``--executor ray --workers 2``: two Ray actors (on a Ray started by the command) simulate, the source
    shipped to them from here; the kept and failed seeds and every frame equal the local run's."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")  # a local Ray for one test: no token file in $HOME
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    log_name = "actionflow_recording.json"
    base = [str(stack_source), "--task", "Stack", "--variant", "D1", "--episodes", "2", "--seed", "2000",
            "--repo-id", "local/stack_gen2", "--quiet"]  # fmt: skip
    assert generate.main([*base, "--root", str(tmp_path / "local")]) == 0
    assert generate.main([*base, "--root", str(tmp_path / "ray"), "--executor", "ray", "--workers", "2"]) == 0
    logs = [json.loads((tmp_path / r / "meta" / log_name).read_text()) for r in ("local", "ray")]
    seeds = [(log["kept_seeds"], log["failed_seeds"]) for log in logs]
    assert seeds[1] == seeds[0]
    local, ray = (
        LeRobotDataset("local/stack_gen2", root=tmp_path / r).hf_dataset.with_format("numpy")[:]
        for r in ("local", "ray")
    )
    assert local.keys() == ray.keys()
    for key in local:
        np.testing.assert_array_equal(np.stack(ray[key]), np.stack(local[key]), err_msg=key)
    with pytest.raises(SystemExit):  # an address is a Ray cluster's: it needs --executor ray
        generate.main([*base, "--root", str(tmp_path / "x"), "--address", "head:6379"])


def test_demo_stats_measure_the_hand_path_and_the_wrist_turn(stack_source):
    """eval.diagnostics.demo_stats on three expert episodes: the frame count and path length equal a direct
    read of the actions, and the expert's top-down grasps stay within 45 degrees of home at the median."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from eval.diagnostics.demo_stats import stats

    data = LeRobotDataset("local/stack_src3", root=stack_source).hf_dataset.with_format("numpy")[:]
    actions, episode = np.stack(data["action"]), np.asarray(data["episode_index"])
    paths = [np.linalg.norm(np.diff(actions[episode == e, :3], axis=0), axis=1).sum() for e in (0, 1, 2)]
    got = stats(stack_source)
    assert got["episodes"] == 3 and got["frames"] == pytest.approx(len(actions) / 3)
    assert got["path_m"] == pytest.approx(np.mean(paths), rel=1e-5)
    assert 0 <= got["yaw_p50"] <= 45 and got["yaw_p50"] <= got["yaw_p90"] <= got["yaw_p99"] <= 180


def test_loader_order_counts_distinct_episodes_per_batch_and_per_ten(stack_source):
    """eval.diagnostics.loader_order: the counts on orders worked out by hand, and the shuffled order of a
    real dataset draws every frame once per pass."""
    from eval.diagnostics.loader_order import mixing, shuffled_order

    in_order = np.repeat(np.arange(40), 8)  # 40 episodes of 8 frames read in file order: 4 per batch of 32
    assert mixing(in_order, 32) == (4.0, 40.0)
    assert mixing(np.tile(np.arange(32), 10), 32) == (32.0, 32.0)
    with pytest.raises(ValueError, match="at least one batch"):
        mixing(np.arange(5), 32)
    import pyarrow.parquet as pq

    frames = sum(pq.read_metadata(f).num_rows for f in (stack_source / "data").rglob("*.parquet"))
    order = shuffled_order(stack_source, frames)
    assert np.array_equal(np.bincount(order), np.bincount(np.sort(order)))
    assert len(order) == frames and sorted(set(order.tolist())) == [0, 1, 2]
