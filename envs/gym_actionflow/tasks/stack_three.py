"""Stack Three (MimicGen): stack cube A on cube B, then cube C on cube A."""

from __future__ import annotations

from typing import ClassVar

import mujoco
import numpy as np

from gym_actionflow.base import TABLE_TOP, ManipulationEnv
from gym_actionflow.geometry import yaw_quat
from gym_actionflow.placement import sample_separated, square

CUBE_HALF = {"cube_a": 0.02, "cube_b": 0.025, "cube_c": 0.02}
CUBE_RGBA = {"cube_a": (0.85, 0.15, 0.15, 1), "cube_b": (0.15, 0.7, 0.2, 1), "cube_c": (0.15, 0.3, 0.85, 1)}
RANGE = {"D0": 0.10, "D1": 0.20}
"""Half-width (m) of the square the cubes' centres are drawn from, per variant (MimicGen's StackThree_D0 /
D1)."""
LIFT = 0.01
"""A stacked cube's bottom face must be this far above the table (m)."""


def add_box_object(spec: mujoco.MjSpec, name: str, half: tuple[float, float, float], rgba, density=500.0):
    """A free-floating box body named ``name`` with a free joint ``name + '_joint'``."""
    body = spec.worldbody.add_body(name=name)
    body.add_freejoint(name=f"{name}_joint")
    body.add_geom(
        name=f"{name}_geom",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=half,
        rgba=rgba,
        density=density,
        friction=(1.0, 0.005, 0.0001),
        condim=4,
    )
    return body


class StackThreeEnv(ManipulationEnv):
    """Stack three cubes: A (red, 4 cm) on B (green, 5 cm), then C (blue, 4 cm) on A.

    MimicGen's Stack Three task, rebuilt on raw MuJoCo.

    ## Observation
    | key | shape | content |
    |---|---|---|
    | `token_poses` | (4, 9) | world poses: 0 = EEF (TCP), 1 = cube A, 2 = cube B, 3 = cube C |
    | `token_features` | (4, 5) | one-hot token id (4) + gripper opening in m (EEF row only) |
    | `agent_pos` | (10,) | EEF pose (9) + gripper opening |
    | `environment_state` | (27,) | poses of cubes A, B, C |
    | `pixels` | {"wrist": (84, 84, 3) uint8} | only with `obs_mode="pixels"` |

    Pose vectors are `[x, y, z, r00, r10, r20, r01, r11, r21]` (position + first two rotation columns).

    ## Action
    (10,) float32: absolute target TCP pose (9, world frame) + gripper command in [-1 open, 1 close]. The
    rotation is orthonormalised, the position clipped to the workspace and each step rate-limited to
    3 cm / 0.3 rad.

    ## Success
    Cube A touches cube B and rests above it, cube C touches cube A and rests above it, A and C are lifted off
    the table (bottom faces more than 1 cm above it, no table contact) and neither is held by the gripper.

    ## Starting state
    The arm at its home pose, gripper open. Cubes on the table, non-overlapping, yaw uniform in [0, 2 pi), x
    and y uniform in +-0.10 m (`variant="D0"`) or +-0.20 m (`variant="D1"`) around the table centre:
    MimicGen's StackThree_D0 / StackThree_D1 ranges (MimicGen has no Stack Three D2).

    ## Episode end
    Terminates on success (unless `terminate_on_success=False`); truncated after `max_episode_steps` (400).

    ## Version history
    * v0: initial release.
    """

    entity_names = ("cube_a", "cube_b", "cube_c")
    half_range: ClassVar[dict[str, float]] = RANGE
    """Placement half-width per variant (Stack has its own)."""
    task_description = "Stack the red cube on the green cube, then the blue cube on the red cube."

    def _build_task(self, spec: mujoco.MjSpec) -> None:
        for name in self.entity_names:
            half = CUBE_HALF[name]
            add_box_object(spec, name, (half, half, half), CUBE_RGBA[name])

    def _cache_refs(self) -> None:
        self.cube_ids = {n: self.model.body(n).id for n in self.entity_names}
        self.cube_geoms = {n: self.geoms_of(n) for n in self.entity_names}
        self.table_geoms = {self.model.geom("table").id}

    def _sample_layout(self, rng: np.random.Generator) -> None:
        half = self.half_range[self.variant]
        names = self.entity_names
        radii = [CUBE_HALF[n] * np.sqrt(2) + 0.01 for n in names]
        placed = sample_separated(rng, [square(half)] * len(names), radii)
        for name, (xy, yaw) in zip(names, placed, strict=True):
            pos = np.array([xy[0], xy[1], TABLE_TOP + CUBE_HALF[name]])
            self.set_free_pose(f"{name}_joint", pos, yaw_quat(yaw))

    def _entity_poses(self):
        return [self.body_pose(i) for i in self.cube_ids.values()]

    def stacked(self, top: str, bottom: str) -> bool:
        p_top = self.data.xpos[self.cube_ids[top]]
        p_bottom = self.data.xpos[self.cube_ids[bottom]]
        return bool(
            self.touching(self.cube_geoms[top], self.cube_geoms[bottom])
            and p_top[2] > p_bottom[2] + 0.5 * CUBE_HALF[bottom]
            and p_top[2] - CUBE_HALF[top] > TABLE_TOP + LIFT
            and not self.touching(self.cube_geoms[top], self.table_geoms)
            and not self.is_grasped(self.cube_geoms[top])
        )

    def _check_success(self) -> bool:
        return self.stacked("cube_a", "cube_b") and self.stacked("cube_c", "cube_a")
