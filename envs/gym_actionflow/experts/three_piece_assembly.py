"""Scripted expert for Three Piece Assembly: pick piece 1 by its ridge, insert it into the base's socket, pick
piece 2 by its knob, lower its slot over piece 1's ridge."""

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
from gym_actionflow.geometry import yaw_matrix, yaw_of
from gym_actionflow.tasks.three_piece_assembly import PIECE1_HEIGHT, PIECE2_HEIGHT, SLAB_HEIGHT

GRASP_DEPTH = 0.025
"""The TCP stops this far below the top of a handle (ridge or knob, both 5 cm high): the pads (1.8 cm below
the TCP) stay 7 mm clear of the slab / plate under it."""
CARRY_Z = {"piece_1": 0.16, "piece_2": 0.12}
"""Height of a carried piece's bottom face during transit: piece 1 passes over piece 2 (13.5 cm tall), piece
2 over piece 1 standing in the base (9 cm). As low as that allows: the far side of the table is at the arm's
reach."""
CARRY_SPEED = 0.015
"""TCP speed (m per step) while carrying a piece."""
RELEASE_GAP = 0.004
"""A piece is let go this far above its seat."""
PLACE_OFFSET = 0.1
"""Scale of the random xy offset of a seat target (std 0.4 mm at noise 1): clearances are 5-8 mm per side."""
SERVO_ROUNDS, SERVO_STEPS, SERVO_TOL = 4, 3, 0.001
"""Before inserting: up to 4 corrections of the piece's xy error (averaged over 3 steps) until under 1 mm."""
FINE_JITTER = 0.3
"""Scale of the per-step action jitter while a piece is aligned, inserted and released (the rest of the
motion keeps the full jitter): at noise 1 the full jitter moves the hand by up to a centimetre, more than the
clearance."""


class ThreePieceAssemblyExpert(ScriptedExpert):
    def pick(self, name: str, height: float, closing_yaw: float):
        """Grasp ``name`` by its handle (top at ``height`` above the body origin), closing along
        ``closing_yaw`` (modulo pi), and lift it to the transit height."""
        env = self.env
        pos, _ = env.body_pose(env.model.body(name).id)
        # top_down(yaw) closes along yaw + pi/2; pick the equivalent yaw nearest the home wrist (0).
        grasp_rot = top_down(symmetric_yaw(closing_yaw - np.pi / 2, np.pi))
        grasp = pos + np.array([0, 0, height - GRASP_DEPTH]) + self.offset() * np.array([1, 1, 0.3])
        carry_z = CARRY_Z[name] + height - GRASP_DEPTH
        yield from self.grasp(grasp, grasp_rot, lift_z=carry_z, lift_speed=CARRY_SPEED)

    def insert(self, name: str, seat_pos: np.ndarray, seat_yaw: float, period: float, above: float):
        """Carry the held piece over its seat, align its yaw (modulo ``period``) with ``seat_yaw``, servo
        its xy onto the seat just above the entry, lower it until its bottom is ``RELEASE_GAP`` above
        ``seat_pos``, let go and retreat upwards."""
        env = self.env
        body = env.model.body(name).id
        in_hand = object_in_tcp(env, body)
        # The seat-aligned yaw (modulo ``period``) nearest the piece's current yaw: the least wrist rotation.
        yaw = symmetric_yaw(seat_yaw, period, reference=yaw_of(env.body_pose(body)[1]))
        target_rot = yaw_matrix(yaw)
        target = np.asarray(seat_pos, dtype=float) + [0, 0, RELEASE_GAP]
        target[:2] += self.offset(PLACE_OFFSET)[:2]
        carry = target.copy()
        carry[2] = max(CARRY_Z[name], target[2] + above)
        yield from self.move_to(*tcp_for_object(carry, target_rot, in_hand), speed=CARRY_SPEED)
        # Re-read how the piece sits in the hand after the transit, then go down to just above the entry.
        in_hand = object_in_tcp(env, body)
        yield from self.move_to(*tcp_for_object(target + [0, 0, above], target_rot, in_hand), speed=0.012)
        # Closed loop on the piece itself: average its xy error over a few steps and shift the hand to cancel
        # it (grasp offsets and in-hand tilt would otherwise add up to more than the clearance).
        self.jitter_scale = FINE_JITTER  # a steadier hand for the insertion itself
        for _ in range(SERVO_ROUNDS):
            error = np.zeros(2)
            for _ in range(SERVO_STEPS):
                yield self._action()
                error += (target[:2] - env.data.xpos[body][:2]) / SERVO_STEPS
            if np.linalg.norm(error) < SERVO_TOL:
                break
            yield from self.move_to(self.cmd_pos + [*error, 0.0], self.cmd_rot, speed=0.004, max_wait=0)
        at_pos = self.cmd_pos - [0, 0, above]
        yield from self.move_to(at_pos, self.cmd_rot, speed=0.006)
        yield from self.set_gripper(OPEN, steps=6)
        self.jitter_scale = 1.0
        yield from self.move_to(at_pos + [0, 0, 0.08], self.cmd_rot, speed=0.015)

    def script(self):
        env = self.env
        # Piece 1: grasp its ridge across its width (piece x axis), put its slab into the socket.
        p1_rot = env.body_pose(env.model.body("piece_1").id)[1]
        yield from self.pick("piece_1", PIECE1_HEIGHT, yaw_of(p1_rot))
        base_pos, base_rot = env.body_pose(env.model.body("base").id)  # origin: socket centre on the table
        yield from self.insert("piece_1", base_pos, yaw_of(base_rot), np.pi / 2, above=0.04)
        # Piece 2: grasp its knob, lower its slot over piece 1's ridge (both symmetric under half turns).
        p2_rot = env.body_pose(env.model.body("piece_2").id)[1]
        yield from self.pick("piece_2", PIECE2_HEIGHT, yaw_of(p2_rot))
        p1_pos, p1_rot = env.body_pose(env.model.body("piece_1").id)
        seat = p1_pos + [0, 0, SLAB_HEIGHT]
        yield from self.insert("piece_2", seat, yaw_of(p1_rot), np.pi, above=0.07)
        yield from self.hold(10)
