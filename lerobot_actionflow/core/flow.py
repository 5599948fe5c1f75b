"""Rectified (straight-line) flow matching on SE(3)^H x R^(H x m) and on R^(H x d).

Time convention: t = 0 is noise, t = 1 is data (as in the paper; LeRobot's pi0 uses the opposite).

SE(3) flow (paper Eq. 2-5). For an action pose T = (R, p) and extras e (e.g. the gripper command):

    path       R_t = R_0 Exp(t Log(R_0^T R_1)),  p_t = (1 - t) p_0 + t p_1,  e_t = (1 - t) e_0 + t e_1
    velocity   w = Log(R_t^T R_1) / (1 - t)            body-frame rotation velocity (constant on the path)
               v = R_t^T (p_1 - p_t) / (1 - t)         translation velocity in the action's local frame
               u = (e_1 - e_t) / (1 - t)
    Euler      R <- R Exp(dt w),  p <- p + R v dt,  e <- e + u dt

(The paper prints the translation velocity as ``R_t^T (p_t - p_1) / (1 - t)``; the sign that moves the
sample towards the data, used here, is ``p_1 - p_t``.)

Because velocities are expressed in each action's own frame, a network that is invariant to a global
SE(3) transform yields samples that transform with it (paper appendix, "Equivariant Generation").

A velocity vector is laid out as ``[v (3), w (3), u (m)]`` for SE(3) and as the plain vector for the
Euclidean flow, so the network head is the same size-agnostic linear layer for both. Each flow says what is
specific to it, so that the model never asks which flow it holds: ``velocity_parts`` (which slice of the
velocity is translation, rotation and extras, for the loss terms), ``network_input_dim`` and
``network_input(x)`` (what the network sees of a state besides its poses), and ``to_poses`` / ``from_poses``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

from lerobot_actionflow.core import geometry as g


@dataclass
class SE3State:
    """Action sequences: rotations ``[B, H, 3, 3]``, translations ``[B, H, 3]``, extras ``[B, H, m]``."""

    rot: Tensor
    trans: Tensor
    extra: Tensor


def time_grid(
    num_steps: int,
    schedule: Literal["uniform", "exponential"] = "uniform",
    rate: float = 2.0,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Integration times ``t_0 = 0 < t_1 < ... < t_K = 1``, shape ``[K + 1]``.

    ``"exponential"`` spaces the steps as ``t_k = (1 - exp(-rate k / K)) / (1 - exp(-rate))``: long steps
    while the sample is still mostly noise, short steps near the data where precision matters.
    """
    if num_steps < 1:
        raise ValueError(f"num_steps={num_steps}; expected an integer >= 1")
    s = torch.linspace(0.0, 1.0, num_steps + 1, device=device, dtype=torch.float64)
    if schedule == "uniform":
        grid = s
    elif schedule == "exponential":
        if rate <= 0:
            raise ValueError(f"rate={rate}; the exponential time grid needs rate > 0")
        grid = (1.0 - torch.exp(-rate * s)) / (1.0 - math.exp(-rate))
    else:
        raise ValueError(f"schedule={schedule!r}; expected 'uniform' or 'exponential'")
    grid[-1] = 1.0
    return grid.to(dtype)


class SE3Flow:
    """Rectified flow on SE(3) x R^m per action step (paper Eq. 2-5).

    Noise: translations and extras standard normal; rotations uniform on SO(3) (the paper's,
    ``rotation_noise_std=None``) or ``Exp(std * N(0, I))``, concentrated around the identity, which in
    the policy's EEF frame is the gripper's current orientation (as the translation noise is centred on
    the gripper). Uniform noise starts rotation paths anywhere, up to pi away and across the cut locus of
    ``Log``, so the marginal field the network must learn averages paths that cross; concentrated noise
    keeps rotation paths short and nearly straight.
    """

    def __init__(self, extra_dim: int, rotation_noise_std: float | None = None):
        if rotation_noise_std is not None and not rotation_noise_std > 0:
            raise ValueError(f"rotation_noise_std={rotation_noise_std}; expected None (uniform) or > 0 (rad)")
        self.rotation_noise_std = rotation_noise_std
        self.extra_dim = extra_dim
        self.velocity_dim = 6 + extra_dim
        self.velocity_parts = {"translation": slice(0, 3), "rotation": slice(3, 6), "extra": slice(6, None)}
        """Which slice of a velocity ``[..., 6 + m]`` is translation, rotation and extras."""
        self.network_input_dim = extra_dim
        """The network sees each action's extras (the gripper) as features, and its pose as a pose."""

    def noise(
        self,
        batch: int,
        horizon: int,
        generator: torch.Generator | None = None,
        device=None,
        dtype: torch.dtype = torch.float32,
    ) -> SE3State:
        if self.rotation_noise_std is None:
            rot = g.random_rotation((batch, horizon), generator=generator, device=device, dtype=dtype)
        else:
            axis_angle = torch.randn(batch, horizon, 3, generator=generator, device=device, dtype=dtype)
            rot = g.so3_exp(self.rotation_noise_std * axis_angle)
        trans = torch.randn(batch, horizon, 3, generator=generator, device=device, dtype=dtype)
        extra = torch.randn(batch, horizon, self.extra_dim, generator=generator, device=device, dtype=dtype)
        return SE3State(rot, trans, extra)

    def interpolate(self, x0: SE3State, x1: SE3State, t: Tensor) -> tuple[SE3State, Tensor]:
        """Point on the path at time ``t`` (``[B]``) and the target velocity there, ``[B, H, 6 + m]``.

        Uses the closed forms that hold on the path, ``w = Log(R_0^T R_1)`` and ``v = R_t^T (p_1 - p_0)``,
        which equal :meth:`conditional_velocity` without its division by ``1 - t``.
        """
        tb = t[:, None, None]  # [B, 1, 1]
        rot_t, omega = g.so3_geodesic(x0.rot, x1.rot, tb)  # [B, H, 3, 3], [B, H, 3]
        trans_t = (1 - tb) * x0.trans + tb * x1.trans
        extra_t = (1 - tb) * x0.extra + tb * x1.extra
        v = torch.einsum("bhji,bhj->bhi", rot_t, x1.trans - x0.trans)
        target = torch.cat([v, omega, x1.extra - x0.extra], dim=-1)
        return SE3State(rot_t, trans_t, extra_t), target

    def conditional_velocity(self, x: SE3State, x1: SE3State, t: Tensor) -> Tensor:
        """The conditional field ``u_t(x | x_1)`` at an arbitrary state ``x`` (Eq. 3), ``[B, H, 6 + m]``.

        Integrating it from any ``x`` at any ``t < 1`` reaches ``x_1`` at ``t = 1`` exactly.
        """
        remaining = (1 - t)[:, None, None]
        omega = g.so3_log(x.rot.transpose(-1, -2) @ x1.rot) / remaining
        v = torch.einsum("bhji,bhj->bhi", x.rot, x1.trans - x.trans) / remaining
        u = (x1.extra - x.extra) / remaining
        return torch.cat([v, omega, u], dim=-1)

    def step(self, x: SE3State, velocity: Tensor, dt: float | Tensor) -> SE3State:
        """One Euler step in the local frame (Eq. 5): ``R <- R Exp(dt w)``, ``p <- p + R v dt``."""
        v, omega, u = velocity[..., :3], velocity[..., 3:6], velocity[..., 6:]
        trans = x.trans + dt * torch.einsum("bhij,bhj->bhi", x.rot, v)
        rot = x.rot @ g.so3_exp(dt * omega)
        return SE3State(rot, trans, x.extra + dt * u)

    def to_poses(self, x: SE3State) -> SE3State:
        return x

    def from_poses(self, x: SE3State) -> SE3State:
        return x

    def network_input(self, x: SE3State) -> Tensor:
        return x.extra

    def batch_size(self, x: SE3State) -> int:
        return x.trans.shape[0]


EUCLIDEAN_FRAMES = ("action", "eef")


class EuclideanFlow:
    """Rectified flow on the flat action vector ``[p (3), rot6d (6), extras (m)]`` (paper appendix).

    Noise is standard normal in every dimension, and the path is the straight line ``x_t = (1 - t) x_0 + t
    x_1`` in the policy's EEF frame. The network sees the state as poses through :meth:`to_poses`, whose
    rotation ``R`` is the Gram-Schmidt frame of the current 6D part. ``frame`` says in which frame the
    network reads the 6D part and writes the velocity:

    * ``"action"``: each action's own frame ``R``, as the SE(3) flow's velocity is. The velocity of each of
      the three 3-vectors (the position and the two 6D columns) is ``R`` times the network's output, and the
      network reads the 6D columns as ``R^T a_1, R^T a_2`` (their lengths and angle), which no turn of the
      whole scene changes. An invariant network (IPA, whose outputs describe the scene from each token's
      pose) can then give the velocity directly.
    * ``"eef"``: the flat vector in the EEF frame, in and out. An invariant network must then work out
      its token's orientation from the 6D values it is fed to turn its output into the EEF frame
      (checkpoints saved before the choice existed are this).

    The two describe the same straight-line flow (the norm of a velocity, hence the loss, is the same in
    either frame); they differ only in what the network must learn.
    """

    def __init__(self, extra_dim: int, frame: str = "action"):
        if frame not in EUCLIDEAN_FRAMES:
            raise ValueError(f"euclidean frame={frame!r}; expected one of {EUCLIDEAN_FRAMES}")
        self.extra_dim = extra_dim
        self.frame = frame
        self.velocity_dim = 9 + extra_dim
        self.velocity_parts = {"translation": slice(0, 3), "rotation": slice(3, 9), "extra": slice(9, None)}
        """Which slice of a velocity ``[..., 9 + m]`` is translation, rotation (6D) and extras."""
        self.network_input_dim = self.velocity_dim - 3 if frame == "action" else self.velocity_dim
        """What the network sees of each action besides its pose: the 6D part in the action's frame and the
        extras (``"action"``), or the whole flat state (``"eef"``)."""

    def noise(
        self,
        batch: int,
        horizon: int,
        generator: torch.Generator | None = None,
        device=None,
        dtype: torch.dtype = torch.float32,
    ) -> Tensor:
        return torch.randn(batch, horizon, self.velocity_dim, generator=generator, device=device, dtype=dtype)

    def _turn(self, x: Tensor, vec: Tensor, inverse: bool = False) -> Tensor:
        """``vec``'s three 3-vectors (position, 6D columns) turned from the frame of the actions ``x`` into
        the EEF frame (``R v``), or back (``inverse``: ``R^T v``); the extras are left as they are. Identity
        for ``frame="eef"``."""
        if self.frame == "eef":
            return vec
        rot = g.rot6d_to_matrix(x[..., 3:9])  # [..., 3, 3]
        blocks = vec[..., :9].unflatten(-1, (3, 3))  # [..., 3 vectors, 3]
        pattern = "...ji,...kj->...ki" if inverse else "...ij,...kj->...ki"
        turned = torch.einsum(pattern, rot, blocks).flatten(-2)
        return torch.cat([turned, vec[..., 9:]], dim=-1)

    def interpolate(self, x0: Tensor, x1: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
        tb = t[:, None, None]
        xt = (1 - tb) * x0 + tb * x1
        return xt, self._turn(xt, x1 - x0, inverse=True)

    def conditional_velocity(self, x: Tensor, x1: Tensor, t: Tensor) -> Tensor:
        return self._turn(x, (x1 - x) / (1 - t)[:, None, None], inverse=True)

    def step(self, x: Tensor, velocity: Tensor, dt: float | Tensor) -> Tensor:
        return x + dt * self._turn(x, velocity)

    def to_poses(self, x: Tensor) -> SE3State:
        return SE3State(g.rot6d_to_matrix(x[..., 3:9]), x[..., :3], x[..., 9:])

    def from_poses(self, x: SE3State) -> Tensor:
        return torch.cat([x.trans, g.matrix_to_rot6d(x.rot), x.extra], dim=-1)

    def network_input(self, x: Tensor) -> Tensor:
        if self.frame == "eef":
            return x
        return self._turn(x, x, inverse=True)[..., 3:]  # the 6D columns in the action's frame, the extras

    def batch_size(self, x: Tensor) -> int:
        return x.shape[0]


Flow = SE3Flow | EuclideanFlow
VelocityFn = Callable[[object, Tensor], Tensor]


def make_flow(
    action_space: str,
    extra_dim: int,
    rotation_noise_std: float | None = None,
    euclidean_frame: str = "action",
) -> Flow:
    """The flow of an ``action_space``: ``"se3"`` (the paper's) or ``"euclidean"`` (flat vector ablation).
    ``rotation_noise_std`` shapes the SE(3) flow's rotation noise (see :class:`SE3Flow`); the Euclidean flow's
    noise is standard normal in every dimension, its velocity in the frame ``euclidean_frame`` (see
    :class:`EuclideanFlow`)."""
    if action_space == "se3":
        return SE3Flow(extra_dim, rotation_noise_std)
    if action_space == "euclidean":
        return EuclideanFlow(extra_dim, euclidean_frame)
    raise ValueError(f"action_space={action_space!r}; expected one of ('se3', 'euclidean')")


def euler_states(flow: Flow, velocity_fn: VelocityFn, x0, grid: Tensor, start: int = 0) -> Iterator:
    """Every state of the Euler integration of ``dx/dt = velocity_fn(x, t)`` over ``grid[start:]``: ``x0``
    (at ``grid[start]``), then the state after each step, the last at ``grid[-1]``; ``t`` is passed as
    ``[B]``. :func:`integrate` is its last state; the states are there to be looked at (e.g. to show how
    the sampler carries noise to the chunk) without a second copy of the loop.

    ``velocity_fn`` receives the flow's native state (``SE3State`` or a tensor) and returns ``[B, H, D]``.
    """
    x = x0
    yield x
    batch = flow.batch_size(x0)
    for k in range(start, grid.numel() - 1):
        t = grid[k].expand(batch)
        x = flow.step(x, velocity_fn(x, t), grid[k + 1] - grid[k])
        yield x


def integrate(flow: Flow, velocity_fn: VelocityFn, x0, grid: Tensor, start: int = 0):
    """Euler-integrate ``dx/dt = velocity_fn(x, t)`` over ``grid[start:]``; ``t`` is passed as ``[B]``.

    ``velocity_fn`` receives the flow's native state (``SE3State`` or a tensor) and returns ``[B, H, D]``.
    """
    *_, x = euler_states(flow, velocity_fn, x0, grid, start)
    return x
