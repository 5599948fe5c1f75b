"""The task table: one row per registered environment id ``gym_actionflow/<name>-v0``.

Entry points are strings, so importing gym_actionflow stays cheap: a task module is imported when used.
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import gymnasium as gym

OBS_MODES = ("state", "pixels")
"""``state``: no image; ``pixels``: the observation adds the cameras (``cameras``, default the wrist one)."""
OBS_LAYOUTS = ("tokens", "lerobot")
"""The observation's keys. ``tokens``: the token observation (``token_poses``, ``token_features``,
``agent_pos``, ``environment_state``, a task's extra keys) plus the cameras; ``lerobot``: a plain LeRobot
layout, ``agent_pos`` and the cameras only (no token keys, no object poses), with ``obs_mode="pixels"``."""
CAMERAS = ("front", "wrist")
"""The cameras an env can render under ``pixels/<name>``: ``front``, static, looking at the workspace from the
front and above; ``wrist``, on the hand (the only one before cameras could be chosen)."""
DEFAULT_CAMERAS = ("wrist",)
"""The cameras of ``obs_mode="pixels"`` when ``cameras`` is not given."""


def check_choice(name: str, value: object, choices: Sequence, context: str = "") -> None:
    """The one check of a keyword against its choices: ``variant='D7'; expected one of ('D0', 'D1')``."""
    if value not in choices:
        raise ValueError(f"{name}={value!r}; expected one of {tuple(choices)}{context}")


def check_observation(
    obs_mode: str, obs_layout: str = "tokens", cameras: Sequence[str] | None = None
) -> tuple[str, ...]:
    """The one check of the observation keywords together; returns the cameras the observation renders (none
    with ``obs_mode="state"``). Cameras are named only with ``obs_mode="pixels"`` (they would not be
    rendered otherwise), at least one, each once; the LeRobot layout needs a camera, its only view of the
    objects."""
    check_choice("obs_mode", obs_mode, OBS_MODES, " ('pixels' adds the cameras)")
    check_choice("obs_layout", obs_layout, OBS_LAYOUTS, " ('lerobot': agent_pos and the cameras only)")
    if cameras is None:
        chosen = DEFAULT_CAMERAS if obs_mode == "pixels" else ()
    else:
        if isinstance(cameras, str) or not all(isinstance(c, str) for c in cameras):
            raise ValueError(f"cameras={cameras!r}; expected a sequence of camera names from {CAMERAS}")
        chosen = tuple(cameras)
        for camera in chosen:
            if camera not in CAMERAS:
                raise ValueError(f"cameras={chosen!r} names {camera!r}; expected names from {CAMERAS}")
        if len(set(chosen)) != len(chosen):
            raise ValueError(f"cameras={chosen!r} names a camera twice; expected each at most once")
        if obs_mode != "pixels":
            raise ValueError(
                f"cameras={chosen!r} with obs_mode={obs_mode!r}: cameras are rendered with obs_mode='pixels' "
                "only; pass obs_mode='pixels' (or leave cameras out)"
            )
        if not chosen:
            raise ValueError(
                f"cameras=() with obs_mode='pixels'; expected at least one of {CAMERAS} (or obs_mode='state')"
            )
    if obs_layout == "lerobot" and obs_mode != "pixels":
        raise ValueError(
            f"obs_layout='lerobot' with obs_mode={obs_mode!r}: the LeRobot layout is agent_pos plus the "
            "cameras, its only view of the objects; pass obs_mode='pixels' (and cameras, default ('wrist',))"
        )
    return chosen


ROUND = 360
"""The symmetry of a solid of revolution about its own z axis (a pod), taken in one-degree steps."""


class Subtask(NamedTuple):
    """One object-centric subtask of a task: the token of the object its motion is relative to, and the token
    of the object the hand carries through it (None: nothing held, or nothing whose pose matters).

    ``symmetry`` and ``carried_symmetry`` say what the subtask cannot tell apart: n when the part of the
    object it acts on looks the same turned by 360/n degrees about the object's own z axis (a cube 4, a
    half-turn-symmetric piece 2, a round pod :data:`ROUND`, no symmetry 1). ``actionflow-generate`` then
    moves a segment with whichever of the object's n equivalent poses turns the hand least, as the scripted
    experts pick the nearest equivalent grasp, instead of turning the wrist with every random yaw."""

    object: str
    carried: str | None = None
    symmetry: int = 1
    carried_symmetry: int = 1


@dataclass(frozen=True)
class TaskSpec:
    name: str
    entry_point: str
    """``module:EnvClass`` of the environment."""
    expert: str
    """``module:ExpertClass`` of its scripted expert."""
    max_episode_steps: int
    variants: tuple[str, ...]
    """Initial-state distributions (the ``variant`` keyword of every task); the first is the default."""
    simulator: str = "mujoco"
    """``mujoco``: our own MjSpec scene (:class:`gym_actionflow.base.ManipulationEnv`); ``robosuite``:
    robosuite's environment behind the same token contract (:mod:`gym_actionflow.tasks.robomimic`)."""
    subtasks: tuple[Subtask, ...] = ()
    """The task's object-centric subtasks, in order: an episode is cut into them where the gripper command
    changes sign (closes on an object, opens to release it), so a task with k gripper changes has k + 1
    subtasks, the last running to the episode's end. Stack: reach and grasp cube A
    (``Subtask("cube_a", None, 4)``: a cube looks the same every quarter turn); carry it onto cube B and open
    (``Subtask("cube_b", "cube_a", 4, 4)``); leave (``Subtask("cube_b", None, 4)``).
    What ``actionflow-generate`` moves into a new layout (empty: the task cannot be generated)."""

    @property
    def env_id(self) -> str:
        return f"gym_actionflow/{self.name}-v0"

    def kwargs(
        self,
        variant: str | None = None,
        obs_mode: str | None = None,
        obs_layout: str | None = None,
        cameras: Sequence[str] | None = None,
    ) -> dict[str, Any]:
        """``gym.make`` keyword arguments selecting ``variant`` (default: the first), ``obs_mode``,
        ``obs_layout`` and ``cameras`` (default: the env's: ``state``, ``tokens``, the wrist camera with
        pixels); a value the task does not have, or a combination the env refuses, is a ValueError naming the
        keyword."""
        variant = self.variants[0] if variant is None else variant
        check_choice("variant", variant, self.variants, f" for {self.name}")
        kwargs: dict[str, Any] = {"variant": variant}
        if obs_mode is None and obs_layout is None and cameras is None:
            return kwargs
        check_observation("state" if obs_mode is None else obs_mode, obs_layout or "tokens", cameras)
        given = {
            "obs_mode": obs_mode,
            "obs_layout": obs_layout,
            "cameras": None if cameras is None else tuple(cameras),
        }
        return kwargs | {key: value for key, value in given.items() if value is not None}


def find_task(name: str) -> TaskSpec:
    """The row of a task given by name (``Stack``), ``Name-v0`` or gym id (``gym_actionflow/Stack-v0``)."""
    for task in TASKS:
        if name in (task.name, f"{task.name}-v0", task.env_id):
            return task
    known = ", ".join(task.name for task in TASKS)
    raise ValueError(f"unknown task {name!r}; gym_actionflow has: {known}")


def make_env(task: str, variant: str | None = None, **kwargs) -> gym.Env:
    """``gym.make`` of a task given by name (as :func:`find_task` reads it) on ``variant`` (default: the
    task's first) with any other env keyword: ``make_env("MugHanging", "test", mug_yaw="slight")``."""
    spec = find_task(task)
    return gym.make(spec.env_id, **spec.kwargs(variant), **kwargs)


def load(entry_point: str) -> type:
    module, _, attr = entry_point.partition(":")
    return getattr(importlib.import_module(module), attr)


_S = Subtask
TASKS: tuple[TaskSpec, ...] = (
    TaskSpec(
        "Stack",
        "gym_actionflow.tasks.stack:StackEnv",
        "gym_actionflow.experts.stack_three:StackExpert",
        200,
        ("D0", "D1"),
        subtasks=(_S("cube_a", None, 4), _S("cube_b", "cube_a", 4, 4), _S("cube_b", None, 4)),
    ),
    TaskSpec(
        "StackThree",
        "gym_actionflow.tasks.stack_three:StackThreeEnv",
        "gym_actionflow.experts.stack_three:StackThreeExpert",
        400,
        ("D0", "D1"),
        subtasks=(
            _S("cube_a", None, 4),
            _S("cube_b", "cube_a", 4, 4),
            _S("cube_c", None, 4),
            _S("cube_a", "cube_c", 4, 4),
            _S("cube_a", None, 4),
        ),
    ),
    TaskSpec(
        "ThreePieceAssembly",
        "gym_actionflow.tasks.three_piece_assembly:ThreePieceAssemblyEnv",
        "gym_actionflow.experts.three_piece_assembly:ThreePieceAssemblyExpert",
        500,
        ("D0", "D1", "D2"),
        subtasks=(
            # The socket turns a quarter; each piece's grip and seat a half (the slab fits any quarter turn).
            _S("piece_1", None, 2),
            _S("base", "piece_1", 4, 4),
            _S("piece_2", None, 2),
            _S("piece_1", "piece_2", 2, 2),
            _S("piece_1", None, 2),
        ),
    ),
    TaskSpec(
        "Coffee",
        "gym_actionflow.tasks.coffee:CoffeeEnv",
        "gym_actionflow.experts.coffee:CoffeeExpert",
        500,
        ("D0", "D1", "D2"),
        subtasks=(_S("pod", None, ROUND), _S("machine", "pod", 1, ROUND), _S("lid"), _S("machine")),
    ),
    TaskSpec(
        "Threading",
        "gym_actionflow.tasks.threading:ThreadingEnv",
        "gym_actionflow.experts.threading:ThreadingExpert",
        400,
        ("D0", "D1", "D2"),
        subtasks=(_S("needle"), _S("tripod", "needle")),
    ),
    TaskSpec(
        "Lightbulb",
        "gym_actionflow.tasks.lightbulb:LightbulbEnv",
        "gym_actionflow.experts.lightbulb:LightbulbExpert",
        300,
        ("D0",),
        subtasks=(_S("socket", "bulb", 2, 2),),  # two slots, two pins
    ),
    TaskSpec(
        "MugHanging",
        "gym_actionflow.tasks.mug_hanging:MugHangingEnv",
        "gym_actionflow.experts.mug_hanging:MugHangingExpert",
        400,
        ("train", "test", "scene_moved"),
        # The rim is gripped modulo a half turn, as the expert does; the hanging needs the handle's true pose.
        subtasks=(_S("mug", None, 2), _S("hanger", "mug"), _S("hanger")),
    ),
    # Robomimic's tasks, simulated by robosuite itself (installed by `make robosuite`; imported when made).
    TaskSpec(
        "RobosuiteLift",
        "gym_actionflow.tasks.robomimic:RobosuiteLiftEnv",
        "gym_actionflow.experts.robomimic:LiftExpert",
        200,
        ("D0",),
        "robosuite",
        # Grasp the cube, then lift it: a closing and no release.
        subtasks=(_S("cube", None, 4), _S("cube", None, 4)),
    ),
    TaskSpec(
        "RobosuiteCan",
        "gym_actionflow.tasks.robomimic:RobosuiteCanEnv",
        "gym_actionflow.experts.robomimic:CanExpert",
        400,
        ("D0",),
        "robosuite",
        # The can is round; its compartment is a fixed pose.
        subtasks=(_S("can", None, ROUND), _S("target", "can", 1, ROUND), _S("target")),
    ),
    TaskSpec(
        "RobosuiteSquare",
        "gym_actionflow.tasks.robomimic:RobosuiteSquareEnv",
        "gym_actionflow.experts.robomimic:SquareExpert",
        400,
        ("D0",),
        "robosuite",
        # The nut's handle is on one side (no symmetry for the grasp). Its square hole would fit the peg every
        # quarter turn, but taking the hole's quarter turns kept 5 of 10 generated tries against 9 of 10
        # without (seeds 100-109): a quarter-turned nut can take the hand round the peg. The episode ends on
        # the peg, before the release.
        subtasks=(_S("nut"), _S("peg", "nut")),
    ),
    TaskSpec(
        "RobosuiteToolHang",
        "gym_actionflow.tasks.robomimic:RobosuiteToolHangEnv",
        "gym_actionflow.experts.robomimic:ToolHangExpert",
        700,
        ("D0",),
        "robosuite",
        # Grasp the frame, insert it into the stand, grasp the tool, hang it on the frame's hook, back off.
        subtasks=(_S("frame"), _S("stand", "frame"), _S("tool"), _S("frame", "tool"), _S("frame")),
    ),
)
