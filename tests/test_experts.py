"""Every registered task's scripted expert solves fixed seeds: guards against a task or expert change that
silently breaks demonstration recording. One test over the registry; each task's near misses (what must not
count as success) stay in its own test file."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np
import pytest
from gym_actionflow import TASKS, make_expert, run_episode
from gym_actionflow.experts.base import CLOSE, OPEN, top_down

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


def _run(plan) -> tuple[list, object]:
    """Every action of a script generator, and what it returned."""
    out: dict = {}

    def driver():
        out["result"] = yield from plan

    return list(driver()), out["result"]


@pytest.mark.parametrize(("held_on", "tries", "n_actions"), [(2, 2, 1 + 6 + 1), (None, 3, 3 * (1 + 6))])
def test_a_missed_grasp_is_retried_with_the_fingers_open(held_on, tries, n_actions):
    """Guards the one grasp-and-retry loop the experts share: each miss opens the fingers before the next try,
    a hold ends the tries, there are at most three, and the last try's result (its grasp rotation) comes
    back to the script."""
    env = gym.make("gym_actionflow/Stack-v0")
    env.reset(seed=0)
    expert = make_expert(env)
    expert.reset()
    grip_at_start = []

    def attempt():
        grip_at_start.append(expert.grip)
        expert.grip = CLOSE
        yield expert._action()
        return len(grip_at_start)

    actions, result = _run(expert.grasp_until_held(attempt, held=lambda: len(grip_at_start) == held_on))
    assert grip_at_start == [OPEN] * tries and result == tries and len(actions) == n_actions
    assert expert.grip == (CLOSE if held_on else OPEN)
    env.close()


def test_grasp_closes_on_the_pose_and_lifts():
    """Guards the grasp building block: it ends closed, straight above the grasp (``lift`` over it or at the
    height ``lift_z``), and asks for exactly one of the two."""
    env = gym.make("gym_actionflow/Stack-v0")
    env.reset(seed=0)
    expert = make_expert(env)
    expert.reset()
    pos, rot = np.array([0.05, 0.02, 0.02]), top_down(0.3)
    _run(expert.grasp(pos, rot, lift=0.1))
    assert expert.grip == CLOSE
    np.testing.assert_allclose(expert.cmd_pos, pos + [0, 0, 0.1], atol=1e-12)
    _run(expert.grasp(pos, rot, lift_z=0.2))
    np.testing.assert_allclose(expert.cmd_pos, [0.05, 0.02, 0.2], atol=1e-12)
    for bad in ({}, {"lift": 0.1, "lift_z": 0.2}):
        with pytest.raises(ValueError, match="one of lift"):
            _run(expert.grasp(pos, rot, **bad))
    env.close()
