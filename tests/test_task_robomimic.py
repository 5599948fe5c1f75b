"""Robomimic's tasks on robosuite (gym_actionflow/Robosuite*-v0): the frames and control behind the token
contract, each success rule at its boundary (robosuite's own check, against the thresholds written out here),
and the installation. The registry-driven tests (check_env, schema, determinism, experts) cover them too."""

from __future__ import annotations

import re
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import gym_actionflow
import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gym_actionflow.experts.base import top_down
from gym_actionflow.geometry import pose9
from gym_actionflow.tasks.robomimic import ROBOSUITE_VERSION
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
ROBOSUITE_IDS = [t.env_id for t in gym_actionflow.TASKS if t.simulator == "robosuite"]


def place(env, body_id: int, pos, yaw: float = 0.0) -> None:
    """Put a free object at ``pos`` (our frame), upright with ``yaw`` and at rest, without stepping."""
    adr = env.model.jnt_qposadr[env.model.body_jntadr[body_id]]
    env.data.qpos[adr : adr + 3] = np.asarray(pos) + [0.0, 0.0, env.table_top]
    env.data.qpos[adr + 3 : adr + 7] = Rotation.from_euler("z", yaw).as_quat(scalar_first=True)
    env.data.qvel[:] = 0.0
    mujoco.mj_forward(env.model, env.data)


def test_the_four_robomimic_tasks_are_registered_on_robosuite():
    names = {t.name for t in gym_actionflow.TASKS if t.simulator == "robosuite"}
    assert names == {"RobosuiteLift", "RobosuiteCan", "RobosuiteSquare", "RobosuiteToolHang"}


@pytest.mark.parametrize("env_id", ROBOSUITE_IDS)
def test_tcp_token_is_the_suites_frame(env_id):
    """As in every gym_actionflow task: the TCP's z axis points out of the fingers, which close along its y
    axis, and it sits between the fingertips; the entity tokens are the bodies robosuite simulates."""
    env = gym.make(env_id)
    obs, _ = env.reset(seed=1)
    base = env.unwrapped
    pos, rot = obs["token_poses"][0, :3], Rotation.from_matrix(np.stack(
        [obs["token_poses"][0, 3:6], obs["token_poses"][0, 6:9],
         np.cross(obs["token_poses"][0, 3:6], obs["token_poses"][0, 6:9])], axis=1))
    left = base.data.xpos[base.model.body("gripper0_right_leftfinger").id]
    right = base.data.xpos[base.model.body("gripper0_right_rightfinger").id]
    across = (left - right) / np.linalg.norm(left - right)
    assert abs(across @ rot.as_matrix()[:, 1]) > 0.99, "the fingers should close along the TCP's y axis"
    hand = base.data.xpos[base.model.body("gripper0_right_right_gripper").id] - [0, 0, base.table_top]
    out = (pos - hand) / np.linalg.norm(pos - hand)
    assert out @ rot.as_matrix()[:, 2] > 0.99, "the TCP's z axis should point from the hand to the fingertips"
    site = base.data.site_xpos[base.model.site("gripper0_right_grip_site").id]
    np.testing.assert_allclose(pos, site - [0, 0, base.table_top], atol=1e-6)
    env.close()


@pytest.mark.parametrize(("controller", "pos_tol", "rot_tol"), [("ik", 1e-3, 0.01), ("osc", 3e-3, 0.02)])
def test_commanded_pose_is_reached(controller, pos_tol, rot_tol):
    """Either controller brings the TCP to an absolute target: IK + joint positions (the default) within 1 mm
    and 0.01 rad; robosuite's absolute OSC within 3 mm and 0.02 rad (wrist turns below 1 rad)."""
    env = gym.make("gym_actionflow/RobosuiteLift-v0", controller=controller)
    rng = np.random.default_rng(0)
    for seed in range(2):
        env.reset(seed=seed)
        target = np.array([rng.uniform(-0.15, 0.1), rng.uniform(-0.2, 0.2), rng.uniform(0.08, 0.3)])
        tilt = Rotation.from_rotvec(rng.normal(0.0, 0.15, 3))
        target_rot = (tilt * Rotation.from_matrix(top_down(rng.uniform(-0.8, 0.8)))).as_matrix()
        for _ in range(50):
            obs, *_ = env.step(np.concatenate([pose9(target, target_rot), [-1.0]]))
        reached = obs["token_poses"][0]
        assert np.linalg.norm(reached[:3] - target) < pos_tol
        r = np.stack([reached[3:6], reached[6:9], np.cross(reached[3:6], reached[6:9])], axis=1)
        assert (Rotation.from_matrix(r).inv() * Rotation.from_matrix(target_rot)).magnitude() < rot_tol
    env.close()


def test_lift_success_is_the_cube_4cm_up():
    env = gym.make("gym_actionflow/RobosuiteLift-v0").unwrapped
    env.reset(seed=0)
    for height, expected in [(0.02, False), (0.035, False), (0.045, True), (0.1, True)]:
        place(env, env.cube_id, [0.0, 0.0, height])
        assert env.is_success() is expected, f"cube centre {height} m above the table"


def test_can_success_is_the_can_in_its_compartment_and_let_go():
    env = gym.make("gym_actionflow/RobosuiteCan-v0").unwrapped
    env.reset(seed=0)
    target = env.target_pos
    # The can's compartment: x from the right bin's centre forward 19.5 cm, y from its centre outwards 24.5
    # cm, below the bin's rim (10 cm); the hand (here at its start) at least 4.2 cm away.
    cases = [
        (target + [0, 0, 0.04], True),
        (target + [-0.09, 0, 0.04], True),
        (target + [-0.105, 0, 0.04], False),  # in the neighbouring compartment
        (target + [0, -0.13, 0.04], False),
        (target + [0, 0, 0.12], False),  # above the rim
    ]
    for pos, expected in cases:
        place(env, env.can_id, pos)
        assert env.is_success() is expected, f"can at {pos - target} from its compartment's centre"


def test_square_success_is_the_nut_down_around_the_peg():
    env = gym.make("gym_actionflow/RobosuiteSquare-v0").unwrapped
    env.reset(seed=0)
    peg = env.body_pose(env.peg_id)[0]
    cases = [
        ([0.0, 0.0], 0.01, True),
        ([0.025, -0.025], 0.01, True),
        ([0.035, 0.0], 0.01, False),  # 3 cm is the tolerance of the nut's centre around the peg
        ([0.0, 0.035], 0.01, False),
        ([0.0, 0.0], 0.06, False),  # not down: 5 cm above the table is the limit
    ]
    for offset, height, expected in cases:
        place(env, env.nut_id, [peg[0] + offset[0], peg[1] + offset[1], height])
        assert env.is_success() is expected, f"nut {offset} off the peg, {height} m up"


def test_tool_hang_success_needs_the_frame_in_the_stand_and_the_tool_on_the_hook():
    """The expert's final state succeeds; the tool off the hook, or the frame out of the stand, fails."""
    env = gym.make("gym_actionflow/RobosuiteToolHang-v0")
    base = env.unwrapped
    episode = gym_actionflow.run_episode(env, gym_actionflow.make_expert(env), seed=0)
    assert episode.success
    assert base.rs._check_frame_assembled() and base.rs._check_tool_on_frame()
    state = base.data.qpos.copy()
    tool = base.model.jnt_qposadr[base.model.body_jntadr[base.tool_id]]
    base.data.qpos[tool + 2] += 0.05
    mujoco.mj_forward(base.model, base.data)
    assert not base.is_success() and base.rs._check_frame_assembled()
    base.data.qpos[:] = state
    frame = base.model.jnt_qposadr[base.model.body_jntadr[base.frame_id]]
    base.data.qpos[frame + 2] += 0.08
    mujoco.mj_forward(base.model, base.data)
    assert not base.is_success() and not base.rs._check_frame_assembled()
    env.close()


def test_pixels_show_the_wrist_camera():
    env = gym.make("gym_actionflow/RobosuiteSquare-v0", obs_mode="pixels")
    obs, _ = env.reset(seed=0)
    wrist = obs["pixels"]["wrist"]
    assert wrist.shape == (84, 84, 3) and wrist.dtype == np.uint8 and wrist.std() > 5
    assert env.observation_space.contains(obs)
    env.close()


def test_bad_controller_is_a_clear_error():
    with pytest.raises(ValueError, match="controller='joint'; expected one of"):
        gym.make("gym_actionflow/RobosuiteLift-v0", controller="joint")


def test_missing_robosuite_says_how_to_install_it():
    code = (
        "import sys; sys.modules['robosuite'] = None; import gymnasium as gym, gym_actionflow\n"
        "try:\n    gym.make('gym_actionflow/RobosuiteLift-v0')\n"
        "except ImportError as err:\n    print(err)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "make robosuite" in out and ROBOSUITE_VERSION in out


def test_the_installed_robosuite_is_the_pinned_one_beside_lerobots_numpy():
    """`make` installs robosuite without its mink pin (numpy < 2): LeRobot's numpy and robosuite coexist, on a
    MuJoCo robosuite works with (3.9.x; robosuite 1.5 breaks on 3.10)."""
    pinned = re.search(r"^ROBOSUITE := robosuite==(\S+)$", (ROOT / "Makefile").read_text(), re.M)
    assert pinned and pinned.group(1) == ROBOSUITE_VERSION == version("robosuite")
    assert int(version("numpy").split(".")[0]) >= 2
    assert version("mujoco").startswith("3.9.")
