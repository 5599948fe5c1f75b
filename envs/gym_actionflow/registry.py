"""The task table: one row per registered environment id ``gym_actionflow/<name>-v0``.

Entry points are strings, so importing gym_actionflow stays cheap: a task module is imported when used.
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from dataclasses import dataclass

import gymnasium as gym

OBS_MODES = ("state", "pixels")
"""``state``: token observations; ``pixels``: the same plus the wrist camera."""


def check_choice(name: str, value: object, choices: Sequence, context: str = "") -> None:
    """The one check of a keyword against its choices: ``variant='D7'; expected one of ('D0', 'D1')``."""
    if value not in choices:
        raise ValueError(f"{name}={value!r}; expected one of {tuple(choices)}{context}")


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

    @property
    def env_id(self) -> str:
        return f"gym_actionflow/{self.name}-v0"

    def kwargs(self, variant: str | None = None, obs_mode: str | None = None) -> dict[str, str]:
        """``gym.make`` keyword arguments selecting ``variant`` (default: the first) and ``obs_mode``
        (default: the env's, ``state``); a value the task does not have is a ValueError naming the choices."""
        variant = self.variants[0] if variant is None else variant
        check_choice("variant", variant, self.variants, f" for {self.name}")
        if obs_mode is None:
            return {"variant": variant}
        check_choice("obs_mode", obs_mode, OBS_MODES)
        return {"variant": variant, "obs_mode": obs_mode}


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


TASKS: tuple[TaskSpec, ...] = (
    TaskSpec(
        "Stack",
        "gym_actionflow.tasks.stack:StackEnv",
        "gym_actionflow.experts.stack_three:StackExpert",
        200,
        ("D0", "D1"),
    ),
    TaskSpec(
        "StackThree",
        "gym_actionflow.tasks.stack_three:StackThreeEnv",
        "gym_actionflow.experts.stack_three:StackThreeExpert",
        400,
        ("D0", "D1"),
    ),
    TaskSpec(
        "ThreePieceAssembly",
        "gym_actionflow.tasks.three_piece_assembly:ThreePieceAssemblyEnv",
        "gym_actionflow.experts.three_piece_assembly:ThreePieceAssemblyExpert",
        500,
        ("D0", "D1", "D2"),
    ),
    TaskSpec(
        "Coffee",
        "gym_actionflow.tasks.coffee:CoffeeEnv",
        "gym_actionflow.experts.coffee:CoffeeExpert",
        500,
        ("D0", "D1", "D2"),
    ),
    TaskSpec(
        "Threading",
        "gym_actionflow.tasks.threading:ThreadingEnv",
        "gym_actionflow.experts.threading:ThreadingExpert",
        400,
        ("D0", "D1", "D2"),
    ),
    TaskSpec(
        "Lightbulb",
        "gym_actionflow.tasks.lightbulb:LightbulbEnv",
        "gym_actionflow.experts.lightbulb:LightbulbExpert",
        300,
        ("D0",),
    ),
    TaskSpec(
        "MugHanging",
        "gym_actionflow.tasks.mug_hanging:MugHangingEnv",
        "gym_actionflow.experts.mug_hanging:MugHangingExpert",
        400,
        ("train", "test", "scene_moved"),
    ),
    # Robomimic's tasks, simulated by robosuite itself (installed by `make robosuite`; imported when made).
    TaskSpec(
        "RobosuiteLift",
        "gym_actionflow.tasks.robomimic:RobosuiteLiftEnv",
        "gym_actionflow.experts.robomimic:LiftExpert",
        200,
        ("D0",),
        "robosuite",
    ),
    TaskSpec(
        "RobosuiteCan",
        "gym_actionflow.tasks.robomimic:RobosuiteCanEnv",
        "gym_actionflow.experts.robomimic:CanExpert",
        400,
        ("D0",),
        "robosuite",
    ),
    TaskSpec(
        "RobosuiteSquare",
        "gym_actionflow.tasks.robomimic:RobosuiteSquareEnv",
        "gym_actionflow.experts.robomimic:SquareExpert",
        400,
        ("D0",),
        "robosuite",
    ),
    TaskSpec(
        "RobosuiteToolHang",
        "gym_actionflow.tasks.robomimic:RobosuiteToolHangEnv",
        "gym_actionflow.experts.robomimic:ToolHangExpert",
        700,
        ("D0",),
        "robosuite",
    ),
)
