"""The env shell every gym_actionflow task shares, whatever simulates it: the token contract, the argument
checks, the reset and step skeletons, success, rendering.

Two simulators fill it, each for its family of tasks: :class:`gym_actionflow.base.ManipulationEnv` (our own
MjSpec scenes) and :class:`gym_actionflow.tasks.robomimic.RobosuiteTaskEnv` (robosuite's environments). So the
observation keys and bounds, the action and its limits, when success is computed and what ``info`` says are
written once, here, and cannot drift between the two. A simulator fills (as robosuite's ``RobotEnv`` fills
``MujocoEnv``'s ``_load_model`` / ``_reset_internal`` / ``_pre_action``):

* ``_initialize_simulation()``: build or load the simulator (``model``, ``data``), the robot's references, the
  command state (``_target_pos``, ``_target_rot``, ``_q_target``) and the task's ids;
* ``_reset_simulation()``: the robot at its start, the layout drawn from ``self.np_random``, the scene
  settled, the command state back at the start pose;
* ``_step_simulation(pos, rot, grip)``: track the (clipped, rate-limited) TCP target and gripper command for
  one control step;
* ``tcp_pose()``, ``gripper_opening()``, ``body_pose(body_id)``, ``camera_frame(camera)``,
  ``is_grasped(geoms)``: read the simulator in the suite's frame (table top at z = 0);
* ``camera_names``: which simulator camera each of the suite's cameras is (``front``, static, and ``wrist``,
  on the hand: :data:`gym_actionflow.registry.CAMERAS`).

A task fills ``_entity_poses()`` (the world pose of each non-EEF token, in ``entity_names`` order) and
``_check_success()`` (free of side effects), and may fill the optional hooks (default: nothing):

* ``_task_scalars()``: per-token task scalars, named by ``scalar_names`` (a lid angle...);
* ``_after_reset()``: after the layout is placed and the scene settled, before the first observation (let a
  held object settle in the hand, clear a counter);
* ``_after_physics()``: once per control step, right after the physics and before the success check (advance
  a counter the success rule reads);
* ``_show_success(success)``: show the task state in the scene before the observation renders (a lit bulb);
* ``_extra_observation_spaces()`` / ``_extra_observation()``: observation keys beyond the tokens (a point
  cloud; none in the LeRobot layout, which refuses an env whose options add one);
* ``_camera_image(camera)``: a camera's image of ``obs_mode="pixels"`` (default: as rendered; a task may mask
  it, ``_geom_ids`` tells which geom each pixel shows).

The observation's keys follow ``obs_layout`` (:data:`gym_actionflow.registry.OBS_LAYOUTS`): ``tokens`` (the
default) is the token observation, plus ``pixels/<camera>`` for the ``cameras`` chosen with
``obs_mode="pixels"`` (default: the wrist camera); ``lerobot`` is ``agent_pos`` and the cameras only, a plain
LeRobot dataset's ``observation.state`` and ``observation.images.*``. :attr:`TokenEnv.camera_poses` says
where each camera is, for a policy that places images in space.

One control step: action -> clip, rate limit -> ``_step_simulation`` -> ``_after_physics`` -> success
(computed once) -> ``_show_success`` -> observation. A reset: ``_reset_simulation`` -> ``_after_reset`` ->
success -> ``_show_success`` -> observation. Nobody overrides ``reset``, ``step`` or ``_observation``.
"""

from __future__ import annotations

import atexit
import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from gym_actionflow.geometry import (
    axis_angle_matrix,
    gram_schmidt,
    matrix_to_quat,
    pose9,
    rotation_angle,
    rotation_log,
)
from gym_actionflow.registry import CAMERAS, check_choice, check_observation
from gym_actionflow.robot import MAX_FINGER, PoseController

CONTROL_HZ = 20
MAX_STEP_POS = 0.03
MAX_STEP_ROT = 0.3
"""Rate limit of the commanded TCP target per control step (m, rad): larger jumps are cut short."""
MAX_JOINT_STEP = np.array([2.175] * 4 + [2.61] * 3) / CONTROL_HZ
"""Cap on the per-step change of the arm joint targets: Panda joint velocity limits (rad/s) over 50 ms."""
POSITION_BOUND = 5.0
SCALAR_BOUND = 10.0
"""Observation-space bounds: positions within 5 m of the table centre, task scalars within +-10."""
TOKEN_EEF = "eef"
"""The name of token 0, the end effector (TCP), in every task's ``token_names``."""


def _close_renderers(renderers: dict[str, mujoco.Renderer]) -> None:
    for renderer in renderers.values():
        renderer.close()
    renderers.clear()


# ---------------------------------------------------------------------- the token contract
# Every gym_actionflow env, whatever simulates it (our MuJoCo scenes or robosuite's environments), speaks
# through these functions: the same observation keys and bounds, the same action and its limits.


_POSE_HIGH = np.array([POSITION_BOUND] * 3 + [1.0] * 6, dtype=np.float32)


def _state_space() -> spaces.Box:
    """``agent_pos``: the TCP pose (9) and the gripper opening (0 .. 2 * MAX_FINGER m)."""
    high = np.concatenate([_POSE_HIGH, [2 * MAX_FINGER]]).astype(np.float32)
    low = np.concatenate([-_POSE_HIGH, [0.0]]).astype(np.float32)
    return spaces.Box(low, high, dtype=np.float32)


def _camera_spaces(cameras: Mapping[str, tuple[int, int, int]]) -> dict[str, spaces.Space]:
    """``pixels``: one (H, W, 3) uint8 image per camera, or no key without cameras."""
    if not cameras:
        return {}
    return {
        "pixels": spaces.Dict(
            {name: spaces.Box(0, 255, shape, dtype=np.uint8) for name, shape in cameras.items()}
        )
    }


def token_observation_space(
    n_tokens: int,
    n_scalars: int,
    extra: dict[str, spaces.Space] | None = None,
    cameras: Mapping[str, tuple[int, int, int]] | None = None,
) -> spaces.Dict:
    """``token_poses`` (N, 9), ``token_features`` (N, N + 1 + n_scalars), ``agent_pos`` (10,),
    ``environment_state`` (9 (N - 1),), the task's ``extra`` keys and each of ``cameras`` (name: (H, W, 3))
    under ``pixels/<name>``."""
    n = n_tokens
    feat_high = np.concatenate([np.ones(n), [2 * MAX_FINGER], np.full(n_scalars, SCALAR_BOUND)])
    feat_low = np.concatenate([np.zeros(n + 1), np.full(n_scalars, -SCALAR_BOUND)])
    return spaces.Dict(
        {
            "token_poses": spaces.Box(
                -np.tile(_POSE_HIGH, (n, 1)), np.tile(_POSE_HIGH, (n, 1)), dtype=np.float32
            ),
            "token_features": spaces.Box(
                np.tile(feat_low, (n, 1)).astype(np.float32),
                np.tile(feat_high, (n, 1)).astype(np.float32),
                dtype=np.float32,
            ),
            "agent_pos": _state_space(),
            "environment_state": spaces.Box(
                -np.tile(_POSE_HIGH, n - 1), np.tile(_POSE_HIGH, n - 1), dtype=np.float32
            ),
            **(extra or {}),
            **_camera_spaces(cameras or {}),
        }
    )


def lerobot_observation_space(cameras: Mapping[str, tuple[int, int, int]]) -> spaces.Dict:
    """The LeRobot layout: ``agent_pos`` (10,) and each of ``cameras`` (name: (H, W, 3)) under
    ``pixels/<name>``; no token keys, no object poses."""
    return spaces.Dict({"agent_pos": _state_space(), **_camera_spaces(cameras)})


def agent_pos(tcp: tuple[np.ndarray, np.ndarray], opening: float) -> np.ndarray:
    """(10,) float32: the TCP pose vector and the gripper opening, the same numbers in every layout."""
    return np.concatenate([pose9(*tcp).astype(np.float32), [opening]]).astype(np.float32)


def token_observation(
    tcp: tuple[np.ndarray, np.ndarray],
    entities: list[tuple[np.ndarray, np.ndarray]],
    opening: float,
    scalars: np.ndarray,
) -> dict[str, np.ndarray]:
    """The token keys of an observation: token 0 is the TCP, then one token per entity; each token's feature
    is its one-hot index, the gripper opening (EEF token only) and the task scalars."""
    n = 1 + len(entities)
    poses = np.empty((n, 9), dtype=np.float32)
    poses[0] = pose9(*tcp)
    for i, (p, r) in enumerate(entities, start=1):
        poses[i] = pose9(p, r)
    scalars = np.asarray(scalars)
    feats = np.zeros((n, n + 1 + scalars.shape[1]), dtype=np.float32)
    feats[np.arange(n), np.arange(n)] = 1.0
    feats[0, n] = opening
    feats[:, n + 1 :] = scalars
    return {
        "token_poses": poses,
        "token_features": feats,
        "agent_pos": agent_pos(tcp, opening),
        "environment_state": poses[1:].reshape(-1).copy(),
    }


def subtree_geoms(model: mujoco.MjModel, body_name: str) -> set[int]:
    """Ids of every geom in the body ``body_name`` and its descendants."""
    root = model.body(body_name).id
    ids = set()
    for g in range(model.ngeom):
        b = model.geom_bodyid[g]
        while b not in (0, root):
            b = model.body_parentid[b]
        if b == root:
            ids.add(g)
    return ids


def pose_action_space(low: np.ndarray, high: np.ndarray) -> spaces.Box:
    """The action: target TCP position within [low, high] (m), two rotation columns, gripper command."""
    return spaces.Box(
        np.concatenate([low, -np.ones(6), [-1.0]]).astype(np.float32),
        np.concatenate([high, np.ones(6), [1.0]]).astype(np.float32),
        dtype=np.float32,
    )


def parse_pose_action(action, low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(position clipped to [low, high], rotation by Gram-Schmidt, gripper in [-1, 1]) of a 10-d action; a
    wrong shape or a NaN is a ValueError saying what was expected."""
    a = np.asarray(action, dtype=np.float64)
    if a.shape != (10,):
        raise ValueError(
            f"action has shape {a.shape}; expected (10,): target TCP pose [x, y, z, r00, r10, r20, r01, "
            "r11, r21] in the world frame + gripper command in [-1 open, 1 close]"
        )
    if not np.all(np.isfinite(a)):
        raise ValueError(f"action contains NaN or inf: {np.array2string(a, precision=4)}")
    return np.clip(a[:3], low, high), gram_schmidt(a[3:6], a[6:9]), float(np.clip(a[9], -1.0, 1.0))


def rate_limit(
    prev_pos: np.ndarray, prev_rot: np.ndarray, pos: np.ndarray, rot: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The target (pos, rot) cut to at most ``MAX_STEP_POS`` and ``MAX_STEP_ROT`` from the previous one."""
    delta = pos - prev_pos
    dist = np.linalg.norm(delta)
    if dist > MAX_STEP_POS:
        pos = prev_pos + delta * (MAX_STEP_POS / dist)
    rel = rotation_log(prev_rot.T @ rot)
    angle = np.linalg.norm(rel)
    if angle > MAX_STEP_ROT:
        rot = prev_rot @ axis_angle_matrix(rel * (MAX_STEP_ROT / angle))
    return pos, rot


@dataclass(frozen=True, eq=False)
class CameraPose:
    """Where a camera is, for a policy that places each image where it was taken.

    ``frame="world"``: a static camera; ``position`` / ``rotation`` are its pose in the world frame (table top
    at z = 0). ``frame="eef"``: a camera on the hand; they are its fixed pose in the TCP frame that
    ``agent_pos`` reports (z out of the fingers, which close along y), so its world pose is the TCP pose times
    this one (:meth:`world_pose`).

    The pose is that of MuJoCo's camera frame: the camera looks along its -z axis, x points to the image's
    right and y to the image's top (OpenGL's convention; OpenCV's camera frame, x right, y down, z forward,
    is this one turned half a turn about its x axis). ``fovy`` is the vertical field of view in degrees: an
    (H, W) image has square pixels, a focal length of (H / 2) / tan(fovy / 2) pixels and its principal point
    at the centre.
    """

    frame: str
    """``world`` (static camera) or ``eef`` (on the hand, relative to the TCP)."""
    position: np.ndarray
    """(3,) metres."""
    rotation: np.ndarray
    """(3, 3): the camera's axes (columns) in the reference frame."""
    fovy: float

    def pose9(self) -> np.ndarray:
        """The pose vector ``[x, y, z, r00, r10, r20, r01, r11, r21]`` (the suite's convention)."""
        return pose9(self.position, self.rotation)

    def quaternion(self) -> np.ndarray:
        """The rotation as a unit quaternion (w, x, y, z), for configs that spell a pose that way."""
        return matrix_to_quat(self.rotation)

    def world_pose(self, tcp: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """The camera's world (position, rotation) when the TCP is at ``tcp`` (ignored by a world camera)."""
        if self.frame == "world":
            return self.position.copy(), self.rotation.copy()
        pos, rot = tcp
        return pos + rot @ self.position, rot @ self.rotation


class TokenEnv(gym.Env):
    """A Panda task behind the token observation and the absolute pose action (see the module docstring for
    the hooks a simulator and a task fill)."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": CONTROL_HZ}
    entity_names: ClassVar[tuple[str, ...]] = ()
    scalar_names: ClassVar[tuple[str, ...]] = ()
    variants: ClassVar[tuple[str, ...]] = ("D0",)
    """Initial-state distributions (``variant=``); the first is the default."""
    task_description: ClassVar[str] = ""
    default_image_size: ClassVar[int] = 84
    """Side of the square wrist image when ``image_size`` is not given."""
    workspace_low: ClassVar[np.ndarray]
    workspace_high: ClassVar[np.ndarray]
    """Action targets are clipped to this box (m, the suite's world frame: table top at z = 0)."""
    render_camera: ClassVar[str]
    """The simulator camera of ``render()``."""
    camera_names: ClassVar[dict[str, str]]
    """The simulator camera of each of the suite's cameras (``pixels/<name>``): every name of
    :data:`gym_actionflow.registry.CAMERAS`. A camera on the world body is static (``frame="world"`` in
    :attr:`camera_poses`); any other must sit on the hand, rigidly with the TCP (``frame="eef"``)."""
    _scene_option: mujoco.MjvOption | None = None
    """What the renderers draw (None: MuJoCo's defaults)."""

    # The command state the shell's step updates; the simulator sets it at initialisation and reset.
    _target_pos: np.ndarray
    _target_rot: np.ndarray
    _q_target: np.ndarray

    def __init__(
        self,
        variant: str | None = None,
        obs_mode: str = "state",
        render_mode: str | None = "rgb_array",
        terminate_on_success: bool = True,
        image_size: int | None = None,
        render_size: tuple[int, int] = (240, 320),
        obs_layout: str = "tokens",
        cameras: Sequence[str] | None = None,
    ) -> None:
        variant = self.variants[0] if variant is None else variant
        check_choice("variant", variant, self.variants, f" for {type(self).__name__}")
        self.cameras = check_observation(obs_mode, obs_layout, cameras)
        """The cameras of the observation, in the order given (none with ``obs_mode="state"``)."""
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode={render_mode!r}; only 'rgb_array' (or None) is supported")
        self.variant = variant
        self.obs_mode = obs_mode
        self.obs_layout = obs_layout
        self.render_mode = render_mode
        self.terminate_on_success = terminate_on_success
        self.image_size = int(self.default_image_size if image_size is None else image_size)
        self.render_size = tuple(render_size)
        self._renderers: dict[str, mujoco.Renderer] = {}
        self._exit_hook: Callable[[], None] | None = None

        self._initialize_simulation()
        self._camera_poses = self._measure_camera_poses()

        self.feature_dim = self.n_tokens + 1 + len(self.scalar_names)
        images = {name: (self.image_size, self.image_size, 3) for name in self.cameras}
        extra = self._extra_observation_spaces()
        if obs_layout == "lerobot" and extra:
            raise ValueError(
                f"obs_layout='lerobot' observes agent_pos and the cameras only, but this "
                f"{type(self).__name__}'s options add {sorted(extra)} (e.g. hanger_obs='point_cloud'); leave "
                "those options at their defaults, or use obs_layout='tokens'"
            )
        if obs_layout == "lerobot":
            self.observation_space = lerobot_observation_space(images)
        else:
            self.observation_space = token_observation_space(
                self.n_tokens, len(self.scalar_names), extra, images
            )
        self.action_space = pose_action_space(self.workspace_low, self.workspace_high)

    # ------------------------------------------------------------------ simulator hooks
    def _initialize_simulation(self) -> None:
        raise NotImplementedError

    def _reset_simulation(self) -> None:
        raise NotImplementedError

    def _step_simulation(self, pos: np.ndarray, rot: np.ndarray, grip: float) -> None:
        raise NotImplementedError

    def tcp_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The TCP's world pose: z out of the fingers, which close along y."""
        raise NotImplementedError

    def gripper_opening(self) -> float:
        """Distance between the fingers in metres (0 closed, about 0.08 fully open)."""
        raise NotImplementedError

    def body_pose(self, body_id: int) -> tuple[np.ndarray, np.ndarray]:
        """World pose (position, rotation matrix) of a body."""
        raise NotImplementedError

    def camera_frame(self, camera: str) -> tuple[np.ndarray, np.ndarray]:
        """World pose (position, rotation matrix) of a simulator camera's frame (MuJoCo's: looking along -z,
        y up) in the current state."""
        raise NotImplementedError

    def is_grasped(self, object_geoms: set[int]) -> bool:
        """Both fingers' pads touch the object."""
        raise NotImplementedError

    # ------------------------------------------------------------------ task hooks
    def _entity_poses(self) -> list[tuple[np.ndarray, np.ndarray]]:
        raise NotImplementedError

    def _check_success(self) -> bool:
        raise NotImplementedError

    def _task_scalars(self) -> np.ndarray:
        """(n_tokens, len(scalar_names)) task scalars, e.g. a lid angle on the machine token."""
        return np.zeros((self.n_tokens, len(self.scalar_names)))

    def _after_reset(self) -> None:
        """After the layout is placed and the scene settled, before the first observation (default: none)."""

    def _after_physics(self) -> None:
        """Once per control step, after the physics, before the success check (default: nothing)."""

    def _show_success(self, success: bool) -> None:
        """Show the task state in the scene before the observation renders (default: nothing)."""

    def _extra_observation_spaces(self) -> dict[str, spaces.Space]:
        """Spaces of the observation keys the task adds beyond the tokens (default: none)."""
        return {}

    def _extra_observation(self) -> dict[str, np.ndarray]:
        """Values of the keys of :meth:`_extra_observation_spaces` for the current state."""
        return {}

    def _camera_image(self, camera: str) -> np.ndarray:
        """The image of one of the suite's cameras (``front``, ``wrist``) in the observation, (image_size,
        image_size, 3) uint8 (default: as rendered)."""
        return self._render_camera(self.camera_names[camera], self.image_size, self.image_size)

    # ------------------------------------------------------------------ helpers for tasks
    @property
    def task(self) -> str:
        """The task's name (``Stack``, ``Coffee``...); ``task_description`` is the instruction in words.

        Vectorised evaluators (LeRobot's ``lerobot-eval``) read both attributes from every sub-env."""
        return type(self).__name__.removesuffix("Env")

    @property
    def camera_poses(self) -> dict[str, CameraPose]:
        """Where each of the suite's cameras is (every name of :data:`gym_actionflow.registry.CAMERAS`, chosen
        or not): the static ``front`` camera's world pose, the ``wrist`` camera's fixed pose in the TCP frame
        (see :class:`CameraPose` for the frames and MuJoCo's camera convention). Constant for an env."""
        return dict(self._camera_poses)

    def _measure_camera_poses(self) -> dict[str, CameraPose]:
        """Read the cameras' poses from the simulator at initialisation, its kinematics computed for the
        model's initial state (a reset starts from scratch, so this changes no episode). A hand camera's pose
        relative to the TCP is the same in every arm pose: the tests check it at several."""
        mujoco.mj_forward(self.model, self.data)
        poses = {}
        tcp_pos, tcp_rot = self.tcp_pose()
        for name in CAMERAS:
            cam = self.model.camera(self.camera_names[name])
            pos, rot = self.camera_frame(cam.name)
            if self.model.cam_bodyid[cam.id] == 0:
                poses[name] = CameraPose("world", pos, rot, float(cam.fovy[0]))
            else:
                offset = (tcp_rot.T @ (pos - tcp_pos), tcp_rot.T @ rot)
                poses[name] = CameraPose("eef", *offset, float(cam.fovy[0]))
        return poses

    @property
    def n_tokens(self) -> int:
        return 1 + len(self.entity_names)

    @property
    def token_names(self) -> tuple[str, ...]:
        """Which row of ``token_poses`` / ``token_features`` is which entity: ``eef`` (token 0, the TCP), then
        ``entity_names`` in order. A recorder writes them into the dataset, so its rows say what they are."""
        return (TOKEN_EEF, *self.entity_names)

    def object_poses(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """World pose (position (3,), rotation (3, 3)) of each entity by its token name, as ``token_poses``
        holds them after the EEF, whatever the observation layout."""
        return dict(zip(self.entity_names, self._entity_poses(), strict=True))

    def geoms_of(self, body_name: str) -> set[int]:
        """Ids of every geom in a body and its descendants."""
        return subtree_geoms(self.model, body_name)

    def _solve_joint_targets(self, ik: PoseController, pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """The arm's next joint targets toward (pos, rot) of ``ik``'s frame, each joint moved by at most
        ``MAX_JOINT_STEP`` from the last targets (so an IK branch switch can never fling the arm); kept in
        ``_q_target``."""
        q = ik.solve(self._q_target, pos, rot)
        self._q_target = self._q_target + np.clip(q - self._q_target, -MAX_JOINT_STEP, MAX_JOINT_STEP)
        return self._q_target

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._reset_simulation()
        self._after_reset()
        obs, success = self._conclude()
        return obs, {"is_success": success}

    def step(self, action):
        self._command(action)
        self._after_physics()
        obs, success = self._conclude()
        terminated = bool(success and self.terminate_on_success)
        return obs, float(success), terminated, False, {"is_success": success}

    def _command(self, action) -> None:
        """One control step of ``action``: its target clipped to the workspace, rate-limited from the last
        one, then tracked by the simulator (the physics of the step)."""
        pos, rot, grip = parse_pose_action(action, self.workspace_low, self.workspace_high)
        pos, rot = rate_limit(self._target_pos, self._target_rot, pos, rot)
        self._target_pos, self._target_rot = pos, rot
        self._step_simulation(pos, rot, grip)

    def _conclude(self) -> tuple[dict[str, Any], bool]:
        """The end of a reset or a step: success computed once, shown in the scene, then the observation."""
        success = self.is_success()
        self._show_success(success)
        return self._observation(), success

    def is_success(self) -> bool:
        """The task's success rule on the current state (no side effects)."""
        return bool(self._check_success())

    def _observation(self) -> dict[str, Any]:
        if self.obs_layout == "lerobot":
            obs = {"agent_pos": agent_pos(self.tcp_pose(), self.gripper_opening())}
        else:
            obs = token_observation(
                self.tcp_pose(), self._entity_poses(), self.gripper_opening(), self._task_scalars()
            )
            obs.update(self._extra_observation())
        if self.cameras:
            obs["pixels"] = {name: self._camera_image(name) for name in self.cameras}
        return obs

    # ------------------------------------------------------------------ rendering
    def _renderer(
        self, height: int, width: int, depth: bool = False, segmentation: bool = False
    ) -> mujoco.Renderer:
        """A cached offscreen renderer of this size and kind (RGB, depth or segmentation), freed by close() or
        at exit."""
        if depth and segmentation:
            raise ValueError("a renderer renders depth or segmentation, not both")
        key = f"{'depth' if depth else 'segmentation' if segmentation else 'rgb'}:{height}x{width}"
        renderer = self._renderers.get(key)
        if renderer is None:
            try:
                renderer = mujoco.Renderer(self.model, height=height, width=width)
            except mujoco.FatalError as err:
                raise RuntimeError(
                    f"offscreen rendering failed ({err}). Set MUJOCO_GL=egl (or osmesa) in the environment, "
                    "or import gym_actionflow before mujoco, so MuJoCo picks a headless GL backend."
                ) from err
            if depth:
                renderer.enable_depth_rendering()
            if segmentation:
                renderer.enable_segmentation_rendering()
            self._renderers[key] = renderer
            if self._exit_hook is None:
                # Free GL contexts at exit before MuJoCo's own EGL shutdown hook (registered earlier, so it
                # runs later), even when close() is never called; otherwise EGL errors are printed at exit.
                self._exit_hook = functools.partial(_close_renderers, self._renderers)
                atexit.register(self._exit_hook)
        return renderer

    def _render_camera(self, camera: str, height: int, width: int) -> np.ndarray:
        renderer = self._renderer(height, width)
        renderer.update_scene(self.data, camera=camera, scene_option=self._scene_option)
        return renderer.render().copy()

    def _geom_ids(self, camera: str, height: int, width: int) -> np.ndarray:
        """(height, width) int32: the id of the geom each pixel of ``camera``'s image shows, -1 where none
        (the background). Pixel-aligned with :meth:`_render_camera` of the same size (MuJoCo's segmentation
        rendering, a separate cached renderer)."""
        renderer = self._renderer(height, width, segmentation=True)
        renderer.update_scene(self.data, camera=camera, scene_option=self._scene_option)
        seg = renderer.render()  # [H, W, 2]: (object id, object type) per pixel, (-1, -1) for the background
        return np.where(seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), seg[..., 0], -1).astype(np.int32)

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            return None
        return self._render_camera(self.render_camera, *self.render_size)

    def close(self) -> None:
        _close_renderers(self._renderers)
        if self._exit_hook is not None:
            atexit.unregister(self._exit_hook)
            self._exit_hook = None

    # ------------------------------------------------------------------ diagnostics
    def tracking_error(self) -> tuple[float, float]:
        """(position m, rotation rad) between the commanded target and the TCP."""
        pos, rot = self.tcp_pose()
        return float(np.linalg.norm(pos - self._target_pos)), rotation_angle(rot, self._target_rot)
