"""Scripted expert for Stack Three: pick A, place on B, pick C, place on A."""

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
from gym_actionflow.tasks.stack_three import CUBE_HALF


class StackThreeExpert(ScriptedExpert):
    def pick(self, name: str):
        env = self.env
        pos, rot = env.body_pose(env.model.body(name).id)
        yaw = symmetric_yaw(yaw_of(rot), np.pi / 2)
        grasp_rot = top_down(yaw)
        grasp = pos + np.array([0, 0, 0.002]) + self.offset() * np.array([1, 1, 0.3])
        yield from self.grasp(grasp, grasp_rot, lift=0.08 + CUBE_HALF["cube_b"])

    def place_on(self, held: str, base: str):
        env = self.env
        held_id, base_id = env.model.body(held).id, env.model.body(base).id
        in_hand = object_in_tcp(env, held_id)
        base_pos, base_rot = env.body_pose(base_id)
        held_rot = env.body_pose(held_id)[1]
        # Align the held cube with the base cube, turning the wrist as little as possible: cubes are symmetric
        # under quarter turns, so the base's yaw is taken modulo pi/2 nearest to the held cube's current yaw.
        yaw = symmetric_yaw(yaw_of(base_rot), np.pi / 2, reference=yaw_of(held_rot))
        target_rot = yaw_matrix(yaw)
        target = base_pos + np.array([0, 0, CUBE_HALF[base] + CUBE_HALF[held] + 0.004])
        target[:2] += self.offset(0.5)[:2]
        above_pos, above_rot = tcp_for_object(target + [0, 0, 0.05], target_rot, in_hand)
        at_pos, at_rot = tcp_for_object(target, target_rot, in_hand)
        yield from self.move_to(above_pos, above_rot)
        yield from self.move_to(at_pos, at_rot, speed=0.01)
        yield from self.set_gripper(OPEN, steps=6)
        yield from self.move_to(at_pos + [0, 0, 0.07], at_rot, speed=0.015)

    def stack(self, held: str, base: str, attempts: int = 3):
        """Pick ``held`` and place it on ``base``; a missed grasp or a cube that fell is picked again."""
        env = self.env
        for _ in range(attempts):
            yield from self.pick(held)
            if not env.is_grasped(env.cube_geoms[held]):
                yield from self.set_gripper(OPEN, steps=4)
                continue
            yield from self.place_on(held, base)
            if env.stacked(held, base):
                return

    def script(self):
        yield from self.stack("cube_a", "cube_b")
        yield from self.stack("cube_c", "cube_a")
        yield from self.hold(10)


class StackExpert(StackThreeExpert):
    """Stack: pick A, place it on B."""

    def script(self):
        yield from self.stack("cube_a", "cube_b")
        yield from self.hold(10)
