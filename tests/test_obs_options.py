"""The paper's observation options: Lightbulb without the socket's token (`socket_obs="none"`) and with the
socket near one pose (`socket_pose="slight"`), and MugHanging's wrist image masked to the mug once it is
grasped (`mask_after_grasp=True`); and that leaving them at their defaults changes nothing."""

from __future__ import annotations

from dataclasses import dataclass

import draccus
import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gym_actionflow import make_expert, run_episode
from gym_actionflow.geometry import pose9
from gym_actionflow.robot import WRIST_CAMERA
from gymnasium.utils.env_checker import check_env
from lerobot.envs.configs import EnvConfig

from lerobot_actionflow.env_config import ActionFlowEnvConfig

BULB = "gym_actionflow/Lightbulb-v0"
MUG = "gym_actionflow/MugHanging-v0"


def assert_same_observation(a: dict, b: dict) -> None:
    """Every key, nested ``pixels`` included, equal bit for bit (same dtype and shape)."""
    assert a.keys() == b.keys()
    for key, value in a.items():
        if isinstance(value, dict):
            assert_same_observation(value, b[key])
        else:
            assert value.dtype == b[key].dtype and value.shape == b[key].shape, key
            np.testing.assert_array_equal(value, b[key], err_msg=key)


def lockstep(env_id: str, kwargs_a: dict, kwargs_b: dict, seed: int, steps: int):
    """Two envs of one task reset with one seed and stepped with the same expert actions (the expert reads the
    first env's observation). Yields (step, obs_a, obs_b, env_a, env_b) for the reset and every step."""
    env_a = gym.make(env_id, terminate_on_success=False, **kwargs_a)
    env_b = gym.make(env_id, terminate_on_success=False, **kwargs_b)
    expert = make_expert(env_a, noise=1.0, seed=seed)
    obs_a, _ = env_a.reset(seed=seed)
    obs_b, _ = env_b.reset(seed=seed)
    expert.reset()
    try:
        for t in range(steps + 1):
            yield t, obs_a, obs_b, env_a.unwrapped, env_b.unwrapped
            action = expert.act(obs_a)
            obs_a, *_ = env_a.step(action)
            obs_b, *_ = env_b.step(action)
    finally:
        env_a.close()
        env_b.close()


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [(BULB, {"socket_obs": "none"}), (BULB, {"socket_obs": "none", "socket_pose": "slight"}),
     (MUG, {"mask_after_grasp": True})],
    ids=["Lightbulb-socket_obs-none", "Lightbulb-socket_pose-slight", "MugHanging-mask_after_grasp"],
)
def test_check_env(env_id, kwargs):
    env = gym.make(env_id, obs_mode="pixels", **kwargs)
    check_env(env.unwrapped, skip_render_check=False)
    env.close()


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [(BULB, {"socket_obs": "pose", "socket_pose": "any"}), (MUG, {"mask_after_grasp": False})],
    ids=["Lightbulb", "MugHanging"],
)
def test_options_at_their_defaults_change_nothing(env_id, kwargs):
    """Guards against an option that alters the default observations: the option given at its default and
    left out give the same observations, bit for bit, over an expert rollout through the grasp (pixels)."""
    for _, a, b, *_ in lockstep(env_id, {"obs_mode": "pixels"}, {"obs_mode": "pixels", **kwargs}, 2, 40):
        assert_same_observation(a, b)
    assert a["token_poses"].shape == (3, 9)


# ---------------------------------------------------------------- Lightbulb, socket_obs
def test_socket_obs_none_removes_only_the_socket_token():
    """Without the socket's token: one token fewer, none of them at the socket's pose, `environment_state`
    the bulb's pose (consistent with the tokens), and everything else (EEF, bulb, gripper, wrist image) as
    with the token, through an expert rollout. Guards against dropping the wrong row or a stale schema."""
    pixels = {"obs_mode": "pixels"}
    for seed in (0, 1, 2):
        for _, with_socket, without, env, bare in lockstep(
            BULB, pixels, {**pixels, "socket_obs": "none"}, seed, 30 if seed == 0 else 0
        ):
            assert bare.n_tokens == env.n_tokens - 1 == 2 and bare.entity_names == ("bulb",)
            assert bare.observation_space.contains(without)
            poses, feats = without["token_poses"], without["token_features"]
            assert (
                poses.shape == (2, 9) and feats.shape == (2, 3) and without["environment_state"].shape == (9,)
            )
            np.testing.assert_array_equal(poses, with_socket["token_poses"][:2])
            np.testing.assert_array_equal(feats[:, :2], np.eye(2, dtype=np.float32))
            assert feats[0, 2] == with_socket["token_features"][0, 3] == without["agent_pos"][9]
            np.testing.assert_array_equal(without["environment_state"], poses[1:].reshape(-1))
            np.testing.assert_array_equal(without["environment_state"], with_socket["environment_state"][:9])
            np.testing.assert_array_equal(without["agent_pos"], with_socket["agent_pos"])
            np.testing.assert_array_equal(without["pixels"]["wrist"], with_socket["pixels"]["wrist"])
            socket = pose9(*bare.body_pose(bare.socket_id)).astype(np.float32)
            np.testing.assert_array_equal(with_socket["token_poses"][2], socket)
            assert np.abs(poses - socket).max(axis=1).min() > 1e-3, "a token still sits at the socket's pose"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_expert_solves_lightbulb_without_the_socket_token(seed):
    """The success rule and the scripted expert read the socket from the simulator, not the tokens: the
    expert still seats and locks the bulb (at the recording noise), and the bulb lights up."""
    env = gym.make(BULB, obs_mode="pixels", socket_obs="none")
    episode = run_episode(env, make_expert(env, noise=1.0, seed=seed), seed)
    assert episode.success, f"seed {seed}: expert failed after {episode.steps} steps"
    base = env.unwrapped
    assert base.bulb_seated() and base.bulb_locked() and base.lit
    env.close()


# ---------------------------------------------------------------- Lightbulb, socket_pose
def test_slight_socket_pose_stays_near_one_pose_and_the_expert_still_solves_it():
    """`socket_pose="slight"` draws the socket within 1 cm of (0.05, 0) and 10 degrees of yaw 56.5 degrees
    (the layouts of "any" spread over 20 x 30 cm and every slot orientation); the expert solves it; "fixed"
    puts it at that one pose in every layout."""
    from gym_actionflow.tasks.lightbulb import SOCKET_POSES

    env = gym.make(BULB, socket_pose="slight")
    base = env.unwrapped
    xys, yaws = [], []
    for seed in range(20):
        env.reset(seed=seed)
        pos, rot = base.body_pose(base.socket_id)
        xys.append(pos[:2])
        yaws.append(np.rad2deg(np.arctan2(rot[1, 0], rot[0, 0])))
    xys, yaws = np.array(xys), np.array(yaws)
    assert np.abs(xys - [0.05, 0.0]).max() <= 0.01 + 1e-9
    assert np.abs(yaws - 56.5).max() <= 10.0 + 1e-6
    assert xys.std(axis=0).min() > 0.003 and yaws.std() > 3.0, "the slight layouts do not vary"
    assert SOCKET_POSES["any"].x == (-0.05, 0.15)  # the default layouts are today's
    episode = run_episode(env, make_expert(env, noise=1.0, seed=0), 0)
    assert episode.success and base.bulb_locked()
    env.close()
    fixed = gym.make(BULB, socket_pose="fixed")
    poses = []
    for seed in range(3):
        fixed.reset(seed=seed)
        pos, rot = fixed.unwrapped.body_pose(fixed.unwrapped.socket_id)
        poses.append(np.concatenate([pos, rot.ravel()]))
    np.testing.assert_array_equal(poses[0], poses[1])
    np.testing.assert_array_equal(poses[0], poses[2])
    np.testing.assert_allclose(poses[0][:2], [0.05, 0.0])
    fixed.close()


# ---------------------------------------------------------------- bad values
@pytest.mark.parametrize(
    ("env_id", "kwargs", "match"),
    [
        (
            BULB,
            {"socket_obs": "depth", "obs_mode": "pixels"},
            r"socket_obs='depth'; expected one of \('pose', 'none'\)",
        ),
        (BULB, {"socket_obs": None, "obs_mode": "pixels"}, r"socket_obs=None; expected one of"),
        (BULB, {"socket_obs": "none"}, r"socket_obs='none' with obs_mode='state'.*obs_mode='pixels'"),
        (BULB, {"socket_pose": "moving"}, r"socket_pose='moving'; expected one of \('any', 'slight', 'fix"),
        (MUG, {"mask_after_grasp": "yes", "obs_mode": "pixels"}, r"mask_after_grasp='yes'; expected True"),
        (MUG, {"mask_after_grasp": 1, "obs_mode": "pixels"}, r"mask_after_grasp=1; expected True"),
        (MUG, {"mask_after_grasp": True}, r"mask_after_grasp=True with obs_mode='state'.*obs_mode='pixels'"),
    ],
)
def test_bad_option_values_raise_errors_naming_the_key(env_id, kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make(env_id, **kwargs)


# ---------------------------------------------------------------- the LeRobot env config
@dataclass
class _EvalArgs:
    env: EnvConfig | None = None


def test_env_config_passes_the_options_like_lerobot_eval_parses_them():
    """`--env.socket_obs=none` / `--env.mask_after_grasp=true` reach gym.make (parsed by draccus, as
    lerobot-eval does) and size the features from the env; on another task they are refused."""
    args = [
        "--env.type=actionflow",
        "--env.task=Lightbulb-v0",
        "--env.obs_mode=pixels",
        "--env.socket_obs=none",
    ]
    config = draccus.parse(_EvalArgs, args=args).env
    assert config.gym_kwargs == {"variant": "D0", "obs_mode": "pixels", "socket_obs": "none"}
    assert config.features["token_poses"].shape == (2, 9)
    assert config.features["environment_state"].shape == (9,)
    args = ["--env.type=actionflow", "--env.task=MugHanging-v0", "--env.obs_mode=pixels"]
    config = draccus.parse(_EvalArgs, args=[*args, "--env.mask_after_grasp=true"]).env
    assert config.gym_kwargs == {"variant": "train", "obs_mode": "pixels", "mask_after_grasp": True}
    with pytest.raises(ValueError, match="--env.socket_obs is a Lightbulb option; the task is MugHanging"):
        ActionFlowEnvConfig(task="MugHanging-v0", socket_obs="none")
    with pytest.raises(
        ValueError, match="--env.mask_after_grasp is a MugHanging option; the task is Lightbulb"
    ):
        ActionFlowEnvConfig(task="Lightbulb-v0", mask_after_grasp=True)
    assert "socket_obs" not in ActionFlowEnvConfig(task="Lightbulb-v0").gym_kwargs
    config = draccus.parse(_EvalArgs, args=["--env.type=actionflow", "--env.task=Lightbulb-v0",
                                            "--env.socket_pose=slight"]).env
    assert config.gym_kwargs == {"variant": "D0", "obs_mode": "state", "socket_pose": "slight"}
    with pytest.raises(ValueError, match="--env.socket_pose is a Lightbulb option; the task is MugHanging"):
        ActionFlowEnvConfig(task="MugHanging-v0", socket_pose="slight")


# ---------------------------------------------------------------- MugHanging, mask_after_grasp
def mug_pixels(env, renderer: mujoco.Renderer) -> np.ndarray:
    """(H, W) bool: the wrist pixels whose geom is one of the mug's, by a segmentation render of our own."""
    renderer.update_scene(env.data, camera=WRIST_CAMERA)
    seg = renderer.render()  # [H, W, 2]: (object id, object type)
    return (seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)) & np.isin(seg[..., 0], sorted(env.mug_geoms))


def test_mask_after_grasp_keeps_only_the_mug_while_it_is_held():
    """Before the grasp the wrist image is the unmasked one, bit for bit; while the fingers hold the mug every
    pixel but the mug's is black and the mug's keep their colour (the non-black pixels are exactly the mug's
    geoms in a segmentation render: same count, same place); after the release the plain image is back. The
    other keys never change. Guards against masking too early, a misaligned or stale mask, and a mask that
    outlives the grasp."""
    pixels = {"obs_mode": "pixels", "variant": "train"}
    held_steps, released_after_hold = [], 0
    renderer = None
    try:
        for t, plain, masked, _, env in lockstep(MUG, pixels, {**pixels, "mask_after_grasp": True}, 0, 150):
            if renderer is None:
                renderer = mujoco.Renderer(env.model, height=env.image_size, width=env.image_size)
                renderer.enable_segmentation_rendering()
            assert_same_observation(
                {k: v for k, v in plain.items() if k != "pixels"},
                {k: v for k, v in masked.items() if k != "pixels"},
            )
            image, reference = masked["pixels"]["wrist"], plain["pixels"]["wrist"]
            if not env.mug_held():
                np.testing.assert_array_equal(image, reference)
                released_after_hold += bool(held_steps)
                continue
            held_steps.append(t)
            mug = mug_pixels(env, renderer)
            visible = image.any(axis=-1)
            assert visible.sum() == mug.sum() > 200, (
                f"step {t}: {visible.sum()} non-black, {mug.sum()} mug pixels"
            )
            np.testing.assert_array_equal(visible, mug)
            np.testing.assert_array_equal(image[mug], reference[mug])
            assert (~mug).sum() > 0.3 * mug.size, "the background should be a large part of the image"
            assert reference[~mug].any(axis=-1).mean() > 0.9, "the unmasked background is not black"
    finally:
        if renderer is not None:
            renderer.close()
    assert len(held_steps) > 40, "the expert should carry the mug for a while"
    assert held_steps == list(range(held_steps[0], held_steps[-1] + 1)), "the grasp flickered"
    assert held_steps[0] > 5 and released_after_hold > 5, "the rollout should cover before, during and after"


def test_masked_wrist_images_are_deterministic():
    """Same seed, same masked images (segmentation and the held test add no randomness)."""

    def rollout(seed: int) -> list[np.ndarray]:
        env = gym.make(MUG, obs_mode="pixels", mask_after_grasp=True)
        expert = make_expert(env, noise=1.0, seed=seed)
        obs, _ = env.reset(seed=seed)
        expert.reset()
        images = [obs["pixels"]["wrist"]]
        for _ in range(45):
            obs, *_ = env.step(expert.act(obs))
            images.append(obs["pixels"]["wrist"])
        held = env.unwrapped.mug_held()
        env.close()
        assert held, "the rollout should end with the mug in the hand"
        return images

    for a, b in zip(rollout(1), rollout(1), strict=True):
        np.testing.assert_array_equal(a, b)
