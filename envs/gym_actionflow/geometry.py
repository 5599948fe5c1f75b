"""Pose conventions at the env boundary (numpy only).

A pose vector has 9 floats ``[x, y, z, r00, r10, r20, r01, r11, r21]``: the position, then the first two
columns of the rotation matrix. MuJoCo quaternions are ``(w, x, y, z)`` and never leave the env.
"""

from __future__ import annotations

import mujoco
import numpy as np

__all__ = [
    "axis_angle_matrix",
    "gram_schmidt",
    "matrix_to_quat",
    "pose9",
    "pose9_to_rt",
    "quat_to_matrix",
    "rotation_angle",
    "rotation_log",
    "yaw_matrix",
    "yaw_of",
    "yaw_quat",
]


def gram_schmidt(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation matrix whose first column is along ``a`` and second is ``b`` made orthogonal to it.

    Degenerate inputs (zero or parallel columns, as random actions can be) fall back to any orthonormal
    completion instead of producing NaN.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    na = np.linalg.norm(a)
    c0 = a / na if na > 1e-9 else np.array([1.0, 0.0, 0.0])
    b = b - c0 * np.dot(c0, b)
    nb = np.linalg.norm(b)
    if nb < 1e-9:
        helper = np.array([0.0, 0.0, 1.0]) if abs(c0[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
        b = helper - c0 * np.dot(c0, helper)
        nb = np.linalg.norm(b)
    c1 = b / nb
    return np.stack([c0, c1, np.cross(c0, c1)], axis=1)


def pose9(pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """(3,) position and (3, 3) rotation -> (9,) float32 pose vector."""
    return np.concatenate([pos, rot[:, 0], rot[:, 1]]).astype(np.float32)


def pose9_to_rt(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(9,) pose vector -> ((3, 3) rotation, (3,) position), rotation orthonormalised."""
    p = np.asarray(p, dtype=np.float64)
    return gram_schmidt(p[3:6], p[6:9]), p[:3].copy()


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    out = np.empty(9)
    mujoco.mju_quat2Mat(out, np.asarray(q, dtype=np.float64))
    return out.reshape(3, 3)


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    out = np.empty(4)
    mujoco.mju_mat2Quat(out, np.ascontiguousarray(r, dtype=np.float64).reshape(9))
    return out


def yaw_matrix(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def yaw_quat(yaw: float) -> np.ndarray:
    """MuJoCo quaternion (w, x, y, z) of a rotation by ``yaw`` about the world z axis."""
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def yaw_of(rot: np.ndarray) -> float:
    """Heading of a rotation matrix: the angle of its first column projected on the xy plane."""
    return float(np.arctan2(rot[1, 0], rot[0, 0]))


def axis_angle_matrix(axis_angle: np.ndarray) -> np.ndarray:
    """Rotation matrix Exp(axis_angle)."""
    v = np.asarray(axis_angle, dtype=np.float64)
    angle = np.linalg.norm(v)
    q = np.array([1.0, 0.0, 0.0, 0.0])
    if angle > 1e-12:
        mujoco.mju_axisAngle2Quat(q, v / angle, angle)
    return quat_to_matrix(q)


def rotation_log(r: np.ndarray) -> np.ndarray:
    """Axis-angle vector Log(r), via MuJoCo's quaternion conversion (stable near pi)."""
    v = np.empty(3)
    mujoco.mju_quat2Vel(v, matrix_to_quat(r), 1.0)
    return v


def rotation_angle(r_a: np.ndarray, r_b: np.ndarray) -> float:
    """Geodesic angle between two rotation matrices, in radians."""
    cos = (np.trace(r_a.T @ r_b) - 1.0) / 2.0
    return float(np.arccos(np.clip(cos, -1.0, 1.0)))
