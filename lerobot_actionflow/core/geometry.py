"""Stateless SO(3) / SE(3) operations on torch tensors.

Every function is batched over arbitrary leading dimensions ``*``. Rotations are ``[*, 3, 3]`` matrices,
rotation vectors (axis-angle, the Lie algebra so(3)) are ``[*, 3]``, translations are ``[*, 3]``.

The 9-float pose vector used across the project (observations, actions, datasets) is
``[x, y, z, r00, r10, r20, r01, r11, r21]``: the position followed by the first and second *columns* of
the rotation matrix (the continuous "6D" rotation representation). Gram-Schmidt turns it back into a
matrix, so slightly non-orthonormal input (e.g. after float16 storage) is repaired, not rejected.

The exponential and logarithm maps are written to stay accurate (and have finite gradients) near angle 0,
where ``sin(theta) / theta`` is evaluated by its Taylor series, and near angle pi, where the logarithm is
computed through a quaternion obtained with Shepperd's method instead of from ``(R - R^T) / (2 sin theta)``.
"""

from __future__ import annotations

import torch
from torch import Tensor

# Below this angle (rad) the Taylor expansions are used; their truncation error is far below float32 eps.
_SMALL_ANGLE = 1e-3


def hat(omega: Tensor) -> Tensor:
    """Skew-symmetric matrix of a rotation vector: ``[*, 3] -> [*, 3, 3]`` with ``hat(a) @ b == a x b``."""
    x, y, z = omega.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack(
        [
            torch.stack([zero, -z, y], dim=-1),
            torch.stack([z, zero, -x], dim=-1),
            torch.stack([-y, x, zero], dim=-1),
        ],
        dim=-2,
    )


def so3_exp(omega: Tensor) -> Tensor:
    """Exponential map so(3) -> SO(3) (Rodrigues): rotation vector ``[*, 3]`` -> matrix ``[*, 3, 3]``."""
    theta2 = (omega * omega).sum(-1)  # [*]
    small = theta2 < _SMALL_ANGLE**2
    # Keep the large-angle branch finite where it is not selected, so that gradients stay finite too.
    theta2_safe = torch.where(small, torch.ones_like(theta2), theta2)
    theta = theta2_safe.sqrt()
    a_large = torch.sin(theta) / theta
    b_large = (1.0 - torch.cos(theta)) / theta2_safe
    a_small = 1.0 - theta2 / 6.0 + theta2 * theta2 / 120.0
    b_small = 0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0
    a = torch.where(small, a_small, a_large)[..., None, None]
    b = torch.where(small, b_small, b_large)[..., None, None]
    k = hat(omega)
    eye = torch.eye(3, dtype=omega.dtype, device=omega.device).expand(k.shape)
    return eye + a * k + b * (k @ k)


def matrix_to_quaternion(rot: Tensor) -> Tensor:
    """Rotation matrix ``[*, 3, 3]`` -> unit quaternion ``[*, 4]`` as (w, x, y, z) with ``w >= 0``.

    Shepperd's method: of the four algebraically equivalent formulas, use the one whose pivot
    (``1 + trace`` or ``1 + 2 R_ii - trace``) is largest, so no division by a small number happens.
    """
    r00, r01, r02 = rot[..., 0, 0], rot[..., 0, 1], rot[..., 0, 2]
    r10, r11, r12 = rot[..., 1, 0], rot[..., 1, 1], rot[..., 1, 2]
    r20, r21, r22 = rot[..., 2, 0], rot[..., 2, 1], rot[..., 2, 2]
    trace = r00 + r11 + r22
    pivots = torch.stack(
        [1.0 + trace, 1.0 + r00 - r11 - r22, 1.0 - r00 + r11 - r22, 1.0 - r00 - r11 + r22], -1
    )
    # Each candidate is 4 * q * q_pivot, written out for the pivot component w, x, y or z.
    candidates = torch.stack(
        [
            torch.stack([pivots[..., 0], r21 - r12, r02 - r20, r10 - r01], -1),
            torch.stack([r21 - r12, pivots[..., 1], r10 + r01, r02 + r20], -1),
            torch.stack([r02 - r20, r10 + r01, pivots[..., 2], r21 + r12], -1),
            torch.stack([r10 - r01, r20 + r02, r21 + r12, pivots[..., 3]], -1),
        ],
        dim=-2,
    )  # [*, 4 candidates, 4]
    best = pivots.argmax(-1)  # [*]
    index = best[..., None, None].expand(*best.shape, 1, 4)
    quat = candidates.gather(-2, index).squeeze(-2)  # [*, 4]
    quat = quat / quat.norm(dim=-1, keepdim=True)
    return torch.where(quat[..., :1] < 0, -quat, quat)


def quaternion_to_matrix(quat: Tensor) -> Tensor:
    """Quaternion ``[*, 4]`` as (w, x, y, z), not necessarily unit, -> rotation matrix ``[*, 3, 3]``."""
    quat = quat / quat.norm(dim=-1, keepdim=True)
    w, x, y, z = quat.unbind(-1)
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        dim=-2,
    )


def so3_log(rot: Tensor) -> Tensor:
    """Logarithm map SO(3) -> so(3): matrix ``[*, 3, 3]`` -> rotation vector ``[*, 3]`` with angle in [0, pi].

    Goes through the quaternion q = (cos(theta/2), sin(theta/2) * axis), so that angles near pi (where
    ``sin(theta)`` vanishes) are as accurate as any other. At exactly pi the sign of the axis is arbitrary.
    """
    quat = matrix_to_quaternion(rot)
    w, v = quat[..., 0], quat[..., 1:]
    s = v.norm(dim=-1)  # sin(theta / 2)
    theta = 2.0 * torch.atan2(s, w)
    small = s < _SMALL_ANGLE
    s_safe = torch.where(small, torch.ones_like(s), s)
    # theta / s = 2 atan(s / w) / s = (2 / w) (1 - s^2 / (3 w^2) + ...) for small s, where w ~ 1.
    w_safe = torch.where(small, w, torch.ones_like(w))
    scale = torch.where(small, 2.0 / w_safe * (1.0 - s * s / (3.0 * w_safe * w_safe)), theta / s_safe)
    return scale[..., None] * v


def so3_geodesic(rot_a: Tensor, rot_b: Tensor, t: Tensor | float) -> tuple[Tensor, Tensor]:
    """The rotation a fraction ``t`` of the way along the geodesic from ``rot_a`` to ``rot_b``,
    ``R_a Exp(t Log(R_a^T R_b))``, and the body-frame rotation vector of the whole way, ``Log(R_a^T R_b)``.

    ``[*, 3, 3], [*, 3, 3]`` and ``t`` broadcastable against ``[*, 3]`` -> ``[*, 3, 3], [*, 3]``. The flow's
    path and the policy's action smoothing both move along it.
    """
    omega = so3_log(rot_a.transpose(-1, -2) @ rot_b)  # [*, 3]
    return rot_a @ so3_exp(t * omega), omega


def rot6d_to_matrix(rot6d: Tensor) -> Tensor:
    """6D rotation ``[*, 6]`` (first column then second column) -> rotation matrix ``[*, 3, 3]``.

    Gram-Schmidt: normalise the first column, remove its component from the second, normalise, and take
    the cross product as the third column.
    """
    a1, a2 = rot6d[..., :3], rot6d[..., 3:6]
    b1 = a1 / a1.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    a2 = a2 - (b1 * a2).sum(-1, keepdim=True) * b1
    b2 = a2 / a2.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    b3 = torch.linalg.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], dim=-1)


def matrix_to_rot6d(rot: Tensor) -> Tensor:
    """Rotation matrix ``[*, 3, 3]`` -> 6D rotation ``[*, 6]``: its first two columns, concatenated."""
    return torch.cat([rot[..., :, 0], rot[..., :, 1]], dim=-1)


def pose9_to_rt(pose: Tensor) -> tuple[Tensor, Tensor]:
    """Pose vector ``[*, 9]`` -> (rotation ``[*, 3, 3]``, translation ``[*, 3]``)."""
    return rot6d_to_matrix(pose[..., 3:9]), pose[..., :3]


def rt_to_pose9(rot: Tensor, trans: Tensor) -> Tensor:
    """(rotation ``[*, 3, 3]``, translation ``[*, 3]``) -> pose vector ``[*, 9]``."""
    return torch.cat([trans, matrix_to_rot6d(rot)], dim=-1)


def apply(rot: Tensor, trans: Tensor, points: Tensor) -> Tensor:
    """Transform points by the pose (R, p): ``R @ x + p``; ``[*, 3, 3], [*, 3], [*, 3] -> [*, 3]``."""
    return torch.einsum("...ij,...j->...i", rot, points) + trans


def apply_inverse(rot: Tensor, trans: Tensor, points: Tensor) -> Tensor:
    """Express world points in the frame (R, p): ``R^T (x - p)``; shapes as in :func:`apply`."""
    return torch.einsum("...ji,...j->...i", rot, points - trans)


def compose(rot_a: Tensor, trans_a: Tensor, rot_b: Tensor, trans_b: Tensor) -> tuple[Tensor, Tensor]:
    """Pose product ``A * B`` (first B, then A): ``(R_a R_b, R_a p_b + p_a)``."""
    return rot_a @ rot_b, apply(rot_a, trans_a, trans_b)


def inverse(rot: Tensor, trans: Tensor) -> tuple[Tensor, Tensor]:
    """Pose inverse ``(R^T, -R^T p)``."""
    rot_t = rot.transpose(-1, -2)
    return rot_t, -torch.einsum("...ij,...j->...i", rot_t, trans)


def relative(rot_ref: Tensor, trans_ref: Tensor, rot: Tensor, trans: Tensor) -> tuple[Tensor, Tensor]:
    """Express pose (R, p) in the frame of the reference pose: ``ref^{-1} * pose``."""
    rot_ref_t = rot_ref.transpose(-1, -2)
    return rot_ref_t @ rot, torch.einsum("...ij,...j->...i", rot_ref_t, trans - trans_ref)


def random_rotation(
    shape: tuple[int, ...],
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> Tensor:
    """Rotations drawn uniformly (Haar measure) from SO(3): ``[*shape, 3, 3]``.

    A 4D standard normal vector, normalised, is a uniform unit quaternion; its matrix is Haar distributed.
    """
    quat = torch.randn(*shape, 4, generator=generator, dtype=dtype, device=device)
    return quaternion_to_matrix(quat)


def geodesic_distance(rot_a: Tensor, rot_b: Tensor) -> Tensor:
    """Angle (rad) of the relative rotation ``R_a^T R_b``: ``[*, 3, 3], [*, 3, 3] -> [*]``."""
    return so3_log(rot_a.transpose(-1, -2) @ rot_b).norm(dim=-1)


def pose9_errors(pose_a: Tensor, pose_b: Tensor) -> tuple[Tensor, Tensor]:
    """Translation error (m) and rotation angle (rad) between pose vectors ``[*, 9]`` -> ``[*], [*]``."""
    rot_a, trans_a = pose9_to_rt(pose_a)
    rot_b, trans_b = pose9_to_rt(pose_b)
    return (trans_a - trans_b).norm(dim=-1), geodesic_distance(rot_a, rot_b)
