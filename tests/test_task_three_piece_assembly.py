"""ThreePieceAssembly: success rule, base fixture and layout (the expert: test_experts.py)."""

from __future__ import annotations

import gym_actionflow
import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gym_actionflow.base import HOME_POS, HOME_ROT, ROBOT_BASE
from gym_actionflow.geometry import pose9, yaw_quat
from gym_actionflow.tasks.three_piece_assembly import (
    BASE_D0,
    PIECE1_HEIGHT,
    PIECE_YAW,
    RANGE,
    REACH,
    SLAB_HEIGHT,
    Z_TOL,
    ThreePieceAssemblyEnv,
)

ENV_ID = "gym_actionflow/ThreePieceAssembly-v0"
HOLD = np.concatenate([pose9(HOME_POS, HOME_ROT), [-1.0]]).astype(np.float32)
"""Keep the arm at its home pose, gripper open (far from the pieces)."""


@pytest.fixture(scope="module")
def env():
    e = gym.make(ENV_ID, variant="D0")
    yield e
    e.close()


def settle(env, piece_1, piece_2, steps: int = 10) -> ThreePieceAssemblyEnv:
    """Reset, put the pieces at ((x, y, z), yaw) (body origin = centre of the bottom face), then hold."""
    env.reset(seed=0)
    u = env.unwrapped
    for name, (pos, yaw) in (("piece_1", piece_1), ("piece_2", piece_2)):
        u.set_free_pose(f"{name}_joint", np.asarray(pos, dtype=float), yaw_quat(yaw))
    mujoco.mj_forward(u.model, u.data)
    for _ in range(steps):
        env.step(HOLD)
    return u


def seat(u) -> np.ndarray:
    return u.data.xpos[u.base_id].copy()


def test_assembled_is_success(env):
    """Positive case: piece 1 in the socket, piece 2's slot over piece 1's ridge, nothing held -> success.
    Guards against seat heights / tolerances that make the real assembled state fail."""
    u = settle(env, ((0, 0, 0), PIECE_YAW), ((0, 0, 0), PIECE_YAW))
    s = seat(u)
    u = settle(env, ((s[0], s[1], 0.0), PIECE_YAW), ((s[0], s[1], SLAB_HEIGHT + 0.001), PIECE_YAW))
    assert u.piece_1_assembled() and u.piece_2_assembled()
    assert u.is_success()
    # Any quarter turn of piece 1 fits the square socket; piece 2 has to match piece 1 modulo a half turn.
    u = settle(env, ((s[0], s[1], 0.0), 0.0), ((s[0], s[1], SLAB_HEIGHT + 0.001), np.pi))
    assert u.is_success()


def test_piece_2_on_piece_1_outside_the_base_is_not_success(env):
    """Piece 2 correctly seated on piece 1 while piece 1 lies on the table away from the base is not success
    (guards against a rule that only checks piece 2 relative to piece 1)."""
    u = settle(env, ((-0.2, 0.2, 0.0), PIECE_YAW), ((-0.2, 0.2, SLAB_HEIGHT + 0.001), PIECE_YAW))
    assert u.piece_2_assembled()
    assert not u.piece_1_assembled()
    assert not u.is_success()


def test_piece_next_to_the_socket_is_not_success(env):
    """A piece lying on the table next to the socket (within a few cm of it, at the seated height of piece 1)
    is not inserted (guards against loose xy / z thresholds)."""
    s = seat(settle(env, ((0, 0, 0), PIECE_YAW), ((0, 0, 0), PIECE_YAW)))
    # Piece 1 just outside the frame, piece 2 on it: only the xy check can reject it.
    x = s[0] + 0.16
    u = settle(env, ((x, s[1], 0.0), PIECE_YAW), ((x, s[1], SLAB_HEIGHT + 0.001), PIECE_YAW))
    assert abs(u.data.xpos[u.piece_ids["piece_1"]][2] - s[2]) < Z_TOL
    assert not u.piece_1_assembled() and not u.is_success()
    # Piece 1 in the socket, piece 2 lying on the table next to the base.
    u = settle(env, ((s[0], s[1], 0.0), PIECE_YAW), ((s[0], s[1] - 0.17, 0.0), PIECE_YAW))
    assert u.piece_1_assembled()
    assert not u.piece_2_assembled() and not u.is_success()


def test_piece_2_alone_in_the_socket_is_not_success(env):
    """Piece 2 dropped into the empty socket (it fits) with piece 1 elsewhere is not success."""
    s = seat(settle(env, ((0, 0, 0), PIECE_YAW), ((0, 0, 0), PIECE_YAW)))
    u = settle(env, ((-0.2, -0.2, 0.0), PIECE_YAW), ((s[0], s[1], 0.001), PIECE_YAW))
    assert not u.piece_1_assembled() and not u.piece_2_assembled() and not u.is_success()


def test_piece_2_across_the_ridge_is_not_success(env):
    """Piece 2 turned a quarter turn rests on top of the ridge instead of over it: not seated, not success
    (guards against an xy-only rule, which MimicGen's z check also rules out)."""
    s = seat(settle(env, ((0, 0, 0), PIECE_YAW), ((0, 0, 0), PIECE_YAW)))
    u = settle(env, ((s[0], s[1], 0.0), PIECE_YAW), ((s[0], s[1], 0.095), PIECE_YAW + np.pi / 2), steps=20)
    assert u.piece_1_assembled()
    p2 = u.data.xpos[u.piece_ids["piece_2"]]
    assert p2[2] > s[2] + SLAB_HEIGHT + 0.03, "piece 2 should rest on the ridge"
    assert not u.piece_2_assembled() and not u.is_success()


def test_held_piece_is_not_assembled():
    """Piece 1 held by the gripper, above its seat or down in it, is not assembled; once released it is
    (guards against a rule that forgets the grasp check)."""
    env = gym.make(ENV_ID, variant="D0")
    u = env.unwrapped
    expert = gym_actionflow.make_expert(env, noise=0.0, seed=0)
    obs, _ = env.reset(seed=0)
    expert.reset(seed=0)
    geoms, body = u.piece_geoms["piece_1"], u.piece_ids["piece_1"]
    held_above = False
    for _ in range(300):  # the expert carries piece 1 over the socket and inserts it
        obs, *_ = env.step(expert.act(obs))
        if u.is_grasped(geoms):
            assert not u.piece_1_assembled() and not u.is_success()
            over_seat = np.linalg.norm(u.data.xpos[body][:2] - seat(u)[:2]) < 0.02
            held_above |= over_seat and u.data.xpos[body][2] > 0.02
        elif u.piece_1_assembled():
            break
    assert held_above and u.piece_1_assembled()
    # Grasp the seated piece again: every clause of the rule holds except "not grasped".
    tcp_rot = u.tcp_pose()[1]
    grasp = u.data.xpos[body] + [0.0, 0.0, PIECE1_HEIGHT - 0.025]
    for z, grip, steps in ((0.08, -1.0, 10), (0.0, -1.0, 10), (0.0, 1.0, 8)):
        action = np.concatenate([pose9(grasp + [0, 0, z], tcp_rot), [grip]]).astype(np.float32)
        for _ in range(steps):
            env.step(action)
    assert u.is_grasped(geoms)
    assert abs(u.data.xpos[body][2] - seat(u)[2]) < Z_TOL
    assert not u.piece_1_assembled() and not u.is_success()
    action[-1] = -1.0
    for _ in range(8):
        env.step(action)
    assert u.piece_1_assembled()
    env.close()


def test_base_is_a_fixture_fixed_in_d0_and_moved_in_d1():
    """The base has no joint; D0 keeps it at the documented pose, D1 moves it (within range and reach) at
    reset, and its token pose follows."""
    d0 = gym.make(ENV_ID, variant="D0").unwrapped
    d1 = gym.make(ENV_ID, variant="D1").unwrapped
    assert d0.model.body_jntnum[d0.base_id] == 0
    seen = []
    for s in range(5):
        obs, _ = d0.reset(seed=s)
        np.testing.assert_allclose(obs["token_poses"][1, :3], [*BASE_D0, 0.0], atol=1e-6)
        obs, _ = d1.reset(seed=s)
        base = obs["token_poses"][1, :3]
        np.testing.assert_allclose(base, d1.data.xpos[d1.base_id], atol=1e-6)
        np.testing.assert_allclose(obs["token_poses"][1, 3:], [1, 0, 0, 0, 1, 0], atol=1e-6)  # yaw 0
        assert np.all(np.abs(base[:2]) <= RANGE) and np.linalg.norm(base[:2] - ROBOT_BASE[:2]) <= REACH
        seen.append(base[:2])
    assert np.ptp(np.array(seen), axis=0).min() > 0.05, "D1 should spread the base"
    # The walls moved with the body: a geom of the base is near its new position.
    wall = d1.model.geom("base_wall_px").id
    assert np.linalg.norm(d1.data.geom_xpos[wall][:2] - d1.data.xpos[d1.base_id][:2]) < 0.1


@pytest.mark.parametrize("variant", ["D0", "D1"])
def test_layout_separated_reachable_and_seeded(variant):
    """Pieces start upright with yaw pi/2 on the table, inside +-0.22 m and the reach limit, apart from each
    other and the base; the same seed gives the same layout."""
    env = gym.make(ENV_ID, variant=variant).unwrapped
    for s in range(20):
        obs, _ = env.reset(seed=s)
        poses = obs["token_poses"]
        base, p1, p2 = poses[1, :2], poses[2, :2], poses[3, :2]
        for p in (p1, p2):
            assert np.all(np.abs(p) <= RANGE + 1e-6)
            assert np.linalg.norm(p - ROBOT_BASE[:2]) <= REACH + 1e-6
            assert np.linalg.norm(p - base) > 0.19
        assert np.linalg.norm(p1 - p2) > 0.14
        for row in poses[2:]:
            assert abs(row[2]) < 2e-3
            np.testing.assert_allclose(row[3:6], [np.cos(PIECE_YAW), np.sin(PIECE_YAW), 0], atol=1e-3)
        again, _ = env.reset(seed=s)
        np.testing.assert_array_equal(again["token_poses"][1:], poses[1:])
        assert not env.is_success()


def test_d2_turns_the_base_and_the_pieces():
    """D2 holds MimicGen's ThreePieceAssembly_D2 ranges: the base anywhere in +-0.22 m turned by up to 45
    degrees, each piece anywhere in +-0.22 m with its own yaw in [0, pi]; within reach, apart, upright, and
    the base's walls turned with its token. Guards against D2 falling back to D1's fixed yaws, pieces sharing
    one yaw, or a base whose geoms do not follow its sampled pose."""
    env = gym.make(ENV_ID, variant="D2").unwrapped
    yaws = []
    for s in range(30):
        obs, _ = env.reset(seed=s)
        poses = obs["token_poses"].astype(np.float64)
        base_yaw, p1_yaw, p2_yaw = (np.arctan2(row[4], row[3]) for row in poses[1:])
        assert abs(base_yaw) <= np.pi / 4 + 1e-6
        assert np.sin(p1_yaw) >= -1e-6 and np.sin(p2_yaw) >= -1e-6  # yaw in [0, pi]
        for row in poses[1:]:
            assert np.all(np.abs(row[:2]) <= RANGE + 1e-6)
            assert np.linalg.norm(row[:2] - ROBOT_BASE[:2]) <= REACH + 1e-6
            assert abs(row[2]) < 2e-3 and abs(row[5]) < 1e-3  # on the table, upright
        base, p1, p2 = poses[1, :2], poses[2, :2], poses[3, :2]
        assert min(np.linalg.norm(p1 - base), np.linalg.norm(p2 - base)) > 0.19
        assert np.linalg.norm(p1 - p2) > 0.14
        # The +x wall sits on the base's turned x axis.
        wall = env.data.geom_xpos[env.model.geom("base_wall_px").id][:2] - base
        assert abs(np.arctan2(wall[1], wall[0]) - base_yaw) < 1e-6
        assert not env.is_success()
        yaws.append([base_yaw, p1_yaw % np.pi, p2_yaw % np.pi])
    yaws = np.array(yaws)
    assert np.ptp(yaws[:, 0]) > 1.0 and np.ptp(yaws[:, 1]) > 2.0 and np.ptp(yaws[:, 2]) > 2.0
    assert np.abs(yaws[:, 1] - yaws[:, 2]).max() > 0.5, "the pieces' yaws should be drawn apart"
    env.close()
