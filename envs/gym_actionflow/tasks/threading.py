"""Threading (MimicGen): pick up a needle by its handle and pass its tip through the ring of a tripod."""

from __future__ import annotations

import mujoco
import numpy as np

from gym_actionflow.base import TABLE_TOP, ManipulationEnv
from gym_actionflow.geometry import yaw_quat

# Needle (free body). Its frame: origin at the centre of the handle, x axis along the bar towards the tip,
# z axis up when it lies on the table. Sizes as MimicGen's NeedleObject: a 4 cm cube handle and a 1 cm thick,
# 12 cm long bar (MimicGen: a 1 cm square box; here a capsule of radius 5 mm), 16 cm in all.
HANDLE_HALF = 0.02
BAR_RADIUS = 0.005
BAR_ROOT = HANDLE_HALF
"""Where the bar leaves the handle, along the needle's x axis (m)."""
NEEDLE_TIP = HANDLE_HALF + 0.12
"""The tip (end of the bar's rounded cap), along the needle's x axis (m): 0.14."""
NEEDLE_CENTRE = (NEEDLE_TIP - HANDLE_HALF) / 2
"""The middle of the needle's 16 cm length, along its x axis (MimicGen's placement ranges refer to it)."""

# Tripod (static fixture). Its frame is the ring frame: origin at the ring centre, x axis = the ring axis (for
# MimicGen's layouts it points away from the side the needle starts on), z axis up. The ring is symmetric: the
# needle may go through it either way.
RING_RADIUS = 0.012
"""Radius of the ring's opening (m), also the success radius: MimicGen's success radius (``ring_size[1]``).
MimicGen's physical hole is tighter (a 1.6 cm square around a 1 cm square bar); here 7 mm of clearance."""
RING_TUBE = 0.003
RING_SEGMENTS = 8
RING_HEIGHT = 0.19
"""Height of the ring centre above the table (MimicGen's tripod: 0.189 m)."""
THROUGH = 0.01
"""The tip must be at least this far beyond the ring plane (m)."""
_PLATE_Z = 0.085
_LEG_RADIUS = 0.008

# Placement (MimicGen's Threading_D0 / D1 / D2 bounds; the table centre is the world origin here too). D2 is
# D1 mirrored left / right (y -> -y): the needle on the robot's right, the tripod on its left.
NEEDLE_X = {"D0": (-0.2, -0.05), "D1": (-0.2, 0.05), "D2": (-0.2, 0.05)}
NEEDLE_Y = {"D0": (0.15, 0.25), "D1": (0.15, 0.25), "D2": (-0.25, -0.15)}
NEEDLE_YAW = {"D0": (-7 * np.pi / 6, -5 * np.pi / 6), "D1": (-5 * np.pi / 3, -np.pi / 3),
              "D2": (-5 * np.pi / 3, -np.pi / 3)}
"""Yaw of the needle's x axis (tip direction). MimicGen's z_rot ranges ([-2pi/3, -pi/3] D0, [-7pi/6, pi/6] D1
and D2) rotate a needle whose tip is along its -y axis, so the tip direction is z_rot - pi/2. The D1 range is
symmetric about the table's x axis (tips towards the robot, +-120 degrees), so D2 keeps it."""
TRIPOD_X = {"D0": (0.0, 0.0), "D1": (-0.1, 0.15), "D2": (-0.1, 0.15)}
TRIPOD_Y = {"D0": (-0.15, -0.15), "D1": (-0.2, -0.1), "D2": (0.1, 0.2)}
TRIPOD_YAW = {"D0": (-np.pi / 2, -np.pi / 2), "D1": (-5 * np.pi / 6, -np.pi / 6),
              "D2": (np.pi / 6, 5 * np.pi / 6)}
"""Yaw of the ring axis. MimicGen's z_rot (pi/2 D0, [pi/6, 5pi/6] D1, [-5pi/6, -pi/6] D2) is that of a ring
whose axis points back towards the needle; ours points the other way, so it is MimicGen's + pi."""

NEEDLE_RGBA = (0.35, 0.2, 0.1, 1.0)
TRIPOD_RGBA = (0.85, 0.72, 0.5, 1.0)


def add_needle(spec: mujoco.MjSpec, name: str = "needle", density: float = 500.0) -> mujoco.MjsBody:
    """The needle: a free body (joint ``name + '_joint'``) made of a box handle and a capsule bar along +x."""
    body = spec.worldbody.add_body(name=name)
    body.add_freejoint(name=f"{name}_joint")
    body.add_geom(name=f"{name}_handle", type=mujoco.mjtGeom.mjGEOM_BOX, size=(HANDLE_HALF,) * 3,
                  rgba=NEEDLE_RGBA, density=density, friction=(1.0, 0.005, 0.0001), condim=4)
    body.add_geom(name=f"{name}_bar", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=(BAR_RADIUS, 0, 0),
                  fromto=(BAR_ROOT - BAR_RADIUS, 0, 0, NEEDLE_TIP - BAR_RADIUS, 0, 0), rgba=NEEDLE_RGBA,
                  density=density, friction=(0.3, 0.005, 0.0001))
    return body


def add_tripod(spec: mujoco.MjSpec, name: str = "tripod") -> mujoco.MjsBody:
    """The tripod: a static body whose frame is the ring frame (ring axis = x). The ring is a polygon of
    ``RING_SEGMENTS`` capsules in the body's y-z plane with an opening of radius ``RING_RADIUS``; below it a
    post, a plate and three legs reach down to the table (``RING_HEIGHT`` below the origin)."""
    body = spec.worldbody.add_body(name=name, pos=(0.0, -0.15, TABLE_TOP + RING_HEIGHT))
    apothem = RING_RADIUS + RING_TUBE
    half_len = apothem * np.tan(np.pi / RING_SEGMENTS)
    for k in range(RING_SEGMENTS):
        a = 2 * np.pi * k / RING_SEGMENTS
        centre = apothem * np.array([0.0, np.cos(a), np.sin(a)])
        along = half_len * np.array([0.0, -np.sin(a), np.cos(a)])
        body.add_geom(name=f"{name}_ring_{k}", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=(RING_TUBE, 0, 0),
                      fromto=(*(centre - along), *(centre + along)), rgba=TRIPOD_RGBA,
                      friction=(0.3, 0.005, 0.0001))
    bottom = -RING_HEIGHT  # the table, in the body frame
    post_top, post_bottom = -apothem, bottom + _PLATE_Z + 0.005
    body.add_geom(name=f"{name}_post", type=mujoco.mjtGeom.mjGEOM_BOX, rgba=TRIPOD_RGBA,
                  size=(0.005, 0.005, (post_top - post_bottom) / 2), pos=(0, 0, (post_top + post_bottom) / 2))
    body.add_geom(name=f"{name}_plate", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=(0.035, 0.005, 0),
                  pos=(0, 0, bottom + _PLATE_Z), rgba=TRIPOD_RGBA)
    for k in range(3):
        a = 2 * np.pi * k / 3 + np.pi / 3
        top = (0.02 * np.cos(a), 0.02 * np.sin(a), bottom + _PLATE_Z - 0.005)
        foot = (0.055 * np.cos(a), 0.055 * np.sin(a), bottom + _LEG_RADIUS)
        body.add_geom(name=f"{name}_leg_{k}", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=(_LEG_RADIUS, 0, 0),
                      fromto=(*top, *foot), rgba=TRIPOD_RGBA)
    return body


class ThreadingEnv(ManipulationEnv):
    """Thread a needle: grasp it by its handle and pass its tip through the small ring of a tripod.

    MimicGen's Threading task, rebuilt on raw MuJoCo. The needle is a 4 cm cube handle with a 12 cm bar
    (1 cm thick, rounded tip); the tripod holds a ring with a 2.4 cm opening (radius 1.2 cm) 19 cm above the
    table, its axis horizontal.

    ## Observation
    | key | shape | content |
    |---|---|---|
    | `token_poses` | (3, 9) | world poses: 0 = EEF (TCP), 1 = needle, 2 = tripod (ring frame) |
    | `token_features` | (3, 4) | one-hot token id (3) + gripper opening in m (EEF row only) |
    | `agent_pos` | (10,) | EEF pose (9) + gripper opening |
    | `environment_state` | (18,) | poses of the needle and the ring |
    | `pixels` | {"wrist": (84, 84, 3) uint8} | only with `obs_mode="pixels"` |

    Pose vectors are `[x, y, z, r00, r10, r20, r01, r11, r21]` (position + first two rotation columns).
    Needle pose: origin at the centre of the handle, first column = the bar's direction (handle to tip); the
    tip is 0.14 m from the origin along it. Tripod pose: origin at the ring centre, first column = the ring
    axis (horizontal; it points roughly away from the needle's starting area), third column up.

    ## Action
    (10,) float32: absolute target TCP pose (9, world frame) + gripper command in [-1 open, 1 close]. The
    rotation is orthonormalised, the position clipped to the workspace and each step rate-limited to
    3 cm / 0.3 rad.

    ## Success
    The needle's tip is more than 1 cm beyond the ring plane, within 1.2 cm of the ring axis, and the bar
    still crosses the ring: the root of the bar (where it leaves the handle) is on the other side of the plane
    and the bar meets the plane within 1.2 cm of the ring centre. Either direction through the ring counts
    (as in MimicGen, whose rule is the middle of the bar within 1.2 cm of the ring centre). The needle may
    still be held.

    ## Starting state
    The arm at its home pose, gripper open. The needle lies on the table; its position is that of its centre
    (the middle of its 16 cm length), its yaw that of its tip direction; the tripod's yaw is that of its ring
    axis. MimicGen's Threading_D0 / D1 / D2 ranges (yaws converted to these axes, see ``NEEDLE_YAW`` and
    ``TRIPOD_YAW``):

    | variant | needle x | needle y | needle yaw | tripod x | tripod y | tripod yaw |
    |---|---|---|---|---|---|---|
    | `"D0"` | [-0.2, -0.05] | [0.15, 0.25] | [-7pi/6, -5pi/6] | 0 | -0.15 | -pi/2 |
    | `"D1"` | [-0.2, 0.05] | [0.15, 0.25] | [-5pi/3, -pi/3] | [-0.1, 0.15] | [-0.2, -0.1] | [-5pi/6, -pi/6] |
    | `"D2"` | [-0.2, 0.05] | [-0.25, -0.15] | [-5pi/3, -pi/3] | [-0.1, 0.15] | [0.1, 0.2] | [pi/6, 5pi/6] |

    The needle's tip points towards the robot (D0) or anywhere within 120 degrees of that (D1, D2). D2 is D1
    mirrored left / right: needle and tripod swap sides, the ring axis turns with them (it still points away
    from the needle's side), and the needle's yaw range, symmetric under the mirror, is kept.

    ## Episode end
    Terminates on success (unless `terminate_on_success=False`); truncated after `max_episode_steps` (400).

    ## Version history
    * v0: initial release.
    * v0, issue 13: variant D2 (MimicGen's Threading_D2); D0 and D1 unchanged.
    """

    variants = ("D0", "D1", "D2")
    entity_names = ("needle", "tripod")
    task_description = "Pick up the needle by its handle and thread its tip through the ring of the tripod."

    def _build_task(self, spec: mujoco.MjSpec) -> None:
        add_needle(spec)
        add_tripod(spec)

    def _cache_refs(self) -> None:
        self.needle_id = self.model.body("needle").id
        self.tripod_id = self.model.body("tripod").id
        self.needle_geoms = self.geoms_of("needle")

    def _sample_layout(self, rng: np.random.Generator) -> None:
        v = self.variant
        tripod_xy = np.array([rng.uniform(*TRIPOD_X[v]), rng.uniform(*TRIPOD_Y[v])])
        tripod_yaw = rng.uniform(*TRIPOD_YAW[v])
        self.model.body_pos[self.tripod_id] = (*tripod_xy, TABLE_TOP + RING_HEIGHT)
        self.model.body_quat[self.tripod_id] = yaw_quat(tripod_yaw)
        centre = np.array([rng.uniform(*NEEDLE_X[v]), rng.uniform(*NEEDLE_Y[v])])
        yaw = rng.uniform(*NEEDLE_YAW[v])
        origin = centre - NEEDLE_CENTRE * np.array([np.cos(yaw), np.sin(yaw)])
        self.set_free_pose("needle_joint", np.array([*origin, TABLE_TOP + HANDLE_HALF]), yaw_quat(yaw))

    def _entity_poses(self):
        return [self.body_pose(self.needle_id), self.body_pose(self.tripod_id)]

    def needle_points(self) -> tuple[np.ndarray, np.ndarray]:
        """World positions of the bar's root (where it leaves the handle) and of the needle's tip."""
        pos, rot = self.body_pose(self.needle_id)
        return pos + BAR_ROOT * rot[:, 0], pos + NEEDLE_TIP * rot[:, 0]

    def in_ring_frame(self, point: np.ndarray) -> np.ndarray:
        """A world point in the ring frame (x along the ring axis, origin at the ring centre)."""
        centre, rot = self.body_pose(self.tripod_id)
        return rot.T @ (point - centre)

    def _check_success(self) -> bool:
        root, tip = (self.in_ring_frame(p) for p in self.needle_points())
        # Either way through the ring counts (the ring is symmetric): tip beyond the plane, root before it.
        if not (abs(tip[0]) > THROUGH and tip[0] * root[0] < 0.0):
            return False
        crossing = root + (tip - root) * (root[0] / (root[0] - tip[0]))
        return bool(np.linalg.norm(tip[1:]) < RING_RADIUS and np.linalg.norm(crossing[1:]) < RING_RADIUS)
