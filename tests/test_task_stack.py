"""Stack: the success rule rejects the near misses (the expert: test_experts.py)."""

from __future__ import annotations

import gym_actionflow
import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gym_actionflow.geometry import pose9
from gym_actionflow.tasks.stack import StackEnv
from gym_actionflow.tasks.stack_three import CUBE_HALF


def test_scene_has_two_cubes_only():
    env = gym.make("gym_actionflow/Stack-v0").unwrapped
    obs, _ = env.reset(seed=0)
    assert obs["token_poses"].shape == (3, 9)
    with pytest.raises(KeyError):
        env.model.body("cube_c")
    env.close()


def fresh_env() -> StackEnv:
    env = gym.make("gym_actionflow/Stack-v0", terminate_on_success=False).unwrapped
    env.reset(seed=0)
    return env


def place(env: StackEnv, name: str, xy, z_bottom: float) -> None:
    env.set_free_pose(
        f"{name}_joint", np.array([xy[0], xy[1], z_bottom + CUBE_HALF[name]]), np.array([1.0, 0, 0, 0])
    )


def settle(env: StackEnv, steps: int = 10) -> None:
    mujoco.mj_forward(env.model, env.data)
    pos, rot = env.tcp_pose()
    for _ in range(steps):
        env.step(np.concatenate([pose9(pos, rot), [-1.0]]))


def test_a_on_b_is_success():
    env = fresh_env()
    place(env, "cube_b", (0.1, 0.0), 0.0)
    place(env, "cube_a", (0.1, 0.0), 2 * CUBE_HALF["cube_b"])
    settle(env)
    assert env.is_success()


def test_a_beside_b_is_not_success():
    """Guards against a rule that only checks contact: A pushed against B's side, both on the table."""
    env = fresh_env()
    place(env, "cube_b", (0.1, 0.0), 0.0)
    place(env, "cube_a", (0.1, CUBE_HALF["cube_b"] + CUBE_HALF["cube_a"]), 0.0)
    settle(env)
    assert not env.is_success()


def test_a_held_above_b_is_not_success():
    """Guards against counting a cube that is still in the hand: the expert holds A over B just before it
    opens the gripper."""
    env = gym.make("gym_actionflow/Stack-v0", terminate_on_success=False)
    expert = gym_actionflow.make_expert(env)
    obs, _ = env.reset(seed=0)
    expert.reset()
    base = env.unwrapped
    for _ in range(200):
        action = expert.act(obs)
        if action[9] < 0 and base.is_grasped(base.cube_geoms["cube_a"]):
            break  # the expert is about to release A over B
        obs, *_ = env.step(action)
    else:
        pytest.fail("the expert never released A")
    a, b = (base.data.xpos[base.cube_ids[n]] for n in ("cube_a", "cube_b"))
    assert np.linalg.norm(a[:2] - b[:2]) < 0.01 and a[2] > b[2]
    assert not base.is_success()
    env.close()


def test_starting_ranges_are_mimicgens():
    """Cube centres start within MimicGen's Stack ranges: +-0.08 m in D0 (narrower than Stack Three's
    +-0.10 m, which Stack once inherited) and +-0.20 m in D1, each range filled, not a smaller square."""
    for variant, half in (("D0", 0.08), ("D1", 0.20)):
        env = gym.make("gym_actionflow/Stack-v0", variant=variant)
        xy = np.concatenate([env.reset(seed=s)[0]["token_poses"][1:, :2] for s in range(30)])
        assert np.abs(xy).max() <= half + 1e-6, variant
        assert np.abs(xy).max() > 0.8 * half, variant
        env.close()
