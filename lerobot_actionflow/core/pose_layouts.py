"""Pose layouts of other datasets and their conversions to ours, written once (plain torch, no LeRobot).

A plain LeRobot dataset keeps the end-effector pose inside ``observation.state`` and ``action`` in its own
convention. ActionFlow works on pose vectors ``[x, y, z, r00, r10, r20, r01, r11, r21]`` ("pose9": the
position, then the first two columns of the rotation matrix) and actions ``pose9 + gripper command``; these
functions convert the other layouts to and from it, batched over leading dims ``*``:

| layout | size | elements |
|---|---|---|
| ``pose9`` | 9 | ``x, y, z, r00, r10, r20, r01, r11, r21`` (ours) |
| ``xyz_quat_wxyz`` | 7 | ``x, y, z, qw, qx, qy, qz``: scalar-first quaternion (MuJoCo, Isaac, Eigen) |
| ``xyz_quat_xyzw`` | 7 | ``x, y, z, qx, qy, qz, qw``: scalar-last quaternion (ROS messages, scipy) |
| ``xyz_rotvec`` | 6 | ``x, y, z, rx, ry, rz``: rotation axis times angle (rad) |
| ``xyz_rpy`` | 6 | ``x, y, z, roll, pitch, yaw`` (rad): ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (scipy's "xyz") |

Quaternions need not be unit on input; on output they are unit with ``qw >= 0``. Converting ``pose9`` to
``pose9`` returns the tensor itself, so datasets in our own layout are untouched bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from lerobot_actionflow.core import geometry as g

POSE_LAYOUTS: dict[str, int] = {
    "pose9": 9,
    "xyz_quat_wxyz": 7,
    "xyz_quat_xyzw": 7,
    "xyz_rotvec": 6,
    "xyz_rpy": 6,
}
"""Layout name -> number of elements."""


def _axis_rotation(angle: Tensor, axis: int) -> Tensor:
    """Rotation ``[*, 3, 3]`` by ``angle [*]`` about the coordinate axis 0 (x), 1 (y) or 2 (z)."""
    omega = torch.zeros(*angle.shape, 3, dtype=angle.dtype, device=angle.device)
    omega[..., axis] = angle
    return g.so3_exp(omega)


def rpy_to_matrix(rpy: Tensor) -> Tensor:
    """Roll, pitch, yaw ``[*, 3]`` (rad) -> ``Rz(yaw) Ry(pitch) Rx(roll)`` ``[*, 3, 3]``."""
    roll, pitch, yaw = rpy.unbind(-1)
    return _axis_rotation(yaw, 2) @ _axis_rotation(pitch, 1) @ _axis_rotation(roll, 0)


def matrix_to_rpy(rot: Tensor) -> Tensor:
    """Inverse of :func:`rpy_to_matrix`: ``[*, 3, 3]`` -> ``[*, 3]`` with pitch in [-pi/2, pi/2]. At pitch
    +-pi/2 (gimbal lock) only roll - yaw (or roll + yaw) is defined."""
    pitch = torch.atan2(-rot[..., 2, 0], torch.hypot(rot[..., 0, 0], rot[..., 1, 0]))
    roll = torch.atan2(rot[..., 2, 1], rot[..., 2, 2])
    yaw = torch.atan2(rot[..., 1, 0], rot[..., 0, 0])
    return torch.stack([roll, pitch, yaw], dim=-1)


def check_layout(layout: str) -> int:
    """The size of ``layout``; a ValueError naming the known layouts if there is no such layout."""
    if layout not in POSE_LAYOUTS:
        raise ValueError(f"pose layout {layout!r} is unknown; expected one of {tuple(POSE_LAYOUTS)}")
    return POSE_LAYOUTS[layout]


def layout_to_rt(layout: str, pose: Tensor) -> tuple[Tensor, Tensor]:
    """A pose ``[*, size]`` in ``layout`` -> (rotation ``[*, 3, 3]``, translation ``[*, 3]``)."""
    check_layout(layout)
    trans, rest = pose[..., :3], pose[..., 3:]
    if layout == "pose9":
        return g.pose9_to_rt(pose)
    if layout == "xyz_quat_wxyz":
        return g.quaternion_to_matrix(rest), trans
    if layout == "xyz_quat_xyzw":
        return g.quaternion_to_matrix(rest.roll(1, dims=-1)), trans
    if layout == "xyz_rotvec":
        return g.so3_exp(rest), trans
    return rpy_to_matrix(rest), trans


def rt_to_layout(layout: str, rot: Tensor, trans: Tensor) -> Tensor:
    """(rotation ``[*, 3, 3]``, translation ``[*, 3]``) -> a pose ``[*, size]`` in ``layout``."""
    check_layout(layout)
    if layout == "pose9":
        return g.rt_to_pose9(rot, trans)
    if layout == "xyz_quat_wxyz":
        rest = g.matrix_to_quaternion(rot)
    elif layout == "xyz_quat_xyzw":
        rest = g.matrix_to_quaternion(rot).roll(-1, dims=-1)
    elif layout == "xyz_rotvec":
        rest = g.so3_log(rot)
    else:
        rest = matrix_to_rpy(rot)
    return torch.cat([trans, rest], dim=-1)


def to_pose9(layout: str, pose: Tensor) -> Tensor:
    """A pose ``[*, size]`` in ``layout`` -> our pose vector ``[*, 9]`` (``pose`` itself for ``pose9``)."""
    return pose if layout == "pose9" else g.rt_to_pose9(*layout_to_rt(layout, pose))


def from_pose9(layout: str, pose9: Tensor) -> Tensor:
    """Our pose vector ``[*, 9]`` -> the pose ``[*, size]`` in ``layout`` (``pose9`` itself for ``pose9``)."""
    return pose9 if layout == "pose9" else rt_to_layout(layout, *g.pose9_to_rt(pose9))


def actions_to_ours(layout: str, action: Tensor) -> Tensor:
    """Dataset actions ``[*, size + 1]`` (a pose in ``layout``, then one gripper value) -> ours ``[*, 10]``
    (target pose9 + gripper); ``action`` itself for ``pose9``."""
    if layout == "pose9":
        return action
    return torch.cat([to_pose9(layout, action[..., :-1]), action[..., -1:]], -1)


def actions_from_ours(layout: str, action: Tensor) -> Tensor:
    """Our actions ``[*, 10]`` -> the dataset's ``[*, size + 1]`` (inverse of :func:`actions_to_ours`)."""
    if layout == "pose9":
        return action
    return torch.cat([from_pose9(layout, action[..., :-1]), action[..., -1:]], -1)


@dataclass(frozen=True)
class CameraPose:
    """Where a camera is: ``frame`` ``"eef"`` (mounted on the end effector: ``pose`` is its fixed offset in
    the end effector's frame, so the camera's pose is ``EEF pose * offset`` at every step) or ``"world"``
    (static: ``pose`` is its extrinsic pose in the world frame). ``pose`` is 7 numbers
    ``x, y, z, qw, qx, qy, qz`` (metres, scalar-first quaternion: the layout ``xyz_quat_wxyz``) of any frame
    fixed to the camera, the same in training and deployment (the optical frame, z forward, x right, y down,
    is the usual one)."""

    frame: str
    pose: tuple[float, ...]

    def world_pose(self, eef_rot: Tensor, eef_trans: Tensor) -> tuple[Tensor, Tensor]:
        """The camera's world pose at each of the EEF poses ``[*, 3, 3], [*, 3]`` -> ``[*, 3, 3], [*, 3]``."""
        pose = torch.tensor(self.pose, dtype=eef_trans.dtype, device=eef_trans.device)
        rot, trans = layout_to_rt("xyz_quat_wxyz", pose)
        rot, trans = rot.expand_as(eef_rot), trans.expand_as(eef_trans)
        return g.compose(eef_rot, eef_trans, rot, trans) if self.frame == "eef" else (rot, trans)


@dataclass(frozen=True)
class StateLayout:
    """Where the end effector is in a flat state vector ``[*, dim]``: its pose at ``start`` in the layout
    ``pose``, its gripper opening at ``gripper_index`` (None: no gripper), and whether every other element
    (``extra_features``: joint angles, say) joins the EEF token's feature. Those extras must not change when
    the whole scene moves (no world-frame velocities), or the policy is no longer SE(3)-equivariant."""

    pose: str
    start: int
    gripper_index: int | None
    extra_features: bool
    dim: int

    @property
    def pose_indices(self) -> range:
        return range(self.start, self.start + check_layout(self.pose))

    @property
    def extra_indices(self) -> list[int]:
        """The state elements that are neither the pose nor the gripper."""
        used = {*self.pose_indices, self.gripper_index}
        return [i for i in range(self.dim) if i not in used] if self.extra_features else []

    @property
    def feature_dim(self) -> int:
        """F of the EEF token: a constant 1 (as the token schema's one-hot ``is_eef``), the gripper
        opening when there is one, the extras."""
        return 1 + (self.gripper_index is not None) + len(self.extra_indices)

    def tokens(self, state: Tensor) -> tuple[Tensor, Tensor]:
        """``state [*, dim]`` -> the EEF token: pose ``[*, 1, 9]`` (world) and feature ``[*, 1, F]``."""
        pose9 = to_pose9(self.pose, state[..., self.pose_indices.start : self.pose_indices.stop])
        columns = [torch.ones_like(state[..., :1])]
        if self.gripper_index is not None:
            columns.append(state[..., self.gripper_index : self.gripper_index + 1])
        columns.append(state[..., self.extra_indices])
        return pose9[..., None, :], torch.cat(columns, dim=-1)[..., None, :]
