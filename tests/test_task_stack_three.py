"""Stack Three: the success rule rejects the near misses (the expert: test_experts.py)."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
from gym_actionflow.geometry import pose9
from gym_actionflow.tasks.stack_three import CUBE_HALF, StackThreeEnv


def place(env: StackThreeEnv, name: str, xy, z_bottom: float, yaw: float = 0.0) -> None:
    quat = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
    env.set_free_pose(f"{name}_joint", np.array([xy[0], xy[1], z_bottom + CUBE_HALF[name]]), quat)


def settle(env: StackThreeEnv, steps: int = 10, grip: float = -1.0) -> None:
    mujoco.mj_forward(env.model, env.data)
    pos, rot = env.tcp_pose()
    for _ in range(steps):
        env.step(np.concatenate([pose9(pos, rot), [grip]]))


def fresh_env() -> StackThreeEnv:
    env = gym.make("gym_actionflow/StackThree-v0", terminate_on_success=False).unwrapped
    env.reset(seed=0)
    return env


def test_full_stack_is_success():
    env = fresh_env()
    place(env, "cube_b", (0.1, 0.0), 0.0)
    place(env, "cube_a", (0.1, 0.0), 2 * CUBE_HALF["cube_b"])
    place(env, "cube_c", (0.1, 0.0), 2 * CUBE_HALF["cube_b"] + 2 * CUBE_HALF["cube_a"])
    settle(env)
    assert env.is_success()


def test_a_on_b_without_c_is_not_success():
    """Guards against a rule that checks only the first stacking step."""
    env = fresh_env()
    place(env, "cube_b", (0.1, 0.0), 0.0)
    place(env, "cube_a", (0.1, 0.0), 2 * CUBE_HALF["cube_b"])
    place(env, "cube_c", (-0.1, 0.1), 0.0)
    settle(env)
    assert env.stacked("cube_a", "cube_b")
    assert not env.is_success()


def test_c_on_a_beside_b_is_not_success():
    """Guards against a rule that only checks contacts: C on A with A on the table is a two-cube stack."""
    env = fresh_env()
    place(env, "cube_b", (0.1, 0.1), 0.0)
    place(env, "cube_a", (0.1, -0.1), 0.0)
    place(env, "cube_c", (0.1, -0.1), 2 * CUBE_HALF["cube_a"])
    settle(env)
    assert not env.is_success()


def test_cube_a_held_above_b_is_notstacked():
    """Holding cube A above B is not success: A must rest on B, released and touching."""
    env = fresh_env()
    place(env, "cube_b", (0.0, 0.1), 0.0)
    tcp_pos, tcp_rot = env.tcp_pose()
    # Put cube A between the open fingers, then close them and carry it over B.
    place(env, "cube_a", tcp_pos[:2], tcp_pos[2] - CUBE_HALF["cube_a"])
    settle(env, steps=8, grip=1.0)
    assert env.is_grasped(env.cube_geoms["cube_a"])
    top_of_b = 2 * CUBE_HALF["cube_b"]
    target = np.array([0.0, 0.1, top_of_b + CUBE_HALF["cube_a"] + 0.004])
    for _ in range(30):
        env.step(np.concatenate([pose9(target, tcp_rot), [1.0]]))
    assert env.is_grasped(env.cube_geoms["cube_a"])
    assert not env.stacked("cube_a", "cube_b")
    # Pressing it onto B while still holding it is not stacked either.
    target[2] -= 0.006
    for _ in range(10):
        env.step(np.concatenate([pose9(target, tcp_rot), [1.0]]))
    assert env.touching(env.cube_geoms["cube_a"], env.cube_geoms["cube_b"])
    assert not env.stacked("cube_a", "cube_b")


def test_d1_spreads_cubes_wider_than_d0():
    spread = {}
    for variant in ("D0", "D1"):
        env = gym.make("gym_actionflow/StackThree-v0", variant=variant)
        xy = np.concatenate([env.reset(seed=s)[0]["token_poses"][1:, :2] for s in range(20)])
        spread[variant] = np.abs(xy).max()
    assert spread["D0"] <= 0.10 + 1e-6
    assert 0.12 < spread["D1"] <= 0.20 + 1e-6
