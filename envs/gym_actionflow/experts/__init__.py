"""``make_expert(env)``: the scripted expert of any gym_actionflow task."""

from __future__ import annotations

import gymnasium as gym

from gym_actionflow.experts.base import Episode, ScriptedExpert, run_episode
from gym_actionflow.registry import TASKS, load

__all__ = ["Episode", "ScriptedExpert", "make_expert", "run_episode"]


def make_expert(env: gym.Env, noise: float = 0.0, seed: int | None = None) -> ScriptedExpert:
    """The scripted expert for ``env`` (a gym_actionflow env, wrapped or not).

    Call ``expert.reset()`` after each ``env.reset()``, then ``expert.act(obs)`` for each step. ``noise``
    scales waypoint offsets and action jitter (0: deterministic); ``seed`` seeds that noise.
    """
    base = env.unwrapped
    key = f"{type(base).__module__}:{type(base).__name__}"
    for task in TASKS:
        if task.entry_point == key:
            return load(task.expert)(env, noise=noise, seed=seed)
    known = ", ".join(task.name for task in TASKS)
    raise TypeError(f"no scripted expert for {type(base).__name__}; gym_actionflow has experts for: {known}")
