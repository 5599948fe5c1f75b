"""Scripted experts for robomimic's tasks on robosuite (Lift, Can, Square, Tool Hang).

The same waypoint scripts as the rest of the suite (:class:`ScriptedExpert`): object poses are read when each
phase starts, a missed grasp is retried, and ``noise`` offsets the waypoints and jitters the actions.
"""

from __future__ import annotations

import numpy as np

from gym_actionflow.experts.base import (
    OPEN,
    ScriptedExpert,
    object_in_tcp,
    symmetric_yaw,
    tcp_for_object,
    top_down,
)
from gym_actionflow.geometry import axis_angle_matrix, yaw_matrix, yaw_of

_HOME_YAW = top_down(0.0).T
"""Multiplying a top-down TCP rotation by this leaves its yaw relative to the start pose."""


class LiftExpert(ScriptedExpert):
    """Grasp the cube from above, across its faces, and lift it."""

    def script(self):
        env = self.env

        def grasp_cube():
            pos, rot = env.body_pose(env.cube_id)
            grasp_rot = top_down(symmetric_yaw(yaw_of(rot), np.pi / 2))
            grasp = pos + self.offset() * np.array([1.0, 1.0, 0.3])
            yield from self.grasp(grasp, grasp_rot, close_steps=8, lift=0.15, lift_speed=0.012)
            yield from self.hold(10)

        # Lifted is success, which ends the episode: the cube is grasped again only when it slipped out.
        yield from self.grasp_until_held(grasp_cube, held=env.is_success)


class CanExpert(ScriptedExpert):
    """Grasp the can from above by its upper half, carry it over its compartment, lower it in and let go."""

    def script(self):
        env = self.env
        can_geoms = env.geoms_of("Can_main")
        grasp_rot = top_down(0.0)

        def grasp_can():
            pos, _ = env.body_pose(env.can_id)
            grasp = pos + np.array([0.0, 0.0, 0.02]) + self.offset() * np.array([1.0, 1.0, 0.3])
            yield from self.grasp(grasp, grasp_rot, approach=0.1, close_steps=8, lift=0.15)

        yield from self.grasp_until_held(grasp_can, held=lambda: env.is_grasped(can_geoms))
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

        def grasp_nut():
            handle, _ = env.site_pose(env.handle_site)
            nut_rot = env.body_pose(env.nut_id)[1]
            # Fingers across the handle; of the two such grasps, the one nearer the wrist's start.
            grasp_rot = top_down(symmetric_yaw(yaw_of(nut_rot), np.pi))
            grasp = handle + self.offset(0.5) * np.array([1.0, 1.0, 0.3])
            # Up to clear the peg (its top is 13 cm above the table) before any sideways move.
            yield from self.grasp(grasp, grasp_rot, speed=0.01, close_steps=8, lift_z=0.21, lift_speed=0.012)

        yield from self.grasp_until_held(grasp_nut, held=lambda: env.is_grasped(nut_geoms))
        in_hand = object_in_tcp(env, env.nut_id)
        peg_pos, peg_rot = env.body_pose(env.peg_id)
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


# Tool Hang (robosuite's ToolHang model).
BAR = 0.0075
"""Thickness of the frame's square bars (m): its frame_thickness."""
RING_INNER = 0.0098
"""Inner radius of the tool's large hole (m), across the flats of the octagon of boxes that models it."""
RING_HALF_HEIGHT = 0.0035
"""Half the thickness of the tool's large hole (m): half its height_1."""
FRAME_GRASP_TILT = np.radians(30.0)
"""How far the hand grasping the frame leans back from pointing straight down."""
HOOK_GAP = 0.002
"""Clearance between the hole's underside and the bar when the tool starts rolling (m)."""
HOOK_INSET = 0.001
"""How far in along the bar from the post's axis the hole's centre starts (m)."""
PIVOT_DRIFT = 0.003
"""How far the rolling tool moves in along the bar in the second half of the roll, clearing the post (m)."""
ROLL = np.pi / 2
"""The roll about the bar that takes the tool from flat to hanging."""
ROLL_STEPS = 60
"""Control steps of the roll (3 s)."""


class ToolHangExpert(ScriptedExpert):
    """Insert the hook frame into the stand, then hang the tool on the frame's hook.

    The frame lies flat: grasp its grip from above, fingers across the grip, lift it and turn it upright (the
    hand then points back at the robot), lower its tip into the stand's mount hole with its hanging bar
    pointing to the robot's right, and let go. Then grasp the tool by its grip from above, carry it flat with
    its large hole around the hook's post (at the bar's free end) and its handle pointing out along the bar,
    and roll it down about the bar: the hole goes round the corner between the post and the bar, the handle
    swings down and the tool hangs from the bar, inside the hook. Let go and back off.

    The hole is 2 cm across; the bar and the post are 7.5 mm thick and the post stands 12 mm over the bar, so
    the hole cannot be slid over the hook's end (1 mm to spare) but clears the corner by 1-2 mm when rolled
    about the inner edge of its underside.
    """

    def script(self):
        yield from self._insert_frame()
        yield from self._hang_tool()

    # ------------------------------------------------------------------ frame
    def _insert_frame(self):
        env = self.env
        frame_geoms = env.geoms_of("frame_root")
        grip_local = env.model.geom_pos[env.frame_grip_geom]

        def grasp_frame():
            pos, rot = env.body_pose(env.frame_id)
            grip = pos + rot @ grip_local
            # The frame lies with its y axis down: fingers along its x axis (across the grip), the TCP's y
            # against the frame's x (the wrist turns least); upright, the frame's hanging bar is then along
            # the TCP's y. The hand leans back towards the frame's top, so that the upright frame is held by a
            # hand pointing down at it rather than a level one, which would stretch the arm out straight (the
            # stand is at the end of its reach).
            x_axis = rot[:, 0]
            level_rot = top_down(np.arctan2(-x_axis[0], x_axis[1]))
            grasp_rot = level_rot @ axis_angle_matrix([0.0, FRAME_GRASP_TILT, 0.0])
            grasp = grip + np.array([0.0, 0.0, 0.005]) + self.offset(0.5) * np.array([1.0, 1.0, 0.3])
            yield from self.move_to(grasp + [0, 0, 0.1], level_rot)
            yield from self.grasp(grasp, grasp_rot, speed=0.01, close_steps=8, lift=0.1, lift_speed=0.012)
            return grasp_rot

        grasp_rot = yield from self.grasp_until_held(grasp_frame, held=lambda: env.is_grasped(frame_geoms))
        yield from self.move_to(self.cmd_pos + [0, 0, 0.2], grasp_rot, speed=0.015)

        # Upright over the centre of the mount hole's opening, the hanging bar along the stand's -y.
        stand_pos, stand_rot = env.body_pose(env.stand_id)
        walls = env.stand_wall_geoms
        hole_local = env.model.geom_pos[walls].mean(axis=0)
        hole_local[2] += env.model.geom_size[walls[0], 2]
        hole = stand_pos + stand_rot @ hole_local
        frame_rot = stand_rot @ yaw_matrix(np.pi / 2)
        tip_local = env.model.site_pos[env.frame_tip_site]

        def tcp_with_tip_at(height, in_hand):
            """TCP pose that puts the frame's tip ``height`` over the hole's opening."""
            frame_pos = hole + np.array([0.0, 0.0, height]) - frame_rot @ tip_local
            return tcp_for_object(frame_pos, frame_rot, in_hand)

        # Turn it upright on the way (its tip swings down 19 cm under the hand: high enough to clear the
        # stand).
        pos, rot = tcp_with_tip_at(0.03, object_in_tcp(env, env.frame_id))
        yield from self.move_to(pos + self.offset(), rot, speed=0.015, rot_speed=0.06)
        # The hole is 10 mm wide, the frame's bar 7.5 mm: settle, then place from the in-hand pose seen now.
        self.jitter_scale = 0.2
        yield from self.hold(5)
        in_hand = object_in_tcp(env, env.frame_id)
        pos, rot = tcp_with_tip_at(0.015, in_hand)
        yield from self.move_to(pos, rot, tolerance=0.0015, max_wait=20)
        low_pos, low_rot = tcp_with_tip_at(0.01 - hole[2], in_hand)  # the tip 1 cm over the table
        yield from self.move_to(low_pos, low_rot, speed=0.005)
        yield from self.set_gripper(OPEN, steps=8)
        self.jitter_scale = 1.0
        # Back off along the fingers (up and away) until the fingertips clear the grip (the hanging bar is
        # right above it), then turn the hand down again about the fingertips, rising: the wrist comes back
        # towards the robot, the open fingers staying on either side of the grip.
        back = low_pos - 0.03 * low_rot[:, 2]
        yield from self.move_to(back, low_rot, speed=0.005)
        yield from self.move_to(back + [0, 0, 0.03], top_down(0.0), speed=0.01, rot_speed=0.03)
        yield from self.move_to(back + [0, 0, 0.1] + self.offset(2.0), top_down(0.0), speed=0.015)

    # ------------------------------------------------------------------ tool
    def _hang_tool(self):
        env = self.env
        tool_geoms = env.geoms_of("tool_root")

        def grasp_tool():
            pos, rot = env.body_pose(env.tool_id)
            # Fingers across the grip, the TCP's y against the tool's y: of the two such grasps, the one that
            # ends the roll with the hand pointing along the bar and the elbow comfortably bent.
            y_axis = -rot[:, 1]
            grasp_rot = top_down(np.arctan2(y_axis[0], -y_axis[1]))
            grasp = pos + np.array([0.0, 0.0, 0.003]) + self.offset(0.5) * np.array([1.0, 1.0, 0.3])
            yield from self.grasp(grasp, grasp_rot, speed=0.01, close_steps=8, lift=0.1, lift_speed=0.012)

        yield from self.grasp_until_held(grasp_tool, held=lambda: env.is_grasped(tool_geoms))

        # The hanging bar: its free end (the hang site) and its direction from the frame's corner out to it.
        hang, frame_rot = env.site_pose(env.frame_hang_site)
        corner = env.site_pose(env.frame_corner_site)[0]
        out = (hang - corner) / np.linalg.norm(hang - corner)
        up = frame_rot[:, 2]
        side = np.cross(up, out)
        post = hang - BAR / 2 * out  # on the bar's axis, under the post
        # The tool flat, its handle pointing out along the bar, the hole around the post and its underside
        # just over the bar; it then rolls about the inner edge of that underside (an axis along `side`).
        flat_rot = np.stack([out, side, up], axis=1)
        hole = post + (BAR / 2 + HOOK_GAP + RING_HALF_HEIGHT) * up - HOOK_INSET * out
        pivot = hole - RING_INNER * out - RING_HALF_HEIGHT * up
        pos, rot = env.body_pose(env.tool_id)
        hole_local = rot.T @ (env.site_pose(env.tool_hole_site)[0] - pos)

        def tcp_with_hole_at(hole_pos, tool_rot, in_hand):
            """TCP pose that puts the centre of the tool's large hole at ``hole_pos``."""
            return tcp_for_object(hole_pos - tool_rot @ hole_local, tool_rot, in_hand)

        above = hole + 0.04 * up
        pos, rot = tcp_with_hole_at(above + self.offset(), flat_rot, object_in_tcp(env, env.tool_id))
        yield from self.move_to(pos + [0, 0, 0.05], rot, speed=0.015)
        yield from self.move_to(pos, rot, speed=0.01)
        # 1-2 mm to spare from here on: settle, then place from the in-hand pose seen now.
        self.jitter_scale = 0.2
        yield from self.hold(5)
        in_hand = object_in_tcp(env, env.tool_id)
        yield from self.move_to(*tcp_with_hole_at(above, flat_rot, in_hand), tolerance=0.0015, max_wait=20)
        yield from self.move_to(*tcp_with_hole_at(hole, flat_rot, in_hand), speed=0.004, tolerance=0.0015)
        # Roll: the handle swings down about the pivot; past half-way the hole also moves in along the bar,
        # its inner wall keeping clear of the post.
        for k in range(1, ROLL_STEPS + 1):
            s = k / ROLL_STEPS
            angle = ROLL * s * s * (3 - 2 * s)
            turn = axis_angle_matrix(angle * side)
            drift = PIVOT_DRIFT * max(0.0, (angle - ROLL / 2) / (ROLL / 2))
            hole_k = pivot - drift * out + turn @ (hole - pivot)
            self.cmd_pos, self.cmd_rot = tcp_with_hole_at(hole_k, turn @ flat_rot, in_hand)
            yield self._action()
        yield from self.hold(10)
        yield from self.set_gripper(OPEN, steps=8)
        self.jitter_scale = 1.0
        back = self.cmd_pos - 0.08 * self.cmd_rot[:, 2]
        yield from self.move_to(back + self.offset(), self.cmd_rot, speed=0.01)
        yield from self.hold(10)
