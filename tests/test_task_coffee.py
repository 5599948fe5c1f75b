"""Coffee: the success rule rejects the near misses, the lid hinge behaves (the expert: test_experts.py)."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gym_actionflow.geometry import pose9
from gym_actionflow.tasks.coffee import (
    FOOTPRINT_CENTER_Y,
    HINGE_Z,
    HOLDER_DEPTH,
    HOLDER_FLOOR_Z,
    LID_CLOSED_MAX,
    LID_HALF,
    LID_OPEN,
    POD_HALF_HEIGHT,
    CoffeeEnv,
)


def fresh_env(variant: str = "D0") -> CoffeeEnv:
    env = gym.make("gym_actionflow/Coffee-v0", variant=variant, terminate_on_success=False).unwrapped
    env.reset(seed=0)
    return env


def settle(env: CoffeeEnv, steps: int = 20) -> None:
    """Step with the arm holding its pose (gripper open), far above the machine and pod."""
    mujoco.mj_forward(env.model, env.data)
    pos, rot = env.tcp_pose()
    for _ in range(steps):
        env.step(np.concatenate([pose9(pos, rot), [-1.0]]))


def place_pod(env: CoffeeEnv, local_xyz) -> None:
    """Put the pod upright with its centre at ``local_xyz`` in the holder frame."""
    h_pos, h_rot = env.body_pose(env.machine_id)
    pos = h_pos + h_rot @ np.asarray(local_xyz, dtype=float)
    env.set_free_pose("pod_joint", pos, np.array([1.0, 0, 0, 0]))


def set_lid(env: CoffeeEnv, angle: float) -> None:
    env.data.qpos[env.lid_qpos] = angle
    env.data.qvel[env.lid_dof] = 0.0


def test_pod_in_holder_and_lid_closed_is_success():
    """The positive case: pod dropped into the holder, lid shut."""
    env = fresh_env()
    place_pod(env, (0.002, -0.001, POD_HALF_HEIGHT + 0.005))
    settle(env, 10)
    set_lid(env, 0.0)
    settle(env, 10)
    assert env.pod_seated()
    assert env.lid_angle() < LID_CLOSED_MAX
    assert env.is_success()


def test_pod_in_holder_with_lid_open_is_not_success():
    """Guards against a rule that forgets the lid: the pod is seated but the lid is still open."""
    env = fresh_env()
    place_pod(env, (0.0, 0.0, POD_HALF_HEIGHT + 0.005))
    settle(env)
    assert env.pod_seated()
    assert env.lid_angle() > 2.0
    assert not env.is_success()


def test_lid_closed_with_pod_on_table_is_not_success():
    """Guards against a rule that checks only the lid: lid shut, pod still on the table."""
    env = fresh_env()
    set_lid(env, 0.0)
    settle(env)
    assert env.lid_angle() < LID_CLOSED_MAX
    assert env.data.xpos[env.pod_id][2] < 2 * POD_HALF_HEIGHT
    assert not env.pod_seated()
    assert not env.is_success()


def test_pod_on_closed_lid_is_not_success():
    """Guards against a rule that checks only the pod's xy: the pod stands on the closed lid, right above the
    holder axis, not inside the holder."""
    env = fresh_env()
    set_lid(env, 0.0)
    lid_top = HINGE_Z + LID_HALF[2]
    place_pod(env, (0.0, 0.0, lid_top + POD_HALF_HEIGHT + 0.001))
    settle(env)
    assert np.hypot(*env.pod_in_holder()[:2]) < 0.005
    assert env.lid_angle() < LID_CLOSED_MAX
    assert not env.is_success()


def test_pod_on_the_rim_blocks_the_lid():
    """A pod standing on the holder rim (not dropped in) sticks out: the lid falls onto it and cannot
    close."""
    env = fresh_env()
    place_pod(env, (0.02, 0.0, HOLDER_DEPTH + POD_HALF_HEIGHT + 0.001))
    settle(env, 10)
    set_lid(env, 1.2)
    settle(env, 40)
    assert env.lid_angle() > LID_CLOSED_MAX
    assert not env.is_success()


def test_open_lid_rests_open_and_pushed_lid_falls_shut_and_stays():
    """The hinge works: the lid rests at its 120 degree start; pushed past vertical, gravity shuts it and it
    stays shut (no bounce, no drift) on the holder."""
    env = fresh_env()
    assert env.lid_angle() == pytest.approx(LID_OPEN, abs=0.01)
    settle(env)
    assert env.lid_angle() == pytest.approx(LID_OPEN, abs=0.01)
    set_lid(env, np.deg2rad(80.0))
    settle(env, 30)
    assert abs(env.lid_angle()) < np.deg2rad(1.0)
    settle(env, 40)
    assert abs(env.lid_angle()) < np.deg2rad(1.0)
    assert abs(env.data.qvel[env.lid_dof]) < 1e-3


def test_tokens_and_lid_scalar():
    """Token order pod, machine (holder frame), lid; the lid angle feature sits on the lid token only."""
    env = fresh_env()
    obs, _ = env.reset(seed=3)
    poses, feats = obs["token_poses"], obs["token_features"]
    assert poses.shape == (4, 9) and feats.shape == (4, 6)
    np.testing.assert_allclose(poses[1, :3], env.data.xpos[env.pod_id], atol=1e-6)
    assert poses[2, 2] == pytest.approx(HOLDER_FLOOR_Z, abs=1e-6)
    np.testing.assert_allclose(poses[3, :3], env.data.xpos[env.lid_id], atol=1e-6)
    assert feats[3, 5] == pytest.approx(LID_OPEN, abs=0.01)
    assert np.all(feats[:3, 5] == 0)


def holder_layouts(variant: str, n: int = 15) -> np.ndarray:
    env = gym.make("gym_actionflow/Coffee-v0", variant=variant).unwrapped
    rows = []
    for seed in range(n):
        obs, _ = env.reset(seed=seed)
        p = obs["token_poses"][2]
        rows.append([p[0], p[1], np.arctan2(p[4], p[3]), *obs["token_poses"][1, :2]])
    return np.array(rows)


def test_d0_fixes_the_machine_and_d1_moves_it():
    """D0 places the machine at MimicGen's fixed pose; D1 randomises its position and yaw (-30..60 degrees)
    and spreads the pod wider."""
    d0, d1 = holder_layouts("D0"), holder_layouts("D1")
    assert np.ptp(d0[:, :3], axis=0).max() < 1e-6
    assert d0[0, 2] == pytest.approx(-np.pi / 6, abs=1e-5)
    assert np.ptp(d1[:, 0]) > 0.03 and np.ptp(d1[:, 1]) > 0.03 and np.ptp(d1[:, 2]) > 0.5
    assert np.all(d1[:, 2] >= -np.pi / 6 - 1e-5) and np.all(d1[:, 2] <= np.pi / 3 + 1e-5)
    assert np.all((d0[:, 3] >= -0.13) & (d0[:, 3] <= -0.07) & (d0[:, 4] >= 0.17) & (d0[:, 4] <= 0.23))
    assert np.all((d1[:, 3] >= -0.2) & (d1[:, 3] <= 0.05) & (d1[:, 4] >= 0.17) & (d1[:, 4] <= 0.3))
    assert np.ptp(d1[:, 3]) > np.ptp(d0[:, 3])


def test_d2_swaps_the_sides_of_d1():
    """D2 holds MimicGen's Coffee_D2 ranges: the machine's footprint centre in x [-0.05, 0.05], y [0.1, 0.2],
    yaw [120, 210] degrees (facing the pod's side); the pod in x [-0.2, 0.05], y [-0.3, -0.17]. Guards against
    D2 keeping D1's sides, a yaw range that turns the holder away from the pod, or ranges that collapse."""
    env = gym.make("gym_actionflow/Coffee-v0", variant="D2").unwrapped
    rows = []
    for seed in range(30):
        obs, _ = env.reset(seed=seed)
        holder, pod = obs["token_poses"][2].astype(np.float64), obs["token_poses"][1].astype(np.float64)
        yaw = np.arctan2(holder[4], holder[3]) % (2 * np.pi)
        footprint = holder[:2] + FOOTPRINT_CENTER_Y * holder[6:8]  # along the holder's +y axis
        assert -0.05 - 1e-6 <= footprint[0] <= 0.05 + 1e-6 and 0.1 - 1e-6 <= footprint[1] <= 0.2 + 1e-6
        assert 2 * np.pi / 3 - 1e-5 <= yaw <= 7 * np.pi / 6 + 1e-5
        assert -0.2 - 1e-6 <= pod[0] <= 0.05 + 1e-6 and -0.3 - 1e-6 <= pod[1] <= -0.17 + 1e-6
        assert np.dot(holder[6:8], pod[:2] - holder[:2]) > 0, "the holder should face the pod's side"
        assert env.lid_angle() == pytest.approx(LID_OPEN, abs=0.01) and not env.is_success()
        rows.append([*footprint, yaw, *pod[:2]])
    rows = np.array(rows)
    assert np.ptp(rows[:, 0]) > 0.06 and np.ptp(rows[:, 1]) > 0.06 and np.ptp(rows[:, 2]) > 1.0
    assert np.ptp(rows[:, 3]) > 0.15 and np.ptp(rows[:, 4]) > 0.08
    env.close()
