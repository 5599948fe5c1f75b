"""Every registered task's scripted expert solves fixed seeds: guards against a task or expert change that
silently breaks demonstration recording. One test over the registry; each task's near misses (what must not
count as success) stay in its own test file."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import pytest
from gym_actionflow import TASKS, make_expert, run_episode

D012 = [(variant, seed, 0.0) for variant in ("D0", "D1", "D2") for seed in (0, 1, 2)]
CASES: dict[str, list[tuple[str, int, float]]] = {
    # task: (variant, seed, expert noise); the expert is seeded with the episode's seed.
    "Stack": [(variant, seed, 1.0) for variant in ("D0", "D1") for seed in (0, 1, 2)],
    "StackThree": [(variant, seed, 0.0) for variant in ("D0", "D1") for seed in (0, 1, 2)],
    # D2 (MimicGen's widest layouts) also once at the recording noise.
    "ThreePieceAssembly": [*D012, ("D2", 3, 1.0)],
    "Coffee": [*D012, ("D2", 3, 1.0)],
    "Threading": [*D012, ("D2", 3, 1.0)],
    "Lightbulb": [("D0", seed, noise) for noise in (0.0, 1.0) for seed in (0, 1, 2)],
    # Test seeds 0 and 1 put the hanger on the right and on the left side of the table.
    "MugHanging": [("train", 0, 0.0), ("train", 1, 1.0), ("test", 0, 0.0), ("test", 1, 1.0),
                   ("scene_moved", 2, 1.0)],
    # robosuite's tasks: once deterministic, twice at the recording noise.
    **{name: [("D0", 0, 0.0), ("D0", 1, 1.0), ("D0", 2, 1.0)]
       for name in ("RobosuiteLift", "RobosuiteCan", "RobosuiteSquare", "RobosuiteToolHang")},
}
MAX_STEPS = {"Threading": 300}
"""Episode length the expert must stay within, where tighter than the task's ``max_episode_steps``."""
FINAL_STATE: dict[str, Callable] = {
    "Lightbulb": lambda env: env.bulb_seated() and env.bulb_locked() and env.lit,
}
"""What else must hold when the episode ends (on the unwrapped env)."""

PARAMS = [
    pytest.param(task, variant, seed, noise, id=f"{task.name}-{variant}-seed{seed}-noise{noise:g}")
    for task in TASKS
    for variant, seed, noise in CASES.get(task.name, [])
]


def test_every_registered_task_has_expert_cases():
    assert set(CASES) == {task.name for task in TASKS}


def test_every_registered_variant_has_expert_cases():
    """Guards against a variant added to the registry whose expert no test runs."""
    for task in TASKS:
        assert set(task.variants) <= {variant for variant, _, _ in CASES[task.name]}, task.name


@pytest.mark.parametrize(("task", "variant", "seed", "noise"), PARAMS)
def test_expert_solves_fixed_seeds(task, variant, seed, noise):
    env = gym.make(task.env_id, **task.kwargs(variant))
    _, info = env.reset(seed=seed)
    assert not info["is_success"], "the task starts solved"
    episode = run_episode(env, make_expert(env, noise=noise, seed=seed), seed)
    assert episode.success, f"{task.name} {variant} seed {seed}: expert failed after {episode.steps} steps"
    assert episode.terminated and episode.last_reward == 1.0
    assert episode.steps <= MAX_STEPS.get(task.name, task.max_episode_steps)
    if task.name in FINAL_STATE:
        assert FINAL_STATE[task.name](env.unwrapped)
    env.close()
