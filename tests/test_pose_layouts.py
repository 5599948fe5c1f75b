"""The pose layouts of plain LeRobot datasets (core/pose_layouts.py) against scipy's rotations, their round
trips, the camera poses and the EEF token built from a state vector."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from lerobot_actionflow.core import geometry as g
from lerobot_actionflow.core.pose_layouts import (
    POSE_LAYOUTS,
    CameraPose,
    StateLayout,
    actions_from_ours,
    actions_to_ours,
    from_pose9,
    layout_to_rt,
    rt_to_layout,
    to_pose9,
)

SCIPY_ROTATION = {  # layout -> (its rotation elements from a scipy Rotation, a scipy Rotation from them)
    "xyz_quat_wxyz": (
        lambda r: r.as_quat(scalar_first=True),
        lambda v: Rotation.from_quat(v, scalar_first=True),
    ),
    "xyz_quat_xyzw": (lambda r: r.as_quat(), Rotation.from_quat),
    "xyz_rotvec": (lambda r: r.as_rotvec(), Rotation.from_rotvec),
    "xyz_rpy": (lambda r: r.as_euler("xyz"), lambda v: Rotation.from_euler("xyz", v)),
}


def _rotations(n: int = 64, seed: int = 0) -> Rotation:
    """Random rotations, away from pitch +-pi/2 (where roll and yaw are not separately defined)."""
    rots = Rotation.random(n, random_state=seed)
    return rots[np.abs(rots.as_euler("xyz")[:, 1]) < 1.4]


@pytest.mark.parametrize("layout", list(SCIPY_ROTATION))
def test_layout_to_rotation_matches_scipy(layout):
    """Each layout is read with the convention its name says (a quaternion's order, rpy's axis order):
    scipy's rotation and ours agree on every matrix."""
    rots = _rotations()
    as_layout, _ = SCIPY_ROTATION[layout]
    trans = np.random.default_rng(1).normal(size=(len(rots), 3))
    pose = torch.from_numpy(np.concatenate([trans, as_layout(rots)], -1))
    rot, out_trans = layout_to_rt(layout, pose)
    np.testing.assert_allclose(rot.numpy(), rots.as_matrix(), atol=1e-10)
    np.testing.assert_allclose(out_trans.numpy(), trans)


@pytest.mark.parametrize("layout", list(SCIPY_ROTATION))
def test_rotation_to_layout_matches_scipy(layout):
    """Written back, each layout gives scipy's numbers (a quaternion up to its sign; ours has qw >= 0)."""
    rots = _rotations(seed=2)
    _, from_layout = SCIPY_ROTATION[layout]
    pose = rt_to_layout(
        layout, torch.from_numpy(rots.as_matrix()), torch.zeros(len(rots), 3, dtype=torch.float64)
    )
    assert pose.shape == (len(rots), POSE_LAYOUTS[layout])
    np.testing.assert_allclose(from_layout(pose[:, 3:].numpy()).as_matrix(), rots.as_matrix(), atol=1e-10)
    if layout.startswith("xyz_quat"):
        w = pose[:, 3] if layout == "xyz_quat_wxyz" else pose[:, 6]
        assert (w >= 0).all() and torch.allclose(
            pose[:, 3:].norm(dim=-1), torch.ones(len(rots), dtype=w.dtype)
        )


@pytest.mark.parametrize("layout", list(POSE_LAYOUTS))
def test_round_trips_through_pose9_and_actions(layout):
    """layout -> pose9 -> layout and pose9 -> layout -> pose9 give the pose back, for poses and for actions
    (the gripper value passes through)."""
    gen = torch.Generator().manual_seed(3)
    pose9 = g.rt_to_pose9(
        g.random_rotation((5, 4), gen, torch.float64),
        torch.randn(5, 4, 3, generator=gen, dtype=torch.float64),
    )
    pose = from_pose9(layout, pose9)
    assert pose.shape == (5, 4, POSE_LAYOUTS[layout])
    torch.testing.assert_close(to_pose9(layout, pose), pose9)
    torch.testing.assert_close(from_pose9(layout, to_pose9(layout, pose)), pose)
    actions = torch.cat([pose9, torch.rand(5, 4, 1, generator=gen, dtype=torch.float64) * 2 - 1], -1)
    theirs = actions_from_ours(layout, actions)
    assert theirs.shape == (5, 4, POSE_LAYOUTS[layout] + 1)
    torch.testing.assert_close(actions_to_ours(layout, theirs), actions)


def test_pose9_is_passed_through_untouched():
    """Our own layout is not converted at all: a dataset in it trains and acts bit for bit as before."""
    x = torch.randn(2, 10)
    pose = x[:, :9]
    assert to_pose9("pose9", pose) is pose and from_pose9("pose9", pose) is pose
    assert actions_to_ours("pose9", x) is x and actions_from_ours("pose9", x) is x


def test_unknown_layout_names_the_known_ones():
    with pytest.raises(ValueError, match=r"pose layout 'quat' is unknown; expected one of \('pose9'"):
        layout_to_rt("quat", torch.zeros(7))


def test_camera_poses_follow_the_eef_or_stay_in_the_world():
    """An "eef" camera is the EEF pose times its offset at every step; a "world" camera is its extrinsics
    whatever the EEF does."""
    gen = torch.Generator().manual_seed(4)
    eef_rot, eef_trans = g.random_rotation((2, 3), gen), torch.randn(2, 3, 3, generator=gen)
    offset = Rotation.from_rotvec([0.1, -0.2, 0.3])
    pose = (0.01, 0.02, 0.05, *offset.as_quat(scalar_first=True))
    rot, trans = CameraPose("eef", pose).world_pose(eef_rot, eef_trans)
    off_rot = torch.tensor(offset.as_matrix(), dtype=torch.float32)
    torch.testing.assert_close(rot, eef_rot @ off_rot)
    torch.testing.assert_close(trans, g.apply(eef_rot, eef_trans, torch.tensor(pose[:3]).expand(2, 3, 3)))
    rot, trans = CameraPose("world", pose).world_pose(eef_rot, eef_trans)
    torch.testing.assert_close(rot, off_rot.expand(2, 3, 3, 3))
    torch.testing.assert_close(trans, torch.tensor(pose[:3]).expand(2, 3, 3))


def test_state_layout_builds_the_eef_token():
    """A 12-element state [j1, x, y, z, qx, qy, qz, qw, gripper, j2, j3, j4]: the token's pose is the
    quaternion slice as pose9, its feature [1, gripper] or, with the extras, [1, gripper, j1, j2, j3, j4]."""
    rot = Rotation.from_rotvec([0.3, 0.2, -0.1])
    state = torch.tensor([[7.0, 0.1, 0.2, 0.3, *rot.as_quat(), 0.04, 8.0, 9.0, 10.0]], dtype=torch.float32)
    layout = StateLayout("xyz_quat_xyzw", start=1, gripper_index=8, extra_features=False, dim=12)
    poses, feats = layout.tokens(state)
    assert poses.shape == (1, 1, 9) and feats.shape == (1, 1, 2) == (1, 1, layout.feature_dim)
    expected = g.rt_to_pose9(
        torch.tensor(rot.as_matrix(), dtype=torch.float32), torch.tensor([0.1, 0.2, 0.3])
    )
    torch.testing.assert_close(poses[0, 0], expected)
    torch.testing.assert_close(feats[0, 0], torch.tensor([1.0, 0.04]))
    extra = StateLayout("xyz_quat_xyzw", start=1, gripper_index=8, extra_features=True, dim=12)
    torch.testing.assert_close(extra.tokens(state)[1][0, 0], torch.tensor([1.0, 0.04, 7.0, 8.0, 9.0, 10.0]))
    assert extra.feature_dim == 6
