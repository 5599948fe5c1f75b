"""Physics a real Panda could produce, every task: no sinking objects, no warnings, real limits."""

from __future__ import annotations

import gym_actionflow
import gymnasium as gym
import numpy as np
import pytest
from gym_actionflow.adversarial import resting_penetration, run_adversarial
from gym_actionflow.robot import ARM_JOINTS, FINGER_JOINTS

OUR_SCENES = [task for task in gym_actionflow.TASKS if task.simulator == "mujoco"]
"""Our own scenes; the Robosuite* tasks keep robosuite's physics as it is."""
SPECS = [(task, variant, 0) for task in OUR_SCENES for variant in task.variants]
PAST_FAILURES = [(gym_actionflow.find_task("Coffee"), "D0", 8)]
"""(task, variant, adversarial seed) cases that once broke the bound: Coffee D0 seed 8 pressed the closed lid
4.7 mm into the holder rim while the lid hinge's joint limit had MuJoCo's soft default solreflimit."""
CASES = SPECS + PAST_FAILURES
SINK_BOUND = 0.003
"""Deepest allowed penetration between two scene geoms under any actions (m)."""
REST_BOUND = 0.0005
"""Deepest allowed penetration of objects lying still (m)."""


@pytest.mark.parametrize(
    ("task", "variant", "seed"), CASES, ids=[f"{t.name}-{v}-seed{s}" for t, v, s in CASES]
)
def test_adversarial_actions_neither_sink_objects_nor_break_the_simulation(task, variant, seed):
    """Guards against contacts (or joint limits) soft enough, or an arm strong enough, to press objects into
    the table or each other: 300 steps of random poses, huge values and the hand pressed down onto every
    object keep the state finite, raise no MuJoCo warning and keep every object-table and object-object
    contact within 3 mm."""
    env = gym.make(task.env_id, **task.kwargs(variant)).unwrapped
    report = run_adversarial(env, seed=seed, steps=300)
    env.close()
    assert report.finite, "qpos, qvel or the observation became NaN/inf"
    assert not report.warnings, f"MuJoCo warnings: {report.warnings}"
    assert report.worst_penetration < SINK_BOUND, f"an object sank {1000 * report.worst_penetration:.2f} mm"


@pytest.mark.parametrize("task", OUR_SCENES, ids=[t.name for t in OUR_SCENES])
def test_objects_at_rest_barely_penetrate(task):
    """Guards against objects resting visibly inside the table (MuJoCo's default contacts: ~0.1-0.2 mm)."""
    env = gym.make(task.env_id).unwrapped
    worst = max(resting_penetration(env, seed=seed) for seed in range(2))
    env.close()
    assert worst < REST_BOUND, f"resting objects penetrate {1000 * worst:.3f} mm"


def test_actuator_limits_are_the_pandas():
    """Guards against servos stronger than the real robot: 87 N m on joints 1-4, 12 N m on 5-7 (datasheet)
    and a hand that squeezes with at most 70 N."""
    model = gym.make("gym_actionflow/Stack-v0").unwrapped.model
    arm = np.array([model.actuator(name).forcerange[1] for name in ARM_JOINTS])
    np.testing.assert_array_equal(arm, [87.0] * 4 + [12.0] * 3)
    for name in (*ARM_JOINTS, *FINGER_JOINTS):
        assert model.actuator(name).forcelimited and model.actuator(name).forcerange[0] == -model.actuator(
            name
        ).forcerange[1]
    fingers = [model.actuator(name).forcerange[1] for name in FINGER_JOINTS]
    assert fingers == [70.0, 70.0]
