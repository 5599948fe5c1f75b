"""Scripted experts for robomimic's tasks on robosuite (Lift, Can, Square, Tool Hang).

The same waypoint scripts as the rest of the suite (:class:`ScriptedExpert`): object poses are read when each
phase starts, a missed grasp is retried, and ``noise`` offsets the waypoints and jitters the actions.
"""

from __future__ import annotations

import numpy as np

from gym_actionflow.experts.base import (
    CLOSE,
    OPEN,
    ScriptedExpert,
    object_in_tcp,
    symmetric_yaw,
    tcp_for_object,
    top_down,
)
from gym_actionflow.geometry import yaw_matrix, yaw_of

_HOME_YAW = top_down(0.0).T
"""Multiplying a top-down TCP rotation by this leaves its yaw relative to the start pose."""


class LiftExpert(ScriptedExpert):
    """Grasp the cube from above, across its faces, and lift it."""

    def script(self):
        env = self.env
        for _ in range(3):
            pos, rot = env.body_pose(env.cube_id)
            grasp_rot = top_down(symmetric_yaw(yaw_of(rot), np.pi / 2))
            grasp = pos + self.offset() * np.array([1.0, 1.0, 0.3])
            yield from self.move_to(grasp + [0, 0, 0.08], grasp_rot)
            yield from self.move_to(grasp, grasp_rot, speed=0.012)
            yield from self.set_gripper(CLOSE, steps=8)
            yield from self.move_to(grasp + [0, 0, 0.15], grasp_rot, speed=0.012)
            yield from self.hold(10)
            yield from self.set_gripper(OPEN, steps=6)  # reached only when the cube slipped out


class CanExpert(ScriptedExpert):
    """Grasp the can from above by its upper half, carry it over its compartment, lower it in and let go."""

    def script(self):
        env = self.env
        can_geoms = env.geoms_of("Can_main")
        for _ in range(3):
            pos, _ = env.body_pose(env.can_id)
            grasp_rot = top_down(0.0)
            grasp = pos + np.array([0.0, 0.0, 0.02]) + self.offset() * np.array([1.0, 1.0, 0.3])
            yield from self.move_to(grasp + [0, 0, 0.1], grasp_rot)
            yield from self.move_to(grasp, grasp_rot, speed=0.012)
            yield from self.set_gripper(CLOSE, steps=8)
            yield from self.move_to(grasp + [0, 0, 0.15], grasp_rot, speed=0.015)
            if env.is_grasped(can_geoms):
                break
            yield from self.set_gripper(OPEN, steps=6)
        target = env.target_pos + self.offset(2.0) * np.array([1.0, 1.0, 0.0])
        held = env.body_pose(env.can_id)[0]
        tcp = env.tcp_pose()[0]
        drop = target + (tcp - held) + np.array([0.0, 0.0, 0.07])
        yield from self.move_to(np.array([drop[0], drop[1], tcp[2]]), grasp_rot)
        yield from self.move_to(drop, grasp_rot, speed=0.012)
        yield from self.set_gripper(OPEN, steps=8)
        yield from self.move_to(drop + [0, 0, 0.1], grasp_rot, speed=0.015)
        yield from self.hold(10)


class SquareExpert(ScriptedExpert):
    """Grasp the square nut by its handle, carry it above the peg with a side of its hole along the peg's,
    lower it over the peg and let go."""

    def script(self):
        env = self.env
        nut_geoms = env.geoms_of("SquareNut_main")
        for _ in range(3):
            handle, _ = env.site_pose(env.handle_site)
            nut_rot = env.body_pose(env.nut_id)[1]
            # Fingers across the handle; of the two such grasps, the one nearer the wrist's start.
            grasp_rot = top_down(symmetric_yaw(yaw_of(nut_rot), np.pi))
            grasp = handle + self.offset(0.5) * np.array([1.0, 1.0, 0.3])
            yield from self.move_to(grasp + [0, 0, 0.08], grasp_rot)
            yield from self.move_to(grasp, grasp_rot, speed=0.01)
            yield from self.set_gripper(CLOSE, steps=8)
            # Up to clear the peg (its top is 13 cm above the table) before any sideways move.
            yield from self.move_to(np.array([grasp[0], grasp[1], 0.21]), grasp_rot, speed=0.012)
            if env.is_grasped(nut_geoms):
                break
            yield from self.set_gripper(OPEN, steps=6)
        in_hand = object_in_tcp(env, env.nut_id)
        peg_pos, peg_rot = env.body_pose(env.peg_id)
        nut_rot = env.body_pose(env.nut_id)[1]
        # The hole is square: any quarter turn of the nut fits. Take one that keeps the hand on the robot's
        # side of the peg (beyond it the Panda is at the end of its reach) and turns the wrist least from its
        # start (a half turn runs joint 7 into its limit).
        def cost(nut_rot: np.ndarray) -> float:
            tcp_pos, tcp_rot = tcp_for_object(peg_pos, nut_rot, in_hand)
            return abs(yaw_of(tcp_rot @ _HOME_YAW)) + (3.0 if tcp_pos[0] > peg_pos[0] + 0.01 else 0.0)

        target_rot = min((yaw_matrix(yaw_of(peg_rot) + k * np.pi / 2) for k in range(4)), key=cost)
        above = np.array([peg_pos[0], peg_pos[1], 0.2])
        above[:2] += self.offset(0.3)[:2]
        low = np.array([above[0], above[1], 0.03])
        above_pos, above_rot = tcp_for_object(above, target_rot, in_hand)
        low_pos, low_rot = tcp_for_object(low, target_rot, in_hand)
        yield from self.move_to(above_pos, above_rot, speed=0.015)
        self.jitter_scale = 0.3  # 2-3 mm of clearance between the hole and the peg
        yield from self.move_to(above_pos, above_rot, tolerance=0.002, max_wait=15)
        yield from self.move_to(low_pos, low_rot, speed=0.008)
        yield from self.set_gripper(OPEN, steps=8)
        self.jitter_scale = 1.0
        yield from self.move_to(low_pos + [0, 0, 0.1], low_rot, speed=0.015)
        yield from self.hold(10)
