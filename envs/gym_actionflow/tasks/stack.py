"""Stack (MimicGen): stack cube A on cube B, the simplest task of the suite."""

from __future__ import annotations

from typing import ClassVar

from gym_actionflow.tasks.stack_three import StackThreeEnv

RANGE = {"D0": 0.08, "D1": 0.20}
"""Half-width (m) of the square the cubes' centres are drawn from, per variant: MimicGen's Stack_D0 / D1 (its
Stack D0 is narrower than Stack Three's +-0.10 m)."""


class StackEnv(StackThreeEnv):
    """Stack two cubes: A (red, 4 cm) on B (green, 5 cm).

    MimicGen's Stack task, rebuilt on raw MuJoCo: one pick and one place, the suite's shortest task (about
    75 expert steps). It shares Stack Three's cubes, placement sampler and success rule; only its D0 range
    differs.

    ## Observation
    | key | shape | content |
    |---|---|---|
    | `token_poses` | (3, 9) | world poses: 0 = EEF (TCP), 1 = cube A, 2 = cube B |
    | `token_features` | (3, 4) | one-hot token id (3) + gripper opening in m (EEF row only) |
    | `agent_pos` | (10,) | EEF pose (9) + gripper opening |
    | `environment_state` | (18,) | poses of cubes A and B |
    | `pixels` | {"wrist": (84, 84, 3) uint8} | only with `obs_mode="pixels"` |

    Pose vectors are `[x, y, z, r00, r10, r20, r01, r11, r21]` (position + first two rotation columns).

    ## Action
    (10,) float32: absolute target TCP pose (9, world frame) + gripper command in [-1 open, 1 close]. The
    rotation is orthonormalised, the position clipped to the workspace and each step rate-limited to
    3 cm / 0.3 rad.

    ## Success
    Cube A touches cube B and rests above it, lifted off the table (bottom face more than 1 cm above it, no
    table contact), and is not held by the gripper.

    ## Starting state
    The arm at its home pose, gripper open. Cubes on the table, non-overlapping, yaw uniform in [0, 2 pi), x
    and y uniform in +-0.08 m (`variant="D0"`) or +-0.20 m (`variant="D1"`) around the table centre:
    MimicGen's Stack_D0 / Stack_D1 ranges (MimicGen has no Stack D2).

    ## Episode end
    Terminates on success (unless `terminate_on_success=False`); truncated after `max_episode_steps` (200).

    ## Version history
    * v0: initial release.
    * v0, issue 13: D0 narrowed from +-0.10 m to MimicGen's +-0.08 m (the new square lies inside the old one;
      datasets recorded earlier spread the cubes wider).
    """

    entity_names = ("cube_a", "cube_b")
    half_range: ClassVar[dict[str, float]] = RANGE
    task_description = "Stack the red cube on the green cube."

    def _check_success(self) -> bool:
        return self.stacked("cube_a", "cube_b")
