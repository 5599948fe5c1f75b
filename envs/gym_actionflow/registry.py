"""The task table: one row per registered environment id ``gym_actionflow/<name>-v0``.

Entry points are strings, so importing gym_actionflow stays cheap: a task module is imported when used.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass


@dataclass(frozen=True)
class TaskSpec:
    name: str
    entry_point: str
    """``module:EnvClass`` of the environment."""
    expert: str
    """``module:ExpertClass`` of its scripted expert."""
    max_episode_steps: int
    variants: tuple[str, ...]
    """Initial-state distributions; the first is the default."""
    variant_kwarg: str = "variant"
    """The ``gym.make`` keyword that selects a variant (``layout`` for MugHanging)."""

    @property
    def env_id(self) -> str:
        return f"gym_actionflow/{self.name}-v0"

    def kwargs(self, variant: str) -> dict[str, str]:
        """``gym.make`` keyword arguments selecting ``variant``."""
        if variant not in self.variants:
            raise ValueError(f"{self.name} has no variant {variant!r}; expected one of {self.variants}")
        return {self.variant_kwarg: variant}


def find_task(name: str) -> TaskSpec:
    """The row of a task given by name (``Stack``), ``Name-v0`` or gym id (``gym_actionflow/Stack-v0``)."""
    for task in TASKS:
        if name in (task.name, f"{task.name}-v0", task.env_id):
            return task
    known = ", ".join(task.name for task in TASKS)
    raise ValueError(f"unknown task {name!r}; gym_actionflow has: {known}")


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
        ("D0", "D1"),
    ),
    TaskSpec(
        "Coffee",
        "gym_actionflow.tasks.coffee:CoffeeEnv",
        "gym_actionflow.experts.coffee:CoffeeExpert",
        500,
        ("D0", "D1"),
    ),
    TaskSpec(
        "Threading",
        "gym_actionflow.tasks.threading:ThreadingEnv",
        "gym_actionflow.experts.threading:ThreadingExpert",
        400,
        ("D0", "D1"),
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
        ("train", "test"),
        variant_kwarg="layout",
    ),
)
