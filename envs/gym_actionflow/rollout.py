"""The one closed-loop episode runner of the suite: reset, then act until the time limit or termination.

Every tool that runs an episode calls :func:`rollout`: the scripted experts (recording), the policy
visualiser, the benchmarks and the diagnostics. Only ``lerobot-eval`` runs its own loop (LeRobot's).

    episode = rollout(env, policy_fn, seed=100_000, on_step=lambda obs, action: frames.append(obs))
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gymnasium as gym
import numpy as np


@dataclass(frozen=True)
class Episode:
    """Outcome of one episode."""

    success: bool
    steps: int
    terminated: bool
    last_reward: float
    last_info: dict


def rollout(
    env: gym.Env,
    act: Callable[[dict], np.ndarray],
    seed: int | None = None,
    *,
    options: dict | None = None,
    on_reset: Callable[[dict, dict], None] | None = None,
    on_frame: Callable[[np.ndarray], None] | None = None,
    on_step: Callable[[dict, np.ndarray], None] | None = None,
    after_step: Callable[[dict, float, bool, bool, dict], None] | None = None,
    max_steps: int | None = None,
) -> Episode:
    """Reset ``env`` with ``seed`` and call ``act(observation) -> action (10,)`` until the episode ends.

    ``env`` should come from ``gym.make`` (its time limit ends every episode); ``max_steps`` ends it earlier.
    Hooks, all optional: ``on_reset(obs, info)`` once after the reset (an expert reads the fresh state there),
    ``on_frame(env.render())`` before each step (videos), ``on_step(obs, action)`` with each observation and
    the action taken from it (datasets), ``after_step(next_obs, reward, terminated, truncated, info)``.
    """
    obs, info = env.reset(seed=seed, options=options)
    if on_reset is not None:
        on_reset(obs, info)
    steps, terminated, truncated, reward = 0, False, False, 0.0
    while not (terminated or truncated):
        if max_steps is not None and steps >= max_steps:
            break
        if on_frame is not None:
            on_frame(env.render())
        action = act(obs)
        if on_step is not None:
            on_step(obs, action)
        obs, reward, terminated, truncated, info = env.step(action)
        if after_step is not None:
            after_step(obs, float(reward), bool(terminated), bool(truncated), info)
        steps += 1
    return Episode(bool(info.get("is_success", False)), steps, bool(terminated), float(reward), info)
