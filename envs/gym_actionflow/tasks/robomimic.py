"""Robomimic's four tasks (Lift, Can, Square, Tool Hang) on robosuite's own environments, as token envs.

robosuite simulates (its Panda, its default gripper, its objects, its success checks); this module only
translates, so that these tasks speak the same token contract as every other gym_actionflow task:

* the observation: ``token_poses`` / ``token_features`` (token 0 the TCP, then one token per object),
  ``agent_pos``, ``environment_state`` and, with ``obs_mode="pixels"``, the cameras: ``wrist`` is robosuite's
  ``robot0_eye_in_hand``, ``front`` its ``agentview`` (robomimic's static camera);
* the action: the absolute TCP pose (position + two rotation columns) and a gripper command, rate-limited like
  the other tasks and tracked by robosuite's operational-space controller (``OSC_POSE``) in absolute mode, in
  the world frame.

Frames: positions are robosuite's world frame shifted down so that the table top is z = 0 (as in the rest of
the suite); the TCP frame is robosuite's grip site turned a quarter turn about its z axis, so that, as in the
other tasks, z points out of the fingers and the fingers close along y (at the start: x forward, fingers
down).

robosuite is imported only when one of these envs is made: ``import gym_actionflow`` stays free of it.
robosuite 1.5.2 pins ``mink==0.0.5`` (``numpy<2``), which LeRobot cannot share, and imports mink only inside a
``try``; ``make robosuite`` installs it without that pin (see the README).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any, ClassVar

import mujoco
import numpy as np

from gym_actionflow.geometry import rotation_log
from gym_actionflow.registry import check_choice
from gym_actionflow.robot import MAX_FINGER, PoseController, RobotRefs
from gym_actionflow.shell import CONTROL_HZ, TokenEnv

ROBOSUITE_VERSION = "1.5.2"
SITE_TO_TCP = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
"""Rotation from robosuite's grip site frame to our TCP frame (a quarter turn about z): tcp = site @ this."""
CONTROLLERS = ("ik", "osc")
"""How the pose action reaches robosuite's Panda. ``ik``: our damped-least-squares IK (as in the rest of the
suite) solves the joint targets, robosuite's ``JOINT_POSITION`` controller tracks them. ``osc``: robosuite's
``OSC_POSE`` takes the pose itself, in absolute mode; it tracks within a few millimetres, but a wrist turn of
more than about 1 rad folds the arm into joint limits (q6 at its bound), where it stalls."""
SETTLE_STEPS = 10
"""Control steps (0.5 s) run at reset, the arm holding still, so that dropped objects come to rest."""
DEFAULT_KP = {"ik": 400.0, "osc": 600.0}
"""Stiffness of robosuite's controller (its defaults: 50 for joints, 150 for OSC). Measured on a commanded
path circling 10 cm: OSC at 150 lags 16 mm and settles to 2.2 mm after 2 s, at 600 lags 7 mm and settles to
0.2 mm; IK + joint positions at 400 lags 7.7 mm (one control step) and settles to 0.04 mm."""


def import_robosuite():
    """robosuite, with its import-time notices (no private macro file, no robosuite_models, no mink) kept
    out of the user's log; a clear error when it is missing."""
    previous = logging.root.manager.disable
    logging.disable(logging.WARNING)  # robosuite sets up its logger while importing: quiet only that import
    try:
        import robosuite
    except ImportError as err:
        raise ImportError(
            f"the Robosuite* tasks need robosuite {ROBOSUITE_VERSION}, which is not installed: run `make "
            "robosuite` (or `pip install numba && pip install --no-deps "
            f"robosuite=={ROBOSUITE_VERSION}`; its mink pin would downgrade numpy below what LeRobot needs)"
        ) from err
    finally:
        logging.disable(previous)
    for name in ("robosuite_logs", "robosuite"):
        logging.getLogger(name).setLevel(logging.ERROR)
    return robosuite


class RobosuiteTaskEnv(TokenEnv):
    """One of robosuite's single-arm Panda tasks behind gym_actionflow's token observation and pose action.

    It fills the shell's simulator hooks (:mod:`gym_actionflow.shell`) with robosuite: its environment built
    once, its reset (layout and joint noise from our seed), its controller stepping, its poses read in our
    frame; a task adds ``robosuite_env``, ``_cache_refs`` and ``_entity_poses`` (success is robosuite's)."""

    robosuite_env: ClassVar[str] = ""
    """robosuite's name of the environment (``suite.make``)."""
    variants = ("D0",)
    """robosuite's own initial-state distribution, the only one."""
    workspace_low: ClassVar[np.ndarray] = np.array([-0.35, -0.45, 0.0])
    workspace_high: ClassVar[np.ndarray] = np.array([0.35, 0.45, 0.6])
    """Action targets are clipped to this box (m, our frame: table top at z = 0)."""
    render_camera = "agentview"
    camera_names: ClassVar[dict[str, str]] = {"front": "agentview", "wrist": "robot0_eye_in_hand"}

    def __init__(
        self,
        variant: str | None = None,
        obs_mode: str = "state",
        render_mode: str | None = "rgb_array",
        terminate_on_success: bool = True,
        image_size: int | None = None,
        render_size: tuple[int, int] = (240, 320),
        controller: str = "ik",
        controller_kp: float | None = None,
        obs_layout: str = "tokens",
        cameras: Sequence[str] | None = None,
    ) -> None:
        check_choice("controller", controller, CONTROLLERS)
        controller_kp = DEFAULT_KP[controller] if controller_kp is None else float(controller_kp)
        if not controller_kp > 0:
            raise ValueError(f"controller_kp={controller_kp}; expected a positive stiffness")
        self.controller_name = controller
        self.controller_kp = controller_kp
        super().__init__(
            variant, obs_mode, render_mode, terminate_on_success, image_size, render_size, obs_layout, cameras
        )

    # ------------------------------------------------------------------ simulator hooks
    def _initialize_simulation(self) -> None:
        suite = import_robosuite()
        from robosuite.controllers import load_composite_controller_config

        config = load_composite_controller_config(robot="Panda")
        arm = config["body_parts"]["right"]
        if self.controller_name == "osc":
            arm.update(input_type="absolute", input_ref_frame="world", kp=self.controller_kp)
        else:
            gripper = arm["gripper"]
            arm.clear()
            arm.update(
                type="JOINT_POSITION", input_type="absolute", kp=self.controller_kp, damping_ratio=1.0,
                impedance_mode="fixed", kp_limits=[0, 2000], damping_ratio_limits=[0, 10], input_max=1,
                input_min=-1, output_max=0.05, output_min=-0.05, qpos_limits=None, interpolation=None,
                ramp_ratio=0.2, gripper=gripper,
            )
        self.rs = suite.make(
            self.robosuite_env,
            robots="Panda",
            controller_configs=config,
            has_renderer=False,
            has_offscreen_renderer=False,
            use_camera_obs=False,
            use_object_obs=False,
            control_freq=CONTROL_HZ,
            horizon=10**9,
            ignore_done=True,
            hard_reset=False,
            reward_shaping=False,
            # robosuite draws some object sizes (Lift's cube) from this seed when it builds the model: fixed,
            # so that every env of a task has the same objects.
            seed=0,
            **self._robosuite_kwargs(),
        )
        # Observations are read from the simulator directly: robosuite's observables cost time every step.
        for name in list(self.rs._observables):
            self.rs.modify_observable(name, "enabled", False)
        self.rs.reset()
        self.model: mujoco.MjModel = self.rs.sim.model._model
        self.data: mujoco.MjData = self.rs.sim.data._data
        # Rendering as cheap as the rest of the suite's: without reflections, shadows and multisampling an
        # 84x84 wrist image costs about 20 ms instead of 90 (physics and observations are unaffected).
        self.model.vis.quality.offsamples = 0
        self.model.mat_reflectance[:] = 0.0
        self.model.light_castshadow[:] = 0
        self.table_top = self._table_top()
        self._site = self.model.site("gripper0_right_grip_site").id
        self._fingers = [self.model.joint(f"gripper0_right_finger_joint{i}").qposadr[0] for i in (1, 2)]
        joints = [self.model.joint(f"robot0_joint{i}").id for i in range(1, 8)]
        self._arm = RobotRefs(
            qpos=self.model.jnt_qposadr[joints].copy(),
            dof=self.model.jnt_dofadr[joints].copy(),
            finger_qpos=np.array(self._fingers),
            arm_ctrl=np.arange(7),
            finger_ctrl=np.arange(7, 9),
            tcp=self._site,
            lower=self.model.jnt_range[joints, 0].copy(),
            upper=self.model.jnt_range[joints, 1].copy(),
            pad_geoms=(-1, -1),
        )
        rest = np.array(self.rs.robots[0].init_qpos, dtype=float)
        self.ik = PoseController(self.model, self._arm, rest=rest)
        self._q_target = self.data.qpos[self._arm.qpos].copy()
        self._cache_refs()
        # robosuite's models keep collision shapes in geom group 0 (drawn green), looks in group 1: as its own
        # renderer, draw only the visual groups.
        self._scene_option = mujoco.MjvOption()
        self._scene_option.geomgroup[0] = 0
        self._target_pos, self._target_rot = self.tcp_pose()

    def _reset_simulation(self) -> None:
        # robosuite draws the layout and the arm's initial joint noise from its env's rng, which its placement
        # samplers share: reseed that one generator in place from ours.
        state = np.random.default_rng(self.np_random.integers(2**63)).bit_generator.state
        self.rs.rng.bit_generator.state = state
        self.rs.reset()
        # robosuite's soft reset restores positions and velocities only: clear what else the last episode left
        # in the simulator (the solver's warm start, the controls), or the same seed would not give the same
        # rollout.
        d = self.data
        for field in (d.qacc_warmstart, d.ctrl, d.qfrc_applied, d.xfrc_applied):
            field[:] = 0.0
        mujoco.mj_forward(self.model, self.data)
        self._target_pos, self._target_rot = self.tcp_pose()
        self._q_target = self.data.qpos[self._arm.qpos].copy()
        # robosuite drops its objects from a little above their resting place: let them land before the
        # first observation, the arm holding its start pose.
        hold = np.concatenate([self._target_pos, self._target_rot[:, 0], self._target_rot[:, 1], [-1.0]])
        for _ in range(SETTLE_STEPS):
            self._command(hold)

    def _step_simulation(self, pos: np.ndarray, rot: np.ndarray, grip: float) -> None:
        site_pos = pos + np.array([0.0, 0.0, self.table_top])
        site_rot = rot @ SITE_TO_TCP.T
        if self.controller_name == "osc":
            self.rs.step(np.concatenate([site_pos, rotation_log(site_rot), [grip]]))
            return
        self.rs.step(np.concatenate([self._solve_joint_targets(self.ik, site_pos, site_rot), [grip]]))

    def _to_ours(self, pos: np.ndarray) -> np.ndarray:
        return pos - np.array([0.0, 0.0, self.table_top])

    def body_pose(self, body_id: int) -> tuple[np.ndarray, np.ndarray]:
        """World pose of a body in our frame (table top at z = 0)."""
        return self._to_ours(self.data.xpos[body_id].copy()), self.data.xmat[body_id].reshape(3, 3).copy()

    def site_pose(self, site_id: int) -> tuple[np.ndarray, np.ndarray]:
        return self._to_ours(self.data.site_xpos[site_id].copy()), self.data.site_xmat[site_id].reshape(
            3, 3
        ).copy()

    def camera_frame(self, camera: str) -> tuple[np.ndarray, np.ndarray]:
        cam = self.model.camera(camera).id
        return self._to_ours(self.data.cam_xpos[cam].copy()), self.data.cam_xmat[cam].reshape(3, 3).copy()

    def tcp_pose(self) -> tuple[np.ndarray, np.ndarray]:
        pos, rot = self.site_pose(self._site)
        return pos, rot @ SITE_TO_TCP

    def gripper_opening(self) -> float:
        """Distance between the fingers in metres (0 closed, about 0.08 open)."""
        q = self.data.qpos[self._fingers]
        return float(np.clip(q[0] - q[1], 0.0, 2 * MAX_FINGER))

    def is_grasped(self, object_geoms: set[int]) -> bool:
        """robosuite's grasp check: both fingers' pads touch the object."""
        names = [self.model.geom(g).name for g in object_geoms]
        return bool(self.rs._check_grasp(gripper=self.rs.robots[0].gripper["right"], object_geoms=names))

    def _check_success(self) -> bool:
        """robosuite's own success check of the task (no side effects)."""
        return self.rs._check_success()

    # ------------------------------------------------------------------ task hooks
    def _robosuite_kwargs(self) -> dict[str, Any]:
        """Extra keywords of ``suite.make`` (default: none)."""
        return {}

    def _table_top(self) -> float:
        return float(self.rs.table_offset[2])

    def _cache_refs(self) -> None:
        """Look up the ids the task needs (default: nothing)."""


class RobosuiteLiftEnv(RobosuiteTaskEnv):
    """Lift (robomimic): pick the cube up and raise it 4 cm above the table."""

    robosuite_env = "Lift"
    entity_names = ("cube",)
    task_description = "Lift the red cube off the table."

    def _cache_refs(self) -> None:
        self.cube_id = self.model.body("cube_main").id

    def _entity_poses(self):
        return [self.body_pose(self.cube_id)]


class RobosuiteCanEnv(RobosuiteTaskEnv):
    """Can (robomimic's PickPlaceCan): move the can from the left bin into its compartment of the right bin.

    Tokens: the can and the target compartment (a fixed pose at the compartment's floor centre)."""

    robosuite_env = "PickPlaceCan"
    entity_names = ("can", "target")
    task_description = "Pick the can and place it in its compartment of the right bin."

    def _table_top(self) -> float:
        return float(self.rs.bin1_pos[2])

    def _cache_refs(self) -> None:
        self.can_id = self.model.body("Can_main").id
        self.target_pos = self._to_ours(np.array(self.rs.target_bin_placements[self.rs.object_to_id["can"]]))

    def _entity_poses(self):
        return [self.body_pose(self.can_id), (self.target_pos.copy(), np.eye(3))]


class RobosuiteSquareEnv(RobosuiteTaskEnv):
    """Square (robomimic's NutAssemblySquare): fit the square nut onto the square peg."""

    robosuite_env = "NutAssemblySquare"
    entity_names = ("nut", "peg")
    task_description = "Fit the square nut onto the square peg."

    def _cache_refs(self) -> None:
        self.nut_id = self.model.body("SquareNut_main").id
        self.peg_id = self.model.body("peg1").id
        self.handle_site = self.model.site("SquareNut_handle_site").id

    def _entity_poses(self):
        return [self.body_pose(self.nut_id), self.body_pose(self.peg_id)]


class RobosuiteToolHangEnv(RobosuiteTaskEnv):
    """Tool Hang (robomimic): insert the hook frame into the stand, then hang the tool on the frame."""

    robosuite_env = "ToolHang"
    entity_names = ("stand", "frame", "tool")
    task_description = "Insert the hook frame into the stand and hang the tool on it."
    workspace_high = np.array([0.35, 0.45, 0.7])

    def _cache_refs(self) -> None:
        self.stand_id = self.model.body("stand_root").id
        self.frame_id = self.model.body("frame_root").id
        self.tool_id = self.model.body("tool_root").id
        # For the expert: the four walls of the stand's mount hole and the frame's grip (geoms of the root
        # bodies), the frame's tip, the two ends of its hanging bar and the centre of the tool's large hole.
        self.stand_wall_geoms = [self.model.geom(f"stand_wall{i}").id for i in range(4)]
        self.frame_grip_geom = self.model.geom("frame_grip_frame").id
        self.frame_tip_site = self.model.site("frame_tip_site").id
        self.frame_hang_site = self.model.site("frame_hang_site").id
        self.frame_corner_site = self.model.site("frame_intersection_site").id
        self.tool_hole_site = self.model.site("tool_hole1_center").id

    def _entity_poses(self):
        return [self.body_pose(i) for i in (self.stand_id, self.frame_id, self.tool_id)]
