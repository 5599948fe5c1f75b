"""Our own MuJoCo scenes: the simulator of every gym_actionflow task but robosuite's (table, Panda, control).

:class:`ManipulationEnv` fills the simulator hooks of the env shell (:class:`gym_actionflow.shell.TokenEnv`,
which owns reset, step, the observation, success and rendering, and lists the hooks every task fills:
``_entity_poses``, ``_check_success`` and the optional ones). A task on our scenes subclasses it; it never
overrides ``reset``, ``step`` or ``_observation`` (an ``__init__`` that only adds the task's own keywords is
fine), and also fills:

* ``_build_task(spec)``: add its objects and fixtures to the ``MjSpec``;
* ``_cache_refs()``: look up the ids it needs in the compiled model;
* ``_sample_layout(rng)``: place objects from ``self.np_random`` for the current ``variant``.

The simulation of one control step: IK on the rate-limited target -> joint targets (velocity-limited) ->
``SUBSTEPS`` physics steps. Of a reset: robot home -> ``_sample_layout`` -> settle one control step.
"""

from __future__ import annotations

from typing import ClassVar

import mujoco
import numpy as np

from gym_actionflow.point_cloud import look_at_xyaxes
from gym_actionflow.robot import MAX_FINGER, WRIST_CAMERA, PoseController, RobotRefs, add_panda
from gym_actionflow.shell import CONTROL_HZ, TokenEnv
from gym_actionflow.shell import POSITION_BOUND as POSITION_BOUND  # re-exported: tasks read it from here
from gym_actionflow.shell import TOKEN_EEF as TOKEN_EEF  # re-exported

SUBSTEPS = 25
TIMESTEP = 1.0 / (CONTROL_HZ * SUBSTEPS)
ROBOT_BASE = (-0.56, 0.0, 0.0)
TABLE_TOP = 0.0
"""The table top is the plane z = 0 of the world frame; the robot base stands on it at ``ROBOT_BASE``."""
WORKSPACE_LOW = np.array([-0.35, -0.40, 0.005])
WORKSPACE_HIGH = np.array([0.35, 0.40, 0.60])
"""Action targets are clipped to this box (metres, world frame)."""
HOME_POS = np.array([-0.12, 0.0, 0.30])
HOME_ROT = np.diag([1.0, -1.0, -1.0])
"""Start pose: TCP 30 cm above the table, fingers pointing down, closing along the world y axis."""
CONTACT_SOLREF = (0.004, 1.0)
CONTACT_SOLIMP = (0.95, 0.999, 0.001, 0.5, 2.0)
"""Contact softness of every geom (unless a geom sets its own). MuJoCo's default (0.02 s time constant,
impedance 0.9-0.95) lets a light object sink in proportion to the force on it: the arm pressing a 4 cm cube
pushed it 4 cm into the table. A time constant of two physics steps (the stiffest stable one, as the finger
pads') and impedance rising to 0.999 within 1 mm make the same press sink it about a millimetre, and resting
objects a few micrometres (eval/results/envs_cpu.md). Impedance 0.99 let a pressed needle sink 4.8 mm."""
FRONT_CAMERA_POS = (0.55, 0.0, 0.75)
FRONT_CAMERA_TARGET = (-0.05, 0.0, 0.10)
FRONT_CAMERA_FOVY = 45.0
"""The static ``front`` camera of the observation (``cameras=("front", ...)``): in front of the robot and
above the table, about 47 degrees down, looking at a point 10 cm above the table centre. Its view holds every
task's objects over all the variants' layouts (Stack D1's +-0.2 m, MugHanging's hanger moved 0.3 m to a
side), the arm above them and the robot's base at the top, with little background: at 80x80 a 4 cm cube is
about 5 pixels wide. ``render()`` keeps its own wider view (``overview``)."""
_HOME_SEED = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.0])


class ManipulationEnv(TokenEnv):
    """Franka Panda at a table, controlled by absolute TCP pose targets (see the task classes for details)."""

    variants = ("D0", "D1")
    workspace_low = WORKSPACE_LOW
    workspace_high = WORKSPACE_HIGH
    render_camera = "overview"
    camera_names: ClassVar[dict[str, str]] = {"front": "front", "wrist": WRIST_CAMERA}

    def _initialize_simulation(self) -> None:
        spec = self._build_scene()
        self._build_task(spec)
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self.robot = RobotRefs.from_model(self.model)
        self.controller = PoseController(self.model, self.robot)
        self.home_q = self.controller.solve(_HOME_SEED, HOME_POS, HOME_ROT)
        self.controller.rest = self.home_q.copy()
        self._cache_refs()
        self._target_pos = HOME_POS.copy()
        self._target_rot = HOME_ROT.copy()
        self._q_target = self.home_q.copy()

    def _reset_simulation(self) -> None:
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[self.robot.qpos] = self.home_q
        d.qpos[self.robot.finger_qpos] = MAX_FINGER
        d.ctrl[self.robot.arm_ctrl] = self.home_q
        d.ctrl[self.robot.finger_ctrl] = MAX_FINGER
        self._q_target = self.home_q.copy()
        self._target_pos, self._target_rot = HOME_POS.copy(), HOME_ROT.copy()
        self._sample_layout(self.np_random)
        mujoco.mj_forward(m, d)
        mujoco.mj_step(m, d, nstep=SUBSTEPS)  # let resting contacts settle

    def _step_simulation(self, pos: np.ndarray, rot: np.ndarray, grip: float) -> None:
        d = self.data
        d.ctrl[self.robot.arm_ctrl] = self._solve_joint_targets(self.controller, pos, rot)
        d.ctrl[self.robot.finger_ctrl] = MAX_FINGER * (1.0 - grip) / 2.0
        mujoco.mj_step(self.model, d, nstep=SUBSTEPS)

    # ------------------------------------------------------------------ scene
    def _build_scene(self) -> mujoco.MjSpec:
        spec = mujoco.MjSpec()
        spec.modelname = type(self).__name__
        spec.compiler.degree = False  # joint ranges and angles in radians
        spec.option.timestep = TIMESTEP
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
        spec.option.impratio = 10.0
        # Set before any geom is added, so the table, every task object and the robot inherit them.
        spec.default.geom.solref = CONTACT_SOLREF
        spec.default.geom.solimp = CONTACT_SOLIMP
        spec.visual.quality.offsamples = 0
        spec.visual.quality.shadowsize = 1024
        spec.visual.headlight.ambient = (0.35, 0.35, 0.35)
        spec.visual.headlight.diffuse = (0.5, 0.5, 0.5)
        spec.visual.global_.offwidth = 640
        spec.visual.global_.offheight = 480
        spec.add_material(name="table", rgba=(0.62, 0.5, 0.38, 1.0))
        spec.add_material(name="floor", rgba=(0.3, 0.32, 0.35, 1.0))
        world = spec.worldbody
        world.add_geom(
            name="floor",
            type=mujoco.mjtGeom.mjGEOM_PLANE,
            size=(3, 3, 0.1),
            pos=(0, 0, -0.8),
            material="floor",
        )
        world.add_geom(
            name="table",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=(0.8, 0.8, 0.4),
            pos=(0.1, 0, TABLE_TOP - 0.4),
            material="table",
            friction=(1.0, 0.005, 0.0001),
        )
        world.add_light(pos=(0, 0, 2.0), dir=(0, 0, -1), diffuse=(0.6, 0.6, 0.6), castshadow=False)
        world.add_camera(name="overview", pos=(0.62, 0.0, 0.52), xyaxes=(0, 1, 0, -0.54, 0, 0.84), fovy=55.0)
        world.add_camera(
            name="front",
            pos=FRONT_CAMERA_POS,
            xyaxes=look_at_xyaxes(FRONT_CAMERA_POS, FRONT_CAMERA_TARGET),
            fovy=FRONT_CAMERA_FOVY,
        )
        add_panda(spec, ROBOT_BASE)
        return spec

    def _build_task(self, spec: mujoco.MjSpec) -> None:
        raise NotImplementedError

    def _cache_refs(self) -> None:
        """Look up the ids the task needs after compilation (default: nothing)."""

    def _sample_layout(self, rng: np.random.Generator) -> None:
        raise NotImplementedError

    # ------------------------------------------------------------------ helpers for tasks
    def body_pose(self, body_id: int) -> tuple[np.ndarray, np.ndarray]:
        return self.data.xpos[body_id].copy(), self.data.xmat[body_id].reshape(3, 3).copy()

    def camera_frame(self, camera: str) -> tuple[np.ndarray, np.ndarray]:
        cam = self.model.camera(camera).id
        return self.data.cam_xpos[cam].copy(), self.data.cam_xmat[cam].reshape(3, 3).copy()

    def set_free_pose(self, joint_name: str, pos: np.ndarray, quat: np.ndarray) -> None:
        adr = self.model.joint(joint_name).qposadr[0]
        self.data.qpos[adr : adr + 3] = pos
        self.data.qpos[adr + 3 : adr + 7] = quat

    def touching(self, geoms_a: set[int], geoms_b: set[int]) -> bool:
        for i in range(self.data.ncon):
            c = self.data.contact[i]
            if (c.geom1 in geoms_a and c.geom2 in geoms_b) or (c.geom2 in geoms_a and c.geom1 in geoms_b):
                return True
        return False

    def is_grasped(self, object_geoms: set[int]) -> bool:
        """Both finger pads touch the object."""
        left, right = self.robot.pad_geoms
        return self.touching({left}, object_geoms) and self.touching({right}, object_geoms)

    def gripper_opening(self) -> float:
        """Distance between the finger pads in metres (0 closed, 0.08 fully open)."""
        return float(self.data.qpos[self.robot.finger_qpos].sum())

    def tcp_pose(self) -> tuple[np.ndarray, np.ndarray]:
        return self.data.site_xpos[self.robot.tcp].copy(), self.data.site_xmat[self.robot.tcp].reshape(
            3, 3
        ).copy()
