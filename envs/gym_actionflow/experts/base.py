"""Scripted experts: object-centric waypoint scripts that emit absolute TCP pose actions.

A task expert subclasses :class:`ScriptedExpert` and writes its plan as a generator (``script``) of actions,
reading object poses from the simulator when each phase starts, so the plan follows objects that moved:

    def script(self):
        yield from self.grasp(at_cube, grasp_rot, lift=0.1)  # down from above, close, lift
        yield from self.move_to(above_target, grasp_rot)
        yield from self.set_gripper(OPEN)

A grasp that may miss is retried with :meth:`ScriptedExpert.grasp_until_held`, the one retry loop.

``noise`` makes demonstrations diverse: per-episode offsets of the waypoints (drawn once per phase) and a
per-step jitter on the emitted pose, both scaled by ``noise`` (0 gives a deterministic expert).
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Iterator
from typing import Any

import gymnasium as gym
import numpy as np

from gym_actionflow.geometry import axis_angle_matrix, pose9, rotation_angle, rotation_log
from gym_actionflow.rollout import Episode, rollout
from gym_actionflow.shell import TokenEnv

OPEN, CLOSE = -1.0, 1.0
JITTER_POS = 0.002
JITTER_ROT = 0.02
WAYPOINT_POS = 0.004
"""At ``noise=1``: std of the per-step action jitter (m, rad) and of waypoint offsets (m)."""


class ScriptedExpert:
    """Base class: runs ``script()`` and returns one action per call of :meth:`act`."""

    speed = 0.02
    """Default TCP speed along a segment, metres per control step (0.4 m/s at 20 Hz)."""
    rot_speed = 0.12
    """Default rotation speed, radians per control step."""

    def __init__(self, env: gym.Env, noise: float = 0.0, seed: int | None = None) -> None:
        self.env: TokenEnv = env.unwrapped  # type: ignore[assignment]
        if not isinstance(self.env, TokenEnv):
            raise TypeError(
                f"{type(self).__name__} drives gym_actionflow envs; got {type(self.env).__name__}"
            )
        if noise < 0:
            raise ValueError(f"noise={noise}; expected >= 0")
        self.noise = float(noise)
        self.rng = np.random.default_rng(seed)
        self.jitter_scale = 1.0
        """Scales the per-step jitter: a script lowers it for phases with little clearance (reset: 1)."""
        self._plan: Iterator[np.ndarray] | None = None
        self._last: np.ndarray | None = None

    # ------------------------------------------------------------------ API
    def reset(self, seed: int | None = None) -> None:
        """Start a new plan from the env's current (freshly reset) state."""
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        pos, rot = self.env.tcp_pose()
        self.cmd_pos, self.cmd_rot = pos, rot
        self.grip = OPEN
        self.jitter_scale = 1.0
        self._plan = self.script()
        self._last = None

    def act(self, observation=None) -> np.ndarray:
        """Next action (10,) float32. Once the script is done the last pose is held."""
        if self._plan is None:
            self.reset()
        try:
            action = next(self._plan)
        except StopIteration:
            action = self._action(jitter=False)
        self._last = action
        return action

    @property
    def done(self) -> bool:
        """True once the script ran to its end."""
        return self._plan is not None and self._plan.gi_frame is None

    def script(self) -> Iterator[np.ndarray]:
        raise NotImplementedError

    # ------------------------------------------------------------------ building blocks
    def offset(self, scale: float = 1.0) -> np.ndarray:
        """A random waypoint offset (3,) in metres: normal with std ``WAYPOINT_POS * noise * scale``,
        truncated at 2 std so that rare tails do not turn a diverse demonstration into a failed one."""
        std = WAYPOINT_POS * self.noise * scale
        return np.clip(self.rng.normal(0.0, std, 3), -2 * std, 2 * std)

    def _action(self, jitter: bool = True) -> np.ndarray:
        pos, rot = self.cmd_pos, self.cmd_rot
        scale = self.noise * self.jitter_scale
        if jitter and scale > 0:
            pos = pos + self.rng.normal(0.0, JITTER_POS * scale, 3)
            rot = rot @ axis_angle_matrix(self.rng.normal(0.0, JITTER_ROT * scale, 3))
        return np.concatenate([pose9(pos, rot), [self.grip]]).astype(np.float32)

    def move_to(
        self,
        pos,
        rot,
        speed: float | None = None,
        rot_speed: float | None = None,
        tolerance: float = 0.003,
        max_wait: int = 10,
    ) -> Iterator[np.ndarray]:
        """Move the commanded pose in a straight line (and a geodesic in rotation) to (pos, rot), then wait
        up to ``max_wait`` steps for the TCP to arrive within ``tolerance`` metres."""
        speed = speed or self.speed
        rot_speed = rot_speed or self.rot_speed
        start_pos, start_rot = self.cmd_pos.copy(), self.cmd_rot.copy()
        goal_pos = np.asarray(pos, dtype=np.float64)
        rel = rotation_log(start_rot.T @ rot)
        n = int(
            np.ceil(max(np.linalg.norm(goal_pos - start_pos) / speed, np.linalg.norm(rel) / rot_speed, 1))
        )
        for k in range(1, n + 1):
            s = k / n
            s = s * s * (3 - 2 * s)  # smooth start and stop
            self.cmd_pos = start_pos + s * (goal_pos - start_pos)
            self.cmd_rot = start_rot @ axis_angle_matrix(s * rel)
            yield self._action()
        for _ in range(max_wait):
            tcp_pos, tcp_rot = self.env.tcp_pose()
            if np.linalg.norm(tcp_pos - goal_pos) < tolerance and rotation_angle(tcp_rot, rot) < 0.05:
                break
            yield self._action()

    def hold(self, steps: int) -> Iterator[np.ndarray]:
        for _ in range(steps):
            yield self._action()

    def set_gripper(self, command: float, steps: int = 6) -> Iterator[np.ndarray]:
        self.grip = command
        yield from self.hold(steps)

    def grasp(
        self,
        pos,
        rot,
        *,
        lift: float | None = None,
        lift_z: float | None = None,
        approach: float = 0.08,
        speed: float = 0.012,
        tolerance: float = 0.003,
        close_steps: int = 6,
        lift_speed: float = 0.015,
        fine_jitter: float | None = None,
    ) -> Iterator[np.ndarray]:
        """Grasp from above: to ``approach`` metres over the grasp pose (pos, rot), straight down to it at
        ``speed`` (then within ``tolerance``), close the fingers over ``close_steps`` steps, and lift straight
        up at ``lift_speed``: ``lift`` metres, or to the height ``lift_z``. ``fine_jitter`` scales the
        per-step jitter from the descent to the closed grasp (then back to 1), where the fingers have little
        clearance around the object. Whether the object is held is the caller's to check
        (:meth:`grasp_until_held` retries until it is)."""
        if (lift is None) == (lift_z is None):
            raise ValueError(f"give one of lift (m over the grasp) and lift_z (a height): {lift=}, {lift_z=}")
        pos = np.asarray(pos, dtype=np.float64)
        yield from self.move_to(pos + [0, 0, approach], rot)
        if fine_jitter is not None:
            self.jitter_scale = fine_jitter
        yield from self.move_to(pos, rot, speed=speed, tolerance=tolerance)
        yield from self.set_gripper(CLOSE, steps=close_steps)
        if fine_jitter is not None:
            self.jitter_scale = 1.0
        up = pos + [0, 0, lift] if lift is not None else np.array([pos[0], pos[1], lift_z])
        yield from self.move_to(up, rot, speed=lift_speed)

    def grasp_until_held(
        self,
        attempt: Callable[[], Generator[np.ndarray, None, Any]],
        held: Callable[[], bool],
        attempts: int = 3,
        release_steps: int = 6,
    ) -> Generator[np.ndarray, None, Any]:
        """Run ``attempt`` (one grasp, typically through :meth:`grasp`, reading the object's pose when it
        starts, so that a retry follows an object a miss has pushed) until ``held()``, at most ``attempts``
        times, opening the fingers for ``release_steps`` steps after each miss. Returns what the last attempt
        returned (e.g. its grasp rotation, which the carry keeps)."""
        result = None
        for _ in range(attempts):
            result = yield from attempt()
            if held():
                break
            yield from self.set_gripper(OPEN, steps=release_steps)
        return result


def run_episode(
    env: gym.Env,
    expert: ScriptedExpert,
    seed: int,
    expert_seed: int | None = None,
    on_frame: Callable[[np.ndarray], None] | None = None,
    on_step: Callable[[dict, np.ndarray], None] | None = None,
) -> Episode:
    """Reset ``env`` with ``seed`` and run ``expert`` until the episode terminates or is truncated
    (:func:`gym_actionflow.rollout.rollout`, the expert reset on the fresh state)."""
    return rollout(
        env, expert.act, seed, on_reset=lambda obs, info: expert.reset(seed=expert_seed), on_frame=on_frame,
        on_step=on_step,
    )


def object_in_tcp(env: TokenEnv, body_id: int) -> tuple[np.ndarray, np.ndarray]:
    """Pose of a body in the TCP frame, (position (3,), rotation (3, 3)): how an object sits in the hand."""
    tcp_pos, tcp_rot = env.tcp_pose()
    pos, rot = env.body_pose(body_id)
    return tcp_rot.T @ (pos - tcp_pos), tcp_rot.T @ rot


def tcp_for_object(obj_pos, obj_rot, grasp: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """TCP pose that puts a held object (with in-hand pose ``grasp``) at (obj_pos, obj_rot)."""
    rel_pos, rel_rot = grasp
    tcp_rot = obj_rot @ rel_rot.T
    return obj_pos - tcp_rot @ rel_pos, tcp_rot


def top_down(yaw: float) -> np.ndarray:
    """TCP rotation pointing straight down with the fingers closing along the direction ``yaw + pi/2``."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])


def symmetric_yaw(yaw: float, period: float, reference: float = 0.0) -> float:
    """The angle equal to ``yaw`` modulo ``period`` closest to ``reference`` (wrist-friendly grasps)."""
    return reference + (yaw - reference + period / 2) % period - period / 2
