"""Coffee (MimicGen): put the pod into the coffee machine's pod holder, then close the hinged lid."""

from __future__ import annotations

import mujoco
import numpy as np

from gym_actionflow.base import CONTACT_SOLIMP, CONTACT_SOLREF, TABLE_TOP, ManipulationEnv
from gym_actionflow.geometry import yaw_matrix, yaw_quat
from gym_actionflow.placement import Region

# ---------------------------------------------------------------- pod (free body)
POD_RADIUS = 0.02
POD_HALF_HEIGHT = 0.023
"""The pod: a cylinder 4 cm across and 4.6 cm tall (MimicGen's pod mesh is 4.6 cm tall)."""

# ---------------------------------------------------------------- machine (static fixture), holder frame
# Every machine dimension below is in the *holder frame*: origin on the holder axis at the top of the holder
# floor (where the pod's bottom rests), z up, +y pointing out of the machine (the lid's free end closes
# towards +y), x along the lid hinge.
HOLDER_FLOOR_Z = 0.14
"""Height of the holder floor above the table (m)."""
HOLDER_INNER_RADIUS = 0.025
HOLDER_OUTER_RADIUS = 0.0295
HOLDER_DEPTH = 0.048
"""Holder cup: inner radius 2.5 cm and outer 2.95 cm (MimicGen's values), 4.8 cm deep, so the pod's top rests
2 mm below the rim. The round wall is ``HOLDER_WALLS`` flat boxes (inscribed radius = inner radius)."""
HOLDER_WALLS = 12
POD_CLEARANCE = HOLDER_INNER_RADIUS - POD_RADIUS
POD_XY_TOLERANCE = POD_CLEARANCE + 0.002
"""Success: the pod axis within 7 mm of the holder axis (5 mm radial clearance + 2 mm; the 12-sided wall lets
it reach 5.9 mm)."""
LID_HALF = (0.035, 0.042, 0.006)
"""Lid plate half extents: it covers the holder when closed."""
LID_GAP = 0.001
HINGE_Y = -LID_HALF[1]
HINGE_Z = HOLDER_DEPTH + LID_GAP + LID_HALF[2]
"""The hinge axis (along x) runs through the back edge of the lid plate, mid-thickness; closed, the lid hovers
``LID_GAP`` above the rim (the joint limit holds it there)."""
LID_OPEN = 2.0 * np.pi / 3.0
"""The lid starts open at 120 degrees (MimicGen's reset value), leaning back over the machine body; gravity
holds it open there and, once it is pushed past vertical, pulls it shut."""
LID_CLOSED_MAX = np.deg2rad(15.0)
"""Success needs the lid angle below 15 degrees (MimicGen's hinge tolerance)."""
LID_DAMPING = 0.005
"""Hinge damping (N m s / rad), MimicGen's value."""
LID_LIMIT_SOLREF = CONTACT_SOLREF
"""Softness of the hinge's joint limit, which holds the closed lid above the rim: as stiff as the contacts.
MuJoCo's default (0.02 s) let the arm press the closed lid 4.7 mm into the holder rim under the adversarial
sequence (Coffee D0, seed 8); with this, under 1 mm (eval/results/envs_cpu.md). Its impedance is the contacts'
too (``CONTACT_SOLIMP``): with MuJoCo's default (0.9-0.95) the same seed, on another machine's floating point,
drove the lid 0.35 rad past the limit and 21 mm into the holder walls."""
BODY_HALF = (0.085, 0.085, 0.5 * (HINGE_Z - 0.010 + HOLDER_FLOOR_Z))
BODY_FRONT_Y = -0.05
"""The machine housing: a 17 x 17 cm box behind the holder, its top 1 cm below the hinge so the open lid
clears it."""
TRAY_HALF = (0.045, 0.05, 0.005)
FOOTPRINT_CENTER_Y = BODY_FRONT_Y - BODY_HALF[1] + TRAY_HALF[1]
"""Centre of the machine's footprint in the holder frame: the machine's placement (below) is that of this
point, as robosuite places an object by the centre of its bounding box."""

MACHINE_REGION = {
    "D0": Region((0.0, 0.0), (-0.1, -0.1), (-np.pi / 6, -np.pi / 6)),
    "D1": Region((0.05, 0.15), (-0.2, -0.1), (-np.pi / 6, np.pi / 3)),
    "D2": Region((-0.05, 0.05), (0.1, 0.2), (2 * np.pi / 3, 7 * np.pi / 6)),
}
POD_REGION = {
    "D0": Region((-0.13, -0.07), (0.17, 0.23), (0.0, 0.0)),
    "D1": Region((-0.2, 0.05), (0.17, 0.3), (0.0, 0.0)),
    "D2": Region((-0.2, 0.05), (-0.3, -0.17), (0.0, 0.0)),
}
"""MimicGen's Coffee_D0 / D1 / D2 placement bounds (machine footprint centre and yaw, pod position). D2 is D1
with the sides swapped: the machine on the robot's left, its yaw range D1's mirrored (yaw -> pi - yaw), and
5-10 cm nearer the robot (MimicGen moved it for the arm's reach); the pod on the right."""


def _add_machine(spec: mujoco.MjSpec) -> None:
    box = mujoco.mjtGeom.mjGEOM_BOX
    dark, silver, red = (0.15, 0.15, 0.16, 1), (0.75, 0.75, 0.77, 1), (0.75, 0.12, 0.1, 1)
    machine = spec.worldbody.add_body(name="machine", pos=(0.0, 0.0, TABLE_TOP + HOLDER_FLOOR_Z))
    friction = (1.0, 0.005, 0.0001)
    body_center = (0.0, BODY_FRONT_Y - BODY_HALF[1], HINGE_Z - 0.010 - BODY_HALF[2])
    machine.add_geom(name="machine_body", type=box, size=BODY_HALF, pos=body_center, rgba=dark,
                     friction=friction)
    machine.add_geom(name="machine_tray", type=box, size=TRAY_HALF,
                     pos=(0.0, BODY_FRONT_Y + TRAY_HALF[1], -HOLDER_FLOOR_Z + TRAY_HALF[2]), rgba=dark)
    # Bracket from the housing to the back of the holder cup.
    bracket_y = (BODY_FRONT_Y, -HOLDER_INNER_RADIUS - 0.002)
    bracket_half = (0.015, 0.5 * (bracket_y[1] - bracket_y[0]), 0.01)
    machine.add_geom(name="machine_bracket", type=box, size=bracket_half,
                     pos=(0.0, 0.5 * sum(bracket_y), 0.005), rgba=silver)
    # Holder cup: a floor and a ring of flat walls whose inner faces are tangent to the inner radius.
    machine.add_geom(name="holder_floor", type=box, size=(HOLDER_OUTER_RADIUS, HOLDER_OUTER_RADIUS, 0.0025),
                     pos=(0.0, 0.0, -0.0025), rgba=red, friction=friction)
    thick = 0.5 * (HOLDER_OUTER_RADIUS - HOLDER_INNER_RADIUS)
    half_len = HOLDER_OUTER_RADIUS * np.tan(np.pi / HOLDER_WALLS)
    for i in range(HOLDER_WALLS):
        a = 2 * np.pi * i / HOLDER_WALLS
        r = HOLDER_INNER_RADIUS + thick
        machine.add_geom(name=f"holder_wall{i}", type=box, size=(thick, half_len, 0.5 * HOLDER_DEPTH),
                         pos=(r * np.cos(a), r * np.sin(a), 0.5 * HOLDER_DEPTH), quat=yaw_quat(a), rgba=red,
                         friction=friction)
    lid = machine.add_body(name="lid", pos=(0.0, HINGE_Y, HINGE_Z))
    lid.add_joint(name="lid_hinge", type=mujoco.mjtJoint.mjJNT_HINGE, axis=(1, 0, 0), range=(0.0, LID_OPEN),
                  limited=mujoco.mjtLimited.mjLIMITED_TRUE, damping=LID_DAMPING, armature=1e-4,
                  solref_limit=LID_LIMIT_SOLREF, solimp_limit=CONTACT_SOLIMP)
    lid.add_geom(name="lid_plate", type=box, size=LID_HALF, pos=(0.0, LID_HALF[1], 0.0), rgba=silver,
                 density=500.0, friction=friction)
    # Visual: a knob on top of the lid.
    lid.add_geom(name="lid_knob", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=(0.008, 0.003),
                 pos=(0.0, 1.5 * LID_HALF[1], LID_HALF[2] + 0.003), rgba=dark, contype=0, conaffinity=0,
                 density=0)


class CoffeeEnv(ManipulationEnv):
    """Coffee: pick the pod, drop it into the coffee machine's pod holder, and close the machine's lid.

    MimicGen's Coffee task, rebuilt on raw MuJoCo with primitive shapes. The machine is a static fixture
    (housing, drip tray, a pod-holder cup of inner radius 2.5 cm on a bracket, 14 cm above the table) with a
    lid on a damped hinge; the pod is a free cylinder (radius 2 cm, height 4.6 cm), so it has 5 mm radial
    clearance in the holder. The lid starts open at 120 degrees, leaning back over the housing; it closes when
    pushed forward past vertical (gravity then pulls it down onto the holder). A pod that sticks out of the
    holder blocks the lid.

    ## Observation
    | key | shape | content |
    |---|---|---|
    | `token_poses` | (4, 9) | world poses: 0 = EEF (TCP), 1 = pod, 2 = machine (holder frame), 3 = lid |
    | `token_features` | (4, 6) | one-hot token id (4) + gripper opening in m (EEF) + lid angle in rad (lid) |
    | `agent_pos` | (10,) | EEF pose (9) + gripper opening |
    | `environment_state` | (27,) | poses of pod, machine, lid |
    | `pixels` | {"wrist": (84, 84, 3) uint8} | only with `obs_mode="pixels"` |

    Pose vectors are `[x, y, z, r00, r10, r20, r01, r11, r21]` (position + first two rotation columns). The
    machine token is the holder frame: origin on the holder axis at the top of the holder floor, +y pointing
    out of the machine, x along the lid hinge. The lid token is the lid body: origin on the hinge axis,
    rotating about its x axis; the lid angle is 0 when closed and 2 pi / 3 fully open.

    ## Action
    (10,) float32: absolute target TCP pose (9, world frame) + gripper command in [-1 open, 1 close]. The
    rotation is orthonormalised, the position clipped to the workspace and each step rate-limited to 3 cm /
    0.3 rad.

    ## Success
    The lid hinge angle is below 15 degrees, the pod's axis is within 7 mm of the holder axis (5 mm clearance
    + 2 mm), and the pod lies vertically between the holder floor and the underside of the lid.

    ## Starting state
    The arm at its home pose, gripper open, the lid open at 120 degrees. The pod stands upright on the table.
    MimicGen's Coffee_D0 / D1 / D2 placements (machine: the centre of its footprint, as robosuite places it):

    | variant | machine x | machine y | machine yaw | pod x | pod y |
    |---|---|---|---|---|---|
    | `"D0"` | 0 | -0.1 | -30 deg | [-0.13, -0.07] | [0.17, 0.23] |
    | `"D1"` | [0.05, 0.15] | [-0.2, -0.1] | [-30, 60] deg | [-0.2, 0.05] | [0.17, 0.3] |
    | `"D2"` | [-0.05, 0.05] | [0.1, 0.2] | [120, 210] deg | [-0.2, 0.05] | [-0.3, -0.17] |

    D2 swaps the sides of D1: the machine stands on the other side of the table (its yaw range is D1's
    mirrored, yaw -> pi - yaw, so it still faces the pod's side) and 10 cm nearer the robot, and the pod
    starts on the side the machine had. The ranges are MimicGen's unchanged.

    ## Episode end
    Terminates on success (unless `terminate_on_success=False`); truncated after `max_episode_steps` (500).

    ## Version history
    * v0: initial release.
    * v0, issue 13: variant D2 (MimicGen's Coffee_D2); D0 and D1 unchanged.
    * v0, issue 13: the lid hinge's joint limit as stiff as the contacts (``LID_LIMIT_SOLREF``), so the
      arm cannot press the closed lid into the holder rim.
    """

    variants = ("D0", "D1", "D2")
    entity_names = ("pod", "machine", "lid")
    scalar_names = ("lid_angle",)
    task_description = "Put the coffee pod into the coffee machine's pod holder, then close the lid."

    def _build_task(self, spec: mujoco.MjSpec) -> None:
        _add_machine(spec)
        pod = spec.worldbody.add_body(name="pod", pos=(0.0, 0.3, POD_HALF_HEIGHT))
        pod.add_freejoint(name="pod_joint")
        pod.add_geom(name="pod_geom", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=(POD_RADIUS, POD_HALF_HEIGHT),
                     rgba=(0.85, 0.7, 0.2, 1), density=500.0, friction=(1.0, 0.005, 0.0001), condim=4)

    def _cache_refs(self) -> None:
        m = self.model
        self.pod_id = m.body("pod").id
        self.machine_id = m.body("machine").id
        self.lid_id = m.body("lid").id
        self.lid_qpos = m.joint("lid_hinge").qposadr[0]
        self.lid_dof = m.joint("lid_hinge").dofadr[0]
        self.lid_plate = m.geom("lid_plate").id
        self.pod_geoms = self.geoms_of("pod")
        self.lid_geoms = self.geoms_of("lid")

    def _sample_layout(self, rng: np.random.Generator) -> None:
        center, yaw = MACHINE_REGION[self.variant].sample(rng)
        holder_xy = center - yaw_matrix(yaw)[:2, :2] @ np.array([0.0, FOOTPRINT_CENTER_Y])
        self.place_machine(holder_xy, yaw)
        pod_xy, pod_yaw = POD_REGION[self.variant].sample(rng)
        self.set_free_pose("pod_joint", np.array([pod_xy[0], pod_xy[1], TABLE_TOP + POD_HALF_HEIGHT]),
                           yaw_quat(pod_yaw))
        self.data.qpos[self.lid_qpos] = LID_OPEN

    def place_machine(self, holder_xy, yaw: float) -> None:
        """Move the (static) machine so the holder axis is at ``holder_xy`` with the given yaw; call
        mj_forward (or reset) afterwards."""
        self.model.body_pos[self.machine_id] = (holder_xy[0], holder_xy[1], TABLE_TOP + HOLDER_FLOOR_Z)
        self.model.body_quat[self.machine_id] = yaw_quat(yaw)

    def _entity_poses(self):
        return [self.body_pose(self.pod_id), self.body_pose(self.machine_id), self.body_pose(self.lid_id)]

    def _task_scalars(self) -> np.ndarray:
        out = np.zeros((self.n_tokens, 1))
        out[3, 0] = self.lid_angle()
        return out

    def lid_angle(self) -> float:
        """Lid hinge angle in radians: 0 closed, 2 pi / 3 fully open."""
        return float(self.data.qpos[self.lid_qpos])

    def pod_in_holder(self) -> np.ndarray:
        """Pod centre in the holder frame (3,)."""
        h_pos, h_rot = self.body_pose(self.machine_id)
        return h_rot.T @ (self.data.xpos[self.pod_id] - h_pos)

    def pod_seated(self) -> bool:
        """The pod is inside the holder: centred within the clearance, between the floor and the lid's
        underside."""
        p = self.pod_in_holder()
        h_pos = self.data.xpos[self.machine_id]
        lid_bottom = self.data.geom_xpos[self.lid_plate][2] - LID_HALF[2] - h_pos[2]
        return bool(
            np.hypot(p[0], p[1]) <= POD_XY_TOLERANCE
            and p[2] - POD_HALF_HEIGHT >= -0.002
            and p[2] + POD_HALF_HEIGHT <= lid_bottom + 0.002
        )

    def _check_success(self) -> bool:
        return self.lid_angle() < LID_CLOSED_MAX and self.pod_seated()
