"""Point clouds from rendered depth: back-projection, box filtering, fusion and subsampling (numpy only).

Depth images come from ``mujoco.Renderer`` with depth rendering enabled: it already converts the depth buffer
to metric distance along the camera's optical axis (undoing OpenGL's near/far projection) and flips the EGL /
OSMesa image vertically, so row 0 is the top of the image. MuJoCo cameras look along their -z axis with x to
the right and y up; ``fovy`` (degrees, whatever ``compiler.degree`` says) is the vertical field of view and
pixels are square.
"""

from __future__ import annotations

import numpy as np

__all__ = ["back_project", "farthest_point_sample", "in_boxes", "look_at_xyaxes", "voxel_unique"]


def look_at_xyaxes(pos, target, up=(0.0, 0.0, 1.0)) -> tuple[float, ...]:
    """MuJoCo ``xyaxes`` (camera x and y axes, 6 floats) of a camera at ``pos`` looking at ``target``.

    For a camera looking straight down the image's up direction is the world +x axis."""
    pos, target, up = (np.asarray(v, dtype=np.float64) for v in (pos, target, up))
    z = pos - target
    z /= np.linalg.norm(z)
    x = np.cross(up, z)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross((1.0, 0.0, 0.0), z)
        x = -x if x @ (0.0, 1.0, 0.0) > 0 else x
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return (*x, *y)


def back_project(
    depth: np.ndarray, cam_pos: np.ndarray, cam_mat: np.ndarray, fovy_deg: float, max_depth: float
) -> np.ndarray:
    """World points (M, 3) of the pixels of a metric depth image (H, W) whose depth is below ``max_depth``.

    ``cam_pos`` (3,) and ``cam_mat`` (3, 3) are the camera's world pose (``data.cam_xpos``, ``cam_xmat``).
    Each pixel's ray goes through its centre: column ``c`` and row ``r`` (row 0 at the top) map to camera
    coordinates ``((c + 0.5 - W / 2) d / f, -(r + 0.5 - H / 2) d / f, -d)``, ``f = H / (2 tan(fovy / 2))``.
    """
    h, w = depth.shape
    f = 0.5 * h / np.tan(0.5 * np.deg2rad(fovy_deg))
    rows, cols = np.nonzero(depth < max_depth)
    d = depth[rows, cols].astype(np.float64)
    cam = np.stack([(cols + 0.5 - 0.5 * w) * d / f, -(rows + 0.5 - 0.5 * h) * d / f, -d], axis=1)
    return cam @ np.asarray(cam_mat).T + np.asarray(cam_pos)


def in_boxes(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Mask (M,) of the points inside any of the axis-aligned boxes (K, 2, 3) of [low, high] corners."""
    mask = np.zeros(len(points), dtype=bool)
    for low, high in boxes:
        mask |= np.all((points >= low) & (points <= high), axis=1)
    return mask


def voxel_unique(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point per occupied voxel (the first in input order): evens out the density of fused views."""
    keys = np.floor(points / voxel).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


def farthest_point_sample(points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points spread evenly over the cloud (farthest point sampling from a random start).

    With fewer than ``n`` points, all of them are kept and the rest drawn again at random (with repeats)."""
    m = len(points)
    if m == 0:
        raise ValueError("cannot subsample an empty point cloud")
    if m <= n:
        extra = rng.choice(m, n - m, replace=True) if n > m else np.zeros(0, dtype=int)
        return points[np.concatenate([rng.permutation(m), extra])]
    chosen = np.empty(n, dtype=np.int64)
    chosen[0] = rng.integers(m)
    dist = np.sum((points - points[chosen[0]]) ** 2, axis=1)
    for k in range(1, n):
        chosen[k] = int(np.argmax(dist))
        np.minimum(dist, np.sum((points - points[chosen[k]]) ** 2, axis=1), out=dist)
    return points[chosen]
