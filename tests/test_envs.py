"""Every registered gym_actionflow task: Gymnasium API, observation schema, determinism, control, errors."""

from __future__ import annotations

import subprocess
import sys

import gym_actionflow
import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gym_actionflow.base import HOME_POS, HOME_ROT, WORKSPACE_HIGH, WORKSPACE_LOW
from gym_actionflow.geometry import pose9
from gym_actionflow.registry import load
from gym_actionflow.shell import TokenEnv
from gymnasium.utils.env_checker import check_env
from scipy.spatial.transform import Rotation

SPECS = [(task.env_id, variant) for task in gym_actionflow.TASKS for variant in task.variants]
IDS = [task.env_id for task in gym_actionflow.TASKS]
OUR_SCENES = [task.env_id for task in gym_actionflow.TASKS if task.simulator == "mujoco"]
"""Tasks on our own MuJoCo scenes (ManipulationEnv); the Robosuite* tasks run robosuite's own environments."""
BY_ID = {task.env_id: task for task in gym_actionflow.TASKS}


def hold_action(obs: dict, grip: float = -1.0) -> np.ndarray:
    return np.concatenate([obs["token_poses"][0], [grip]]).astype(np.float32)


@pytest.mark.parametrize(("env_id", "variant"), SPECS, ids=[f"{i}-{v}" for i, v in SPECS])
def test_check_env(env_id, variant):
    env = gym.make(env_id, **BY_ID[env_id].kwargs(variant))
    check_env(env.unwrapped, skip_render_check=False)
    env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_tasks_fill_hooks_and_compute_success_once_per_step(env_id):
    """Guards against a task or a simulator (our scenes, robosuite) re-implementing the env shell (and
    drifting from the others): none overrides reset, step or _observation, and a step evaluates the success
    rule exactly once."""
    cls = load(BY_ID[env_id].entry_point)
    for name in ("reset", "step", "_observation", "_conclude"):
        assert getattr(cls, name) is getattr(TokenEnv, name), f"{cls.__name__} overrides {name}"
    env = gym.make(env_id).unwrapped
    obs, _ = env.reset(seed=0)
    checks = []
    rule = env._check_success
    env._check_success = lambda: checks.append(1) or rule()
    env.step(hold_action(obs))
    assert len(checks) == 1
    env.close()


def test_registry_lists_every_task():
    registered = {i for i in gym.registry if i.startswith("gym_actionflow/")}
    assert registered == set(IDS)
    for task in gym_actionflow.TASKS:
        assert gym.spec(task.env_id).max_episode_steps == task.max_episode_steps


@pytest.mark.parametrize("env_id", IDS)
def test_observation_schema(env_id):
    env = gym.make(env_id)
    obs, info = env.reset(seed=0)
    base = env.unwrapped
    n = base.n_tokens
    assert obs["token_poses"].shape == (n, 9) and obs["token_poses"].dtype == np.float32
    assert obs["token_features"].shape == (n, n + 1 + len(base.scalar_names))
    np.testing.assert_array_equal(obs["token_features"][:, :n], np.eye(n, dtype=np.float32))
    # Rotation columns are orthonormal for every token.
    c0, c1 = obs["token_poses"][:, 3:6], obs["token_poses"][:, 6:9]
    np.testing.assert_allclose(np.linalg.norm(c0, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(c1, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose((c0 * c1).sum(1), 0.0, atol=1e-5)
    # Token 0 is the EEF at the home pose, fingers down (robosuite's tasks: its own start, 20 cm above the
    # table, with its joint noise); agent_pos and environment_state are views of the tokens.
    if env_id in OUR_SCENES:
        np.testing.assert_allclose(obs["token_poses"][0, :3], HOME_POS, atol=2e-3)
    else:
        assert obs["token_poses"][0, 2] == pytest.approx(0.21, abs=0.03)
    np.testing.assert_allclose(obs["token_poses"][0, 3:].reshape(2, 3).T, HOME_ROT[:, :2], atol=0.2)
    np.testing.assert_array_equal(obs["agent_pos"][:9], obs["token_poses"][0])
    if env_id == "gym_actionflow/Lightbulb-v0":  # starts with the bulb held: gripper closed on it
        assert 0.0 < obs["agent_pos"][9] < 0.08
    else:
        assert obs["agent_pos"][9] == pytest.approx(0.08, abs=2e-3 if env_id in OUR_SCENES else 5e-3)  # open
    assert obs["token_features"][0, n] == obs["agent_pos"][9]
    np.testing.assert_array_equal(obs["environment_state"], obs["token_poses"][1:].reshape(-1))
    assert info["is_success"] is False
    # Vectorised evaluators read both from every sub-env.
    assert base.task == BY_ID[env_id].name and base.task_description.endswith(".")
    env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_same_seed_same_rollout_other_seed_other_layout(env_id):
    """Guards against hidden randomness (global RNGs, unseeded samplers): datasets must be reproducible."""

    def rollout(seed: int) -> list[np.ndarray]:
        task = BY_ID[env_id]
        env = gym.make(env_id, **task.kwargs(task.variants[-1]))
        expert = gym_actionflow.make_expert(env, noise=1.0, seed=seed)
        obs, _ = env.reset(seed=seed)
        expert.reset()
        out = [obs["token_poses"].copy()]
        for _ in range(50):
            obs, *_ = env.step(expert.act(obs))
            out.append(obs["token_poses"].copy())
        env.close()
        return out

    a, b = rollout(3), rollout(3)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    c = rollout(4)
    assert np.abs(a[0][1:] - c[0][1:]).max() > 1e-3, "another seed should give another layout"


def test_tcp_observation_matches_forward_kinematics_of_the_flange():
    """The EEF token is the TCP: 0.2354 m along the flange z axis (checked with scipy, not MuJoCo's site)."""
    env = gym.make("gym_actionflow/StackThree-v0")
    obs, _ = env.reset(seed=0)
    base = env.unwrapped
    link7 = base.model.body("panda_link7").id
    flange_rot = Rotation.from_quat(base.data.xquat[link7], scalar_first=True).as_matrix()
    expected = base.data.xpos[link7] + flange_rot @ np.array([0.0, 0.0, 0.2354])
    np.testing.assert_allclose(obs["token_poses"][0, :3], expected, atol=1e-5)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_commanded_pose_is_reached_within_1mm_and_0_01rad(seed):
    env = gym.make("gym_actionflow/StackThree-v0")
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    target_pos = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.25, 0.25), rng.uniform(0.1, 0.4)])
    tilt = Rotation.from_rotvec(rng.normal(0.0, 0.3, 3))
    target_rot = (
        tilt * Rotation.from_euler("x", np.pi) * Rotation.from_euler("z", rng.uniform(-1, 1))
    ).as_matrix()
    action = np.concatenate([pose9(target_pos, target_rot), [-1.0]])
    for _ in range(40):  # rate-limited approach, then settling
        obs, *_ = env.step(action)
    pos, rot = obs["token_poses"][0, :3], obs["token_poses"][0, 3:]
    reached = np.stack([rot[:3], rot[3:], np.cross(rot[:3], rot[3:])], axis=1)
    assert np.linalg.norm(pos - target_pos) < 1e-3
    angle = (Rotation.from_matrix(reached).inv() * Rotation.from_matrix(target_rot)).magnitude()
    assert angle < 0.01


def test_rotation_part_is_orthonormalised():
    """A scaled, skewed 6D rotation is read through Gram-Schmidt, like the policy's own conversion."""
    env = gym.make("gym_actionflow/StackThree-v0")
    obs, _ = env.reset(seed=0)
    target = np.diag([1.0, -1.0, -1.0])
    skewed = np.concatenate([HOME_POS, 3.0 * target[:, 0], 0.5 * target[:, 1] + 0.7 * target[:, 0], [-1.0]])
    for _ in range(20):
        obs, *_ = env.step(skewed)
    np.testing.assert_allclose(obs["token_poses"][0, 3:], pose9(HOME_POS, target)[3:], atol=1e-3)


def test_out_of_workspace_target_is_clipped_not_a_crash():
    env = gym.make("gym_actionflow/StackThree-v0")
    obs, _ = env.reset(seed=0)
    far = hold_action(obs)
    far[:3] = [5.0, -5.0, -1.0]
    for _ in range(30):
        obs, *_ = env.step(far)
    assert np.all(np.isfinite(obs["token_poses"]))
    commanded = env.unwrapped._target_pos
    np.testing.assert_allclose(commanded, np.clip([5.0, -5.0, -1.0], WORKSPACE_LOW, WORKSPACE_HIGH))


def test_rate_limit_cuts_large_jumps():
    env = gym.make("gym_actionflow/StackThree-v0")
    obs, _ = env.reset(seed=0)
    jump = hold_action(obs)
    jump[:3] += [0.2, 0.0, 0.0]
    env.step(jump)
    moved = env.unwrapped._target_pos - obs["token_poses"][0, :3]
    assert np.linalg.norm(moved) == pytest.approx(0.03, abs=1e-4)


@pytest.mark.parametrize(
    ("action", "match"),
    [(np.zeros(9), r"shape \(9,\); expected \(10,\)"), (np.full(10, np.nan), "NaN or inf")],
)
def test_bad_actions_raise_clear_errors(action, match):
    env = gym.make("gym_actionflow/StackThree-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        env.unwrapped.step(action)


def test_bad_kwargs_raise_clear_errors():
    with pytest.raises(ValueError, match="variant='D7'"):
        gym.make("gym_actionflow/StackThree-v0", variant="D7")
    with pytest.raises(ValueError, match="obs_mode='rgbd'"):
        gym.make("gym_actionflow/StackThree-v0", obs_mode="rgbd")


def test_make_expert_rejects_foreign_envs():
    with pytest.raises(TypeError, match="drives gym_actionflow envs|no scripted expert"):
        gym_actionflow.make_expert(gym.make("CartPole-v1"))


def test_wrist_pixels_and_front_render():
    env = gym.make("gym_actionflow/StackThree-v0", obs_mode="pixels")
    obs, _ = env.reset(seed=0)
    wrist = obs["pixels"]["wrist"]
    assert wrist.shape == (84, 84, 3) and wrist.dtype == np.uint8
    assert wrist.std() > 5, "the wrist image should show the scene, not a blank frame"
    frame = env.render()
    assert frame.shape == (240, 320, 3) and frame.dtype == np.uint8 and frame.std() > 5
    # The wrist camera moves with the hand.
    obs2, *_ = env.step(
        np.concatenate([obs["token_poses"][0] + np.r_[0.03, 0.03, -0.03, np.zeros(6)], [-1.0]])
    )
    assert np.abs(obs2["pixels"]["wrist"].astype(int) - wrist).mean() > 1.0
    env.close()


def test_terminate_on_success_is_configurable():
    env = gym.make("gym_actionflow/StackThree-v0", terminate_on_success=False)
    obs, _ = env.reset(seed=0)
    expert = gym_actionflow.make_expert(env)
    expert.reset()
    successes = 0
    for _ in range(250):
        obs, reward, terminated, truncated, info = env.step(expert.act(obs))
        assert not terminated
        successes += info["is_success"]
        assert reward == float(info["is_success"])
    assert successes > 0


def test_is_success_has_no_side_effects():
    env = gym.make("gym_actionflow/StackThree-v0")
    env.reset(seed=0)
    base = env.unwrapped
    before = base.data.qpos.copy(), base.data.qvel.copy(), base.data.time
    for _ in range(3):
        base.is_success()
    np.testing.assert_array_equal(base.data.qpos, before[0])
    np.testing.assert_array_equal(base.data.qvel, before[1])
    assert base.data.time == before[2]


def test_suite_imports_no_torch_and_no_lerobot():
    """Neither does it import robosuite unless a Robosuite* task is made."""
    code = (
        "import sys, gymnasium as gym, gym_actionflow; "
        "gym.make('gym_actionflow/StackThree-v0').reset(seed=0); "
        "gym_actionflow.make_expert(gym.make('gym_actionflow/Stack-v0')); "
        "print(sorted(m for m in ('torch', 'lerobot', 'robosuite') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_mujoco_quaternions_never_leave_the_env():
    env = gym.make("gym_actionflow/StackThree-v0")
    obs, _ = env.reset(seed=0)
    assert set(obs) == {"token_poses", "token_features", "agent_pos", "environment_state"}
    assert isinstance(env.unwrapped.model, mujoco.MjModel)


def test_viewer_cli_writes_a_gif(tmp_path, capsys):
    from gym_actionflow.__main__ import main

    main(["StackThree", "--video", str(tmp_path / "stack.gif"), "--seed", "1"])
    out = capsys.readouterr().out
    assert "seed 1: success" in out
    assert (tmp_path / "stack.gif").stat().st_size > 10_000


def test_unreachable_target_neither_flings_the_arm_nor_traps_the_ik():
    """Guards against IK branch jumps (the arm swinging off the table) and against getting stuck with the
    elbow straight at the workspace edge: after an unreachable corner, a reachable pose is reached again."""
    env = gym.make("gym_actionflow/StackThree-v0")
    env.reset(seed=0)
    down = np.diag([1.0, -1.0, -1.0])
    corner = np.concatenate([pose9(np.array([0.35, 0.4, 0.25]), down), [-1.0]])
    for _ in range(60):
        obs, *_ = env.step(corner)
        tcp = obs["token_poses"][0, :3]
        assert tcp[2] > 0.0 and tcp[0] > -0.4, f"the arm left the workspace: TCP at {tcp}"
    back = np.array([0.1, 0.0, 0.2])
    for _ in range(60):
        obs, *_ = env.step(np.concatenate([pose9(back, down), [-1.0]]))
    assert np.linalg.norm(obs["token_poses"][0, :3] - back) < 1e-3
