"""gym_actionflow: fast MuJoCo manipulation tasks with token-structured observations.

>>> import gymnasium as gym, gym_actionflow
>>> env = gym.make("gym_actionflow/StackThree-v0", variant="D1")
>>> expert = gym_actionflow.make_expert(env)

Every observation has ``token_poses`` (N, 9) and ``token_features`` (N, F), token 0 being the end effector;
the action is an absolute end-effector pose (9) plus a gripper command. No torch, no LeRobot.
"""

from __future__ import annotations

import os

# Offscreen rendering without a display: MuJoCo picks its GL backend when first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

from gymnasium.envs.registration import register  # noqa: E402

from gym_actionflow.experts import make_expert, run_episode  # noqa: E402
from gym_actionflow.registry import TASKS, find_task  # noqa: E402

__all__ = ["TASKS", "find_task", "make_expert", "run_episode"]
__version__ = "0.1.0"

for _task in TASKS:
    register(
        id=f"gym_actionflow/{_task.name}-v0",
        entry_point=_task.entry_point,
        max_episode_steps=_task.max_episode_steps,
    )
