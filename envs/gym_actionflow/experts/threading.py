"""Scripted expert for Threading: grasp the needle's handle, align the bar with the ring axis, push it in."""

from __future__ import annotations

import numpy as np

from gym_actionflow.base import ROBOT_BASE
from gym_actionflow.experts.base import ScriptedExpert, object_in_tcp, tcp_for_object, top_down
from gym_actionflow.geometry import yaw_of
from gym_actionflow.tasks.threading import NEEDLE_TIP, RING_HEIGHT

REACH = 0.72
"""Horizontal distance from the robot base (m) beyond which a TCP pointing down at ring height is avoided (the
arm's top-down reach at that height is about 0.79 m)."""
TRAVEL_HEIGHT = RING_HEIGHT + 0.06
"""The needle is carried at this height (clear of the ring) between the grasp and the ring."""


def wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


def reach(pos: np.ndarray) -> float:
    return float(np.linalg.norm(pos[:2] - np.asarray(ROBOT_BASE[:2])))


class ThreadingExpert(ScriptedExpert):
    approach = 0.03
    """The tip stops this far before the ring plane (m) before the straight push along the ring axis."""
    depth = 0.045
    """How far beyond the ring plane the push brings the tip (m)."""
    retries = 2
    """Pushes that miss the ring are retried this many times."""

    def thread_direction(self) -> np.ndarray:
        """Rotation whose x axis is the direction the tip travels through the ring (the ring axis or its
        opposite): from the needle's side of the ring, unless the handle would then be out of easy reach."""
        env = self.env
        ring_pos, ring_rot = env.body_pose(env.tripod_id)
        needle_pos = env.body_pose(env.needle_id)[0]
        flipped = ring_rot @ np.diag([-1.0, -1.0, 1.0])
        options = sorted((ring_rot, flipped), key=lambda r: float(r[:2, 0] @ (needle_pos - ring_pos)[:2]))
        for rot in options:
            if reach(ring_pos - (NEEDLE_TIP + self.approach) * rot[:, 0]) < REACH:
                return rot
        return min(options, key=lambda r: reach(ring_pos - (NEEDLE_TIP + self.approach) * r[:, 0]))

    def grasp_needle(self, flip: float):
        env = self.env
        pos, rot = env.body_pose(env.needle_id)
        # Fingers close across the handle; the bar lies along the TCP's +x (flip = 0) or -x (flip = pi) axis.
        grasp_rot = top_down(yaw_of(rot) + flip)
        grasp = pos + np.array([0.0, 0.0, 0.002]) + self.offset() * np.array([1.0, 1.0, 0.3])
        yield from self.grasp(grasp, grasp_rot, lift_z=TRAVEL_HEIGHT)

    def thread(self, rot: np.ndarray):
        env = self.env
        ring_pos = env.body_pose(env.tripod_id)[0]
        err = rot @ (self.offset(0.25) * np.array([0.0, 1.0, 1.0]))  # across the ring axis only
        # Needle origin with the tip just before the ring.
        start = ring_pos - (NEEDLE_TIP + self.approach) * rot[:, 0] + err
        # Carry the needle above the ring, aligned with the threading direction, then lower it in front of it.
        in_hand = object_in_tcp(env, env.needle_id)
        above_pos, above_rot = tcp_for_object(start + [0, 0, TRAVEL_HEIGHT - RING_HEIGHT], rot, in_hand)
        yield from self.move_to(above_pos, above_rot)
        at_pos, at_rot = tcp_for_object(start, rot, in_hand)
        yield from self.move_to(at_pos, at_rot, speed=0.012)
        for _ in range(1 + self.retries):
            # Re-read how the needle sits in the hand (it may have slipped or turned on the ring) and correct
            # before the push; if the push missed the ring, back out and try again.
            in_hand = object_in_tcp(env, env.needle_id)
            at_pos, at_rot = tcp_for_object(start, rot, in_hand)
            yield from self.move_to(at_pos, at_rot, speed=0.005, max_wait=5)
            end_pos, end_rot = tcp_for_object(start + (self.approach + self.depth) * rot[:, 0], rot, in_hand)
            yield from self.move_to(end_pos, end_rot, speed=0.006)
            if env.is_success():
                return
            yield from self.move_to(at_pos, at_rot, speed=0.008)

    def script(self):
        env = self.env
        rot = self.thread_direction()
        needle_yaw = yaw_of(env.body_pose(env.needle_id)[1])
        # Grasp so that both the grasp and the threading wrist yaws stay as close to home (0) as possible.
        flip = min((0.0, np.pi), key=lambda f: max(abs(wrap(needle_yaw + f)), abs(wrap(yaw_of(rot) + f))))
        yield from self.grasp_needle(flip)
        yield from self.thread(rot)
        yield from self.hold(10)
