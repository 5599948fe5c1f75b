"""Lightbulb: the success rule needs both the insertion and the turn, the bulb lights up, and a 1.5 mm offset
of the expert's insertion makes it jam (the task needs millimetre accuracy). The expert: test_experts.py."""

from __future__ import annotations

import gym_actionflow
import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gym_actionflow.experts.base import object_in_tcp
from gym_actionflow.experts.lightbulb import LightbulbExpert
from gym_actionflow.geometry import axis_angle_matrix, matrix_to_quat, pose9, rotation_angle, yaw_matrix
from gym_actionflow.tasks.lightbulb import (
    CLEARANCE,
    GLASS_Z,
    IN_HAND_SHIFT,
    IN_HAND_YAW,
    LOCK_ANGLE,
    LOCK_TOL,
    SOCKET_HEIGHT,
    SOCKET_REGION,
    SOCKET_TOP,
    LightbulbEnv,
)

ENV_ID = "gym_actionflow/Lightbulb-v0"


def make_env(**kwargs) -> gym.Env:
    return gym.make(ENV_ID, **kwargs)


def test_reset_starts_with_the_bulb_held_and_the_layout_in_range():
    """The bulb starts between the pads, gripped, with the documented in-hand offset; the socket is placed in
    its documented region. Guards against a reset that leaves the bulb falling or the gripper open."""
    env = make_env(obs_mode="pixels").unwrapped
    rows = []
    for seed in range(12):
        obs, _ = env.reset(seed=seed)
        assert env.is_grasped(env.bulb_geoms)
        assert 0.03 < env.gripper_opening() < 0.045
        pos, rot = object_in_tcp(env, env.bulb_id)
        assert abs(pos[0]) <= IN_HAND_SHIFT + 5e-4 and abs(pos[1]) < 5e-4
        assert abs(pos[2] - GLASS_Z) <= IN_HAND_SHIFT + 5e-4
        in_hand_yaw = np.arctan2(-rot[0, 0], -rot[1, 0])  # pin 1 nominally along the TCP's -y axis
        assert abs(in_hand_yaw) <= IN_HAND_YAW + 0.01
        assert rot[2, 2] < -0.999  # cap down
        s = obs["token_poses"][2]
        rows.append([s[0], s[1], np.arctan2(s[4], s[3]), in_hand_yaw])
        assert s[2] == pytest.approx(SOCKET_HEIGHT, abs=1e-6)
        assert obs["pixels"]["wrist"].shape == (80, 80, 3)
        np.testing.assert_allclose(obs["token_poses"][1, :3], env.data.xpos[env.bulb_id], atol=1e-6)
    rows = np.array(rows)
    assert np.all((rows[:, 0] >= SOCKET_REGION.x[0]) & (rows[:, 0] <= SOCKET_REGION.x[1]))
    assert np.all((rows[:, 1] >= SOCKET_REGION.y[0]) & (rows[:, 1] <= SOCKET_REGION.y[1]))
    yaw = (rows[:, 2] - SOCKET_REGION.yaw[0]) % (2 * np.pi) + SOCKET_REGION.yaw[0]
    assert np.all(yaw <= SOCKET_REGION.yaw[1] + 1e-5)
    assert np.ptp(rows[:, 0]) > 0.05 and np.ptp(rows[:, 1]) > 0.1 and np.ptp(yaw) > 1.0
    assert np.ptp(rows[:, 3]) > 0.03


def test_bulb_stays_firmly_held_through_a_67_degree_turn():
    """The grasp is firm: turning the hand 67 degrees in the air (as fast as the expert's turn) and moving it
    leaves the bulb within 1 mm and 1.5 degrees of its in-hand pose. (With the Panda-like physics of f2f1b96,
    70 N fingers and stiff contacts, it shifts 0.71 mm and 0.98 degrees; the old soft contacts kept it under
    0.5 mm.)"""
    env = make_env().unwrapped
    env.reset(seed=0)
    pos, rot = env.tcp_pose()
    before = object_in_tcp(env, env.bulb_id)
    for k in range(1, 41):
        s = min(k / 24, 1.0)
        target = rot @ axis_angle_matrix(np.array([0.0, 0.0, -LOCK_ANGLE * s]))
        env.step(np.concatenate([pose9(pos + [0.0, 0.05 * s, -0.08 * s], target), [1.0]]))
    after = object_in_tcp(env, env.bulb_id)
    assert np.linalg.norm(after[0] - before[0]) < 1e-3
    assert rotation_angle(after[1], before[1]) < np.deg2rad(1.5)


# ---------------------------------------------------------------- the success rule on placed states
def place_bulb(env: LightbulbEnv, depth: float, angle: float) -> None:
    """Open the gripper and put the bulb on the socket axis, its cap bottom ``depth`` above the floor, turned
    ``angle`` from the entry slots (pin 1 towards slot 1 at 0)."""
    s_pos, s_rot = env.body_pose(env.socket_id)
    env.data.qpos[env.robot.finger_qpos] = 0.04
    env.data.ctrl[env.robot.finger_ctrl] = 0.04
    env.set_free_pose("bulb_joint", s_pos + s_rot @ np.array([0.0, 0.0, depth]),
                      matrix_to_quat(s_rot @ yaw_matrix(angle)))
    env.data.qvel[:] = 0.0
    mujoco.mj_forward(env.model, env.data)


def step_open(env: LightbulbEnv, steps: int = 5):
    """Hold the hand where it is, gripper open."""
    pos, rot = env.tcp_pose()
    for _ in range(steps):
        out = env.step(np.concatenate([pose9(pos, rot), [-1.0]]))
    return out


@pytest.fixture
def env() -> LightbulbEnv:
    env = make_env(terminate_on_success=False).unwrapped
    env.reset(seed=5)
    return env


def test_seated_and_locked_is_success_and_the_bulb_lights(env):
    """The positive case: the bulb seated and turned 67 degrees (its pins under the upper ring) is success,
    and the glass then glows in the rendered frame (emissive material), which it did not before."""
    frame_off = env.render()
    assert not env.lit
    place_bulb(env, 0.0, LOCK_ANGLE)
    assert env.is_success()
    _, reward, _, _, info = step_open(env)
    assert info["is_success"] and reward == 1.0
    assert env.bulb_seated() and env.bulb_locked() and env.lit
    frame_lit = env.render()
    # Same state, glass switched back to the plain material: the lit frame has much brighter pixels there.
    env.model.geom_matid[env.glass_geom] = env.glass_off
    frame_plain = env.render()
    brighter = frame_lit.astype(int).sum(-1) - frame_plain.astype(int).sum(-1)
    assert (brighter > 60).sum() >= 10
    assert frame_off.shape == frame_lit.shape


def test_seated_at_the_entry_is_not_success(env):
    """Guards against a rule that checks only the insertion: seated but not turned."""
    place_bulb(env, 0.0, 0.0)
    step_open(env)
    assert env.bulb_seated()
    assert abs(env.bulb_angle()) < np.deg2rad(2.0)
    assert not env.is_success() and not env.lit


def test_turned_above_the_socket_is_not_success(env):
    """Guards against a rule that checks only the angle: the bulb turned 67 degrees but held above the socket
    (here 3 cm above its floor, not inserted)."""
    place_bulb(env, 0.03, LOCK_ANGLE)
    assert env.bulb_locked()
    assert not env.bulb_seated()
    assert not env.is_success()
    step_open(env, 1)
    assert not env.lit


def test_half_turn_symmetric_pins_count_either_way(env):
    """Pin 1 in slot 2 is as good as pin 1 in slot 1 (the bulb and the socket are symmetric under a half
    turn); a turn short of the tolerance is not locked."""
    place_bulb(env, 0.0, np.pi + LOCK_ANGLE)
    assert env.is_success()
    place_bulb(env, 0.0, LOCK_ANGLE - LOCK_TOL - np.deg2rad(3.0))
    assert env.bulb_seated() and not env.is_success()


def test_expert_stopped_before_the_turn_is_not_success():
    """The expert's own insertion, without the turn: the bulb ends seated at the entry angle, which is not
    a success."""
    env = make_env(terminate_on_success=False)
    base = env.unwrapped
    expert = LightbulbExpert(env)
    expert.turn = lambda entry_yaw: expert.hold(1)  # skip the 67 degree turn
    obs, _ = env.reset(seed=1)
    expert.reset()
    for _ in range(100):
        obs, _, _, _, info = env.step(expert.act(obs))
        assert not info["is_success"]
    assert base.bulb_seated()
    assert abs(base.bulb_angle()) < np.deg2rad(3.0)
    assert not base.lit


# ---------------------------------------------------------------- accuracy
def run_with_insertion_offset(seed: int, offset=None) -> tuple[bool, LightbulbEnv]:
    """The deterministic expert's episode on ``seed``, its insertion pose shifted by ``offset`` (m)."""
    env = make_env()
    expert = gym_actionflow.make_expert(env, noise=0.0, seed=seed)
    if offset is not None:
        expert.insertion_offset = np.asarray(offset, dtype=float)
    episode = gym_actionflow.run_episode(env, expert, seed)
    return episode.success, env.unwrapped


@pytest.mark.parametrize("seed", [0, 3])
def test_a_1_5_mm_offset_of_the_insertion_makes_it_fail(seed):
    """The paper's accuracy test: the expert's insertion pose shifted by 1.5 mm (the total clearance) across
    the slots, either way, lands the bulb on the socket's rim, where it jams: the expert then turns it on the
    rim, which is not success. Without the offset the same seed succeeds."""
    assert CLEARANCE == pytest.approx(0.0015)
    success, _ = run_with_insertion_offset(seed)
    assert success
    for sign in (1.0, -1.0):
        success, env = run_with_insertion_offset(seed, offset=[0.0, sign * 0.0015, 0.0])
        assert not success
        depth = env.bulb_in_socket()[0][2]
        assert depth > SOCKET_TOP - 0.002, "the bulb should be stuck on the rim, not inserted"
