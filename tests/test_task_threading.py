"""Threading: the success rule and the layout of the needle and the tripod (the expert: test_experts.py)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from gym_actionflow.geometry import matrix_to_quat
from gym_actionflow.tasks.threading import (
    BAR_RADIUS,
    NEEDLE_CENTRE,
    NEEDLE_TIP,
    NEEDLE_X,
    NEEDLE_Y,
    RING_HEIGHT,
    RING_RADIUS,
    RING_TUBE,
    THROUGH,
    ThreadingEnv,
)


@pytest.fixture(scope="module")
def env() -> ThreadingEnv:
    e = ThreadingEnv(variant="D0", render_mode=None)
    yield e
    e.close()


def place_needle(env: ThreadingEnv, tip_in_ring: np.ndarray, direction_in_ring: np.ndarray) -> None:
    """Put the needle (kinematically) so that its tip is at ``tip_in_ring`` and its bar points along
    ``direction_in_ring`` (both in the ring frame), then recompute positions and contacts."""
    ring_pos, ring_rot = env.body_pose(env.tripod_id)
    x = ring_rot @ (direction_in_ring / np.linalg.norm(direction_in_ring))
    z = np.array([0.0, 0.0, 1.0]) - x * x[2]
    z /= np.linalg.norm(z)
    rot = np.stack([x, np.cross(z, x), z], axis=1)
    tip = ring_pos + ring_rot @ tip_in_ring
    env.set_free_pose("needle_joint", tip - NEEDLE_TIP * x, matrix_to_quat(rot))
    env.data.qvel[:] = 0.0
    mujoco.mj_forward(env.model, env.data)


ALONG = np.array([1.0, 0.0, 0.0])


def test_threaded_needle_is_success(env):
    """Positive case: the bar along the ring axis with its tip 3 cm through, either way (the ring is
    symmetric). Guards against a rule that never fires or depends on the needle's direction."""
    env.reset(seed=0)
    place_needle(env, np.array([0.03, 0.0, 0.0]), ALONG)
    assert env.is_success()
    place_needle(env, np.array([-0.03, 0.002, -0.003]), -ALONG)
    assert env.is_success()


def test_needle_beside_ring_is_not_success(env):
    """The tip past the ring plane but 2 cm beside the ring axis (the needle went past the ring, not through
    it) is not success."""
    env.reset(seed=0)
    place_needle(env, np.array([0.03, 0.02, 0.0]), ALONG)
    assert not env.is_success()
    place_needle(env, np.array([0.03, 0.0, RING_RADIUS + 0.002]), ALONG)  # just above the opening
    assert not env.is_success()


def test_tip_short_of_ring_plane_is_not_success(env):
    """The tip on the axis but short of the ring plane, or only just through it (less than THROUGH), is not
    success: guards against counting an aligned but not inserted needle."""
    env.reset(seed=0)
    place_needle(env, np.array([-0.005, 0.0, 0.0]), ALONG)
    assert not env.is_success()
    place_needle(env, np.array([THROUGH / 2, 0.0, 0.0]), ALONG)
    assert not env.is_success()


def test_bar_must_cross_the_ring(env):
    """The tip beyond the plane near the axis is not enough: a bar that reaches it around the outside of the
    ring (crossing the plane 5 cm off centre) or that lies entirely beyond the ring is not success."""
    env.reset(seed=0)
    place_needle(env, np.array([0.02, 0.005, 0.0]), np.array([0.02, -0.05, 0.0]))  # steep, from the side
    assert not env.is_success()
    place_needle(env, np.array([0.2, 0.0, 0.0]), ALONG)  # the whole needle beyond the ring
    assert not env.is_success()


def test_success_rule_has_no_side_effects(env):
    """is_success() only reads the state: guards against a rule that steps or edits the simulation."""
    env.reset(seed=0)
    place_needle(env, np.array([0.03, 0.0, 0.0]), ALONG)
    qpos, qvel, ncon = env.data.qpos.copy(), env.data.qvel.copy(), env.data.ncon
    for _ in range(3):
        assert env.is_success()
    np.testing.assert_array_equal(env.data.qpos, qpos)
    np.testing.assert_array_equal(env.data.qvel, qvel)
    assert env.data.ncon == ncon


def test_aligned_needle_clears_the_ring(env):
    """The ring's opening (radius RING_RADIUS) leaves a few mm around the bar: an aligned needle at any depth
    touches no tripod geom. Guards against ring geometry that makes threading impossible."""
    assert RING_RADIUS - BAR_RADIUS >= 0.005
    tripod = env.geoms_of("tripod")
    env.reset(seed=0)
    for depth in (-0.01, 0.0, 0.03, 0.06, 0.1):
        place_needle(env, np.array([depth, 0.0, 0.0]), ALONG)
        assert not env.touching(env.needle_geoms, tripod), f"depth {depth}"
    # ... and a needle 3 mm beyond the opening's edge does touch the ring.
    place_needle(env, np.array([0.03, 0.0, RING_RADIUS - BAR_RADIUS + 0.003]), ALONG)
    assert env.touching(env.needle_geoms, tripod)


def ring_centre_from_geoms(env: ThreadingEnv) -> np.ndarray:
    ids = [env.model.geom(f"tripod_ring_{k}").id for k in range(8)]
    return env.data.geom_xpos[ids].mean(axis=0)


def test_tripod_token_is_the_ring_frame(env):
    """The tripod token sits at the ring centre (where its geoms are) at RING_HEIGHT with a horizontal axis;
    D0 keeps it at MimicGen's fixed pose (0, -0.15), axis at yaw -pi/2."""
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        pose = obs["token_poses"][2]
        np.testing.assert_allclose(pose[:3], [0.0, -0.15, RING_HEIGHT], atol=1e-6)
        np.testing.assert_allclose(pose[3:6], [0.0, -1.0, 0.0], atol=1e-6)
        np.testing.assert_allclose(ring_centre_from_geoms(env), pose[:3], atol=1e-6)
        ring_ids = [env.model.geom(f"tripod_ring_{k}").id for k in range(8)]
        # Every ring capsule lies in the ring plane, its surface RING_RADIUS or more from the axis.
        for g in ring_ids:
            local = env.in_ring_frame(env.data.geom_xpos[g])
            assert abs(local[0]) < 1e-9
            assert np.linalg.norm(local[1:]) - RING_TUBE >= RING_RADIUS - 1e-9


def test_d1_moves_the_tripod():
    """D1 randomises the tripod's position and yaw (a static fixture moved through model.body_pos): guards
    against the writes being ignored (the geoms must move with the token) or a tripod stuck at the D0 pose."""
    e = ThreadingEnv(variant="D1", render_mode=None)
    poses = []
    for seed in range(8):
        obs, _ = e.reset(seed=seed)
        pose = obs["token_poses"][2].astype(np.float64)
        poses.append(pose)
        np.testing.assert_allclose(ring_centre_from_geoms(e), pose[:3], atol=1e-6)
        assert -0.1 - 1e-6 <= pose[0] <= 0.15 + 1e-6 and -0.2 - 1e-6 <= pose[1] <= -0.1 + 1e-6
        assert abs(pose[2] - RING_HEIGHT) < 1e-6 and abs(pose[5]) < 1e-6  # ring axis horizontal
        yaw = np.arctan2(pose[4], pose[3])
        assert -5 * np.pi / 6 - 1e-6 <= yaw <= -np.pi / 6 + 1e-6
    poses = np.array(poses)
    assert np.ptp(poses[:, 0]) > 0.05 and np.ptp(np.arctan2(poses[:, 4], poses[:, 3])) > 0.3
    e.close()


def test_d2_is_d1_mirrored_left_right():
    """D2 holds MimicGen's Threading_D2 ranges: the needle's centre in x [-0.2, 0.05], y [-0.25, -0.15], its
    tip within 120 degrees of pointing at the robot; the tripod in x [-0.1, 0.15], y [0.1, 0.2], its ring
    axis at yaw [pi/6, 5pi/6] (away from the needle). Guards against D2 keeping D1's sides, a ring axis that
    points back at the needle, or ranges that collapse to a point."""
    e = ThreadingEnv(variant="D2", render_mode=None)
    tripods, needles = [], []
    for seed in range(30):
        obs, info = e.reset(seed=seed)
        ring = obs["token_poses"][2].astype(np.float64)
        np.testing.assert_allclose(ring_centre_from_geoms(e), ring[:3], atol=1e-6)
        assert abs(ring[2] - RING_HEIGHT) < 1e-6 and abs(ring[5]) < 1e-6
        ring_yaw = np.arctan2(ring[4], ring[3])
        assert -0.1 - 1e-6 <= ring[0] <= 0.15 + 1e-6 and 0.1 - 1e-6 <= ring[1] <= 0.2 + 1e-6
        assert np.pi / 6 - 1e-6 <= ring_yaw <= 5 * np.pi / 6 + 1e-6
        needle = obs["token_poses"][1].astype(np.float64)
        centre = needle[:3] + NEEDLE_CENTRE * needle[3:6]
        assert abs(needle[2] - 0.02) < 0.002 and abs(needle[5]) < 0.01
        assert -0.2 - 1e-3 <= centre[0] <= 0.05 + 1e-3 and -0.25 - 1e-3 <= centre[1] <= -0.15 + 1e-3
        assert needle[3] <= np.cos(np.pi / 3) + 1e-3, "tip more than 120 degrees from pointing at the robot"
        assert not info["is_success"]
        tripods.append([*ring[:2], ring_yaw])
        needles.append([*centre[:2], np.arctan2(needle[4], needle[3])])
    tripods, needles = np.array(tripods), np.array(needles)
    assert np.ptp(tripods[:, 0]) > 0.15 and np.ptp(tripods[:, 1]) > 0.06 and np.ptp(tripods[:, 2]) > 1.2
    assert np.ptp(needles[:, 0]) > 0.15 and np.ptp(needles[:, 1]) > 0.06
    assert needles[:, 2].min() < -np.pi / 2 and needles[:, 2].max() > np.pi / 2, "tips both ways round"
    e.close()


@pytest.mark.parametrize("variant", ["D0", "D1", "D2"])
def test_needle_starts_on_the_table_in_range(variant):
    """The needle token is the handle centre, its first column the tip direction: the needle starts flat on
    the table, its middle (NEEDLE_CENTRE along the bar) inside MimicGen's placement ranges."""
    e = ThreadingEnv(variant=variant, render_mode=None)
    for seed in range(10):
        obs, info = e.reset(seed=seed)
        pose = obs["token_poses"][1].astype(np.float64)
        assert abs(pose[2] - 0.02) < 0.002 and abs(pose[5]) < 0.01  # lying flat, handle on the table
        centre = pose[:3] + NEEDLE_CENTRE * pose[3:6]
        assert NEEDLE_X[variant][0] - 1e-3 <= centre[0] <= NEEDLE_X[variant][1] + 1e-3
        assert NEEDLE_Y[variant][0] - 1e-3 <= centre[1] <= NEEDLE_Y[variant][1] + 1e-3
        root, tip = e.needle_points()
        np.testing.assert_allclose(tip, pose[:3] + NEEDLE_TIP * pose[3:6], atol=1e-5)
        assert not info["is_success"]
    e.close()

