"""Scripted expert for Coffee: pick the pod, drop it into the holder, sweep the lid shut, press it down."""

from __future__ import annotations

import numpy as np

from gym_actionflow.experts.base import (
    CLOSE,
    OPEN,
    ScriptedExpert,
    symmetric_yaw,
    top_down,
)
from gym_actionflow.tasks.coffee import (
    HINGE_Y,
    HINGE_Z,
    HOLDER_DEPTH,
    LID_HALF,
    POD_HALF_HEIGHT,
    CoffeeEnv,
)

GRASP_ABOVE_CENTER = 0.012
"""The TCP grasps the pod 1.2 cm above its centre, so the finger pads stay above the holder rim at the
drop."""
DROP_DEPTH = 0.012
"""The pod is released with its bottom 1.2 cm inside the holder (the pads are then 5 mm above the rim)."""
CARRY_Z = 0.30
"""TCP height for the transfer (the pod's bottom clears the open lid's hinge and the holder)."""
SWEEP_RADIUS = 0.075
SWEEP_START = np.deg2rad(155.0)
SWEEP_END = np.deg2rad(20.0)
"""The closed fingers sweep an arc around the hinge axis (radius, start and end angle from the holder's +y
axis), from behind the open lid over the top: they push the lid past vertical and down onto the holder."""
APPROACH_LIFT = 0.08
"""The fingers come down onto the sweep's start from this far above it, after rising straight up from the
holder: the open lid's free edge stands about 13 cm above the holder floor, in the straight path from the
holder to the sweep, and its stop (a joint limit as stiff as the contacts) does not let it swing away."""


class CoffeeExpert(ScriptedExpert):
    env: CoffeeEnv

    def holder_frame(self) -> tuple[np.ndarray, np.ndarray]:
        return self.env.body_pose(self.env.machine_id)

    def grasp_rotation(self) -> np.ndarray:
        """Top-down TCP rotation whose fingers close along the hinge axis (the holder's x axis), so the
        fingers stay clear of the open lid; of the two equivalent yaws the one nearest home is used."""
        h_rot = self.holder_frame()[1]
        machine_yaw = float(np.arctan2(h_rot[1, 0], h_rot[0, 0]))
        return top_down(symmetric_yaw(machine_yaw - np.pi / 2, np.pi))

    def pick(self):
        env = self.env
        rot = self.grasp_rotation()
        pod = env.data.xpos[env.pod_id].copy()
        # Waypoint noise mostly along the closing axis (TCP y), where the fingers centre the pod: an offset
        # along the narrow (1.8 cm) pads would hold the round pod near a pad edge, from which it slides out.
        off = rot @ (self.offset() * np.array([0.3, 1.0, 0.3]))
        grasp = pod + np.array([0.0, 0.0, GRASP_ABOVE_CENTER]) + off
        yield from self.grasp(grasp, rot, lift=0.10)

    def drop_into_holder(self):
        env = self.env
        h_pos, h_rot = self.holder_frame()
        rot = self.grasp_rotation()
        target = h_pos + h_rot @ np.array([0.0, 0.0, POD_HALF_HEIGHT + HOLDER_DEPTH - DROP_DEPTH])
        target[:2] += self.offset(0.3)[:2]

        def tcp_above(height: float) -> np.ndarray:
            """TCP position (top-down grasp rotation kept) that puts the pod's centre ``height`` above the
            target, from the pod's in-hand position measured now."""
            tcp_pos, tcp_rot = env.tcp_pose()
            pod_in_tcp = tcp_rot.T @ (env.data.xpos[env.pod_id] - tcp_pos)
            return target + np.array([0.0, 0.0, height]) - rot @ pod_in_tcp

        above = tcp_above(0.05)
        yield from self.move_to(np.array([above[0], above[1], max(above[2], CARRY_Z)]), rot)
        # The pod can creep in the fingers during the transfer: re-measure its in-hand position over the
        # holder and again just above the rim before each part of the descent.
        for height, speed in ((0.05, 0.015), (0.015, 0.008), (0.0, 0.006)):
            yield from self.move_to(tcp_above(height), rot, speed=speed, tolerance=0.002)
        yield from self.set_gripper(OPEN, steps=6)
        yield from self.move_to(self.cmd_pos + [0, 0, 0.05], rot, speed=0.015)

    def close_lid(self):
        h_pos, h_rot = self.holder_frame()
        rot = self.grasp_rotation()
        hinge = np.array([0.0, HINGE_Y, HINGE_Z])
        off = self.offset(0.5)

        def arc(angle: float) -> np.ndarray:
            local = hinge + SWEEP_RADIUS * np.array([0.0, np.cos(angle), np.sin(angle)])
            return h_pos + h_rot @ local + off

        start = arc(SWEEP_START)
        self.grip = CLOSE
        approach = start + [0, 0, APPROACH_LIFT]
        yield from self.move_to(np.array([*self.cmd_pos[:2], approach[2]]), rot)
        yield from self.move_to(approach, rot)
        yield from self.move_to(start, rot, speed=0.015)
        n = 24
        for k in range(1, n + 1):
            self.cmd_pos = arc(SWEEP_START + (SWEEP_END - SWEEP_START) * k / n)
            yield self._action()
        # Press the closed lid down at its middle, then lift away.
        lid_top = HINGE_Z + LID_HALF[2]
        press = h_pos + h_rot @ np.array([0.0, HINGE_Y + 1.2 * LID_HALF[1], lid_top + 0.018 - 0.004]) + off
        yield from self.move_to(press, rot, speed=0.01)
        yield from self.hold(4)
        yield from self.move_to(press + [0, 0, 0.08], rot, speed=0.015)

    def script(self):
        yield from self.pick()
        yield from self.drop_into_holder()
        yield from self.close_lid()
        yield from self.hold(20)
