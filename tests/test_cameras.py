"""The cameras and the plain LeRobot layout: the static front camera sees the task's objects, each camera's
pose is where MuJoCo renders from, ``obs_layout="lerobot"`` observes ``agent_pos`` and the cameras only (and
records as a plain LeRobotDataset with the cameras' poses), and the new keywords left out change nothing."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import draccus
import gymnasium as gym
import numpy as np
import pytest
from gym_actionflow import make_expert
from gym_actionflow.experts.base import top_down
from gym_actionflow.geometry import pose9, pose9_to_rt
from gymnasium.utils.env_checker import check_env
from lerobot.envs.configs import EnvConfig

from lerobot_actionflow import schema
from lerobot_actionflow.env_config import ActionFlowEnvConfig
from lerobot_actionflow.tools.record import load_recipe, main, record

ROOT = Path(__file__).resolve().parents[1]
STACK = "gym_actionflow/Stack-v0"
LEROBOT = {"obs_mode": "pixels", "obs_layout": "lerobot", "cameras": ("front", "wrist"), "image_size": 80}
BOOKKEEPING = {"timestamp", "frame_index", "episode_index", "index", "task_index"}


def assert_same_observation(a: dict, b: dict) -> None:
    """Every key, nested ``pixels`` included, equal bit for bit (same dtype and shape)."""
    assert a.keys() == b.keys()
    for key, value in a.items():
        if isinstance(value, dict):
            assert_same_observation(value, b[key])
        else:
            assert value.dtype == b[key].dtype and value.shape == b[key].shape, key
            np.testing.assert_array_equal(value, b[key], err_msg=key)


def lockstep(kwargs_a: dict, kwargs_b: dict, seed: int, steps: int):
    """Two Stack envs reset with one seed and stepped with the same expert actions (read from the first env's
    observation, which must have the tokens). Yields (obs_a, obs_b) for the reset and every step."""
    env_a, env_b = gym.make(STACK, **kwargs_a), gym.make(STACK, **kwargs_b)
    expert = make_expert(env_a, noise=1.0, seed=seed)
    obs_a, _ = env_a.reset(seed=seed)
    obs_b, _ = env_b.reset(seed=seed)
    try:
        for _ in range(steps + 1):
            yield obs_a, obs_b
            action = expert.act(obs_a)
            obs_a, *_ = env_a.step(action)
            obs_b, *_ = env_b.step(action)
    finally:
        env_a.close()
        env_b.close()


def project(camera, point: np.ndarray, size: int) -> tuple[float, float]:
    """(column, row) of a world point in a square ``size`` image of a world camera, from its pose and field of
    view alone (MuJoCo's convention: the camera looks along its -z axis, x right, y up; row 0 at the top)."""
    local = camera.rotation.T @ (point - camera.position)
    focal = (size / 2) / np.tan(np.radians(camera.fovy) / 2)
    return size / 2 + focal * local[0] / -local[2], size / 2 - focal * local[1] / -local[2]


def move_arm(env, offset, yaw: float, steps: int = 40) -> dict:
    """Hold a top-down TCP target ``offset`` from the start pose at ``yaw`` for ``steps`` steps."""
    obs, _ = env.reset(seed=0)
    start = obs["agent_pos"][:3].astype(np.float64)
    for _ in range(steps):
        obs, *_ = env.step(np.concatenate([pose9(start + np.asarray(offset), top_down(yaw)), [-1.0]]))
    return obs


# ---------------------------------------------------------------------------- the observation
def test_lerobot_layout_with_both_cameras_passes_check_env():
    """Guards against a LeRobot layout that still carries token keys or object poses, or whose space and
    observations disagree."""
    env = gym.make(STACK, **LEROBOT)
    check_env(env.unwrapped)
    obs, _ = env.reset(seed=0)
    assert set(obs) == {"agent_pos", "pixels"} and set(env.observation_space.spaces) == {
        "agent_pos",
        "pixels",
    }
    assert set(obs["pixels"]) == {"front", "wrist"}
    assert obs["agent_pos"].shape == (10,) and env.action_space.shape == (10,)
    for image in obs["pixels"].values():
        assert image.shape == (80, 80, 3) and image.dtype == np.uint8 and image.std() > 5
    env.close()


def test_the_new_keywords_left_out_or_at_their_defaults_change_nothing():
    """Guards against cameras or layouts that alter today's observation: the keywords given at their defaults
    and left out give the same keys and values, bit for bit, through a grasp; the LeRobot layout's agent_pos
    and wrist image are the token layout's, and a front camera added beside the wrist one changes neither."""
    default = {"obs_mode": "pixels", "image_size": 80}
    explicit = default | {"obs_layout": "tokens", "cameras": ("wrist",)}
    for a, b in lockstep(default, explicit, seed=1, steps=30):
        assert_same_observation(a, b)
    assert set(a) == {"token_poses", "token_features", "agent_pos", "environment_state", "pixels"}
    assert set(a["pixels"]) == {"wrist"}
    for a, b in lockstep(default, LEROBOT, seed=1, steps=30):
        np.testing.assert_array_equal(a["agent_pos"], b["agent_pos"])
        np.testing.assert_array_equal(a["pixels"]["wrist"], b["pixels"]["wrist"])
    for a, b in lockstep({}, {"obs_layout": "tokens"}, seed=2, steps=5):
        assert_same_observation(a, b)
    assert "pixels" not in a


def test_the_front_camera_sees_each_cube_where_its_pose_projects():
    """Guards against a front camera that misses or cuts off the objects, and against a camera pose, field of
    view or axis convention that does not say where the image was taken: each cube's centre, projected with
    ``camera_poses["front"]`` alone, lands inside the 80x80 image on a pixel that MuJoCo's segmentation says
    is that cube and whose colour is the cube's (red A, green B), and each cube covers several pixels."""
    env = gym.make(STACK, obs_mode="pixels", cameras=("front",), image_size=80)
    base = env.unwrapped
    camera = base.camera_poses["front"]
    assert camera.frame == "world"
    for seed in (0, 1, 2):
        obs, _ = env.reset(seed=seed)
        image = obs["pixels"]["front"].astype(int)
        ids = base._geom_ids("front", 80, 80)
        for row, name, colour in ((1, "cube_a", 0), (2, "cube_b", 1)):
            u, v = project(camera, obs["token_poses"][row, :3].astype(np.float64), 80)
            assert 4 <= u <= 76 and 4 <= v <= 76, (name, u, v)
            geoms = sorted(base.geoms_of(name))
            assert ids[int(v), int(u)] in geoms, (name, seed, u, v)
            assert np.isin(ids, geoms).sum() >= 9, (name, seed)
            pixel = image[int(v), int(u)]
            assert pixel[colour] > np.delete(pixel, colour).max() + 40, (name, pixel)
    env.close()


def test_camera_poses_are_where_mujoco_renders_from_at_two_arm_poses():
    """Guards against a wrist offset that holds at one arm pose only, or that is not relative to the TCP
    frame agent_pos reports: at two different arm poses, the end-effector pose of agent_pos times the wrist
    offset is MuJoCo's camera frame (to float32), and the front camera's world pose is MuJoCo's. The wrist
    camera looks out of the fingers (its -z is the TCP's z)."""
    env = gym.make(STACK, **LEROBOT)
    base = env.unwrapped
    poses = base.camera_poses
    wrist, front = poses["wrist"], poses["front"]
    assert wrist.frame == "eef" and wrist.rotation[:, 2] @ [0.0, 0.0, 1.0] < -0.99
    tcps = []
    for offset, yaw in (((0.05, 0.08, -0.05), 0.6), ((-0.08, -0.10, 0.05), -1.0)):
        obs = move_arm(env, offset, yaw)
        rot, pos = pose9_to_rt(obs["agent_pos"][:9])
        cam_pos, cam_rot = base.camera_frame(base.camera_names["wrist"])
        got_pos, got_rot = wrist.world_pose((pos, rot))
        np.testing.assert_allclose(got_pos, cam_pos, atol=2e-6)
        np.testing.assert_allclose(got_rot, cam_rot, atol=2e-6)
        np.testing.assert_allclose(wrist.world_pose(base.tcp_pose())[0], cam_pos, atol=1e-12)
        front_pos, front_rot = base.camera_frame(base.camera_names["front"])
        np.testing.assert_allclose(front.world_pose((pos, rot))[0], front_pos, atol=1e-12)
        np.testing.assert_allclose(front.rotation, front_rot, atol=1e-12)
        tcps.append((pos, rot))
    (p0, r0), (p1, r1) = tcps
    assert np.linalg.norm(p0 - p1) > 0.1 and np.degrees(np.arccos((np.trace(r0.T @ r1) - 1) / 2)) > 45
    np.testing.assert_allclose(wrist.pose9()[:3], wrist.position, atol=1e-7)
    assert abs(np.linalg.norm(wrist.quaternion()) - 1) < 1e-12
    env.close()


def test_robosuite_cameras_have_poses_too():
    """Guards against the robomimic tasks' cameras (robosuite's agentview and eye-in-hand) placed in
    robosuite's frame instead of ours (table top at z = 0), or a wrist offset that does not hold."""
    pytest.importorskip("robosuite")
    env = gym.make("gym_actionflow/RobosuiteLift-v0", **LEROBOT)
    base = env.unwrapped
    obs = move_arm(env, (0.0, 0.1, -0.05), 0.8, steps=30)
    poses = base.camera_poses
    assert set(obs["pixels"]) == {"front", "wrist"}
    front_pos, _ = base.camera_frame("agentview")
    np.testing.assert_allclose(poses["front"].position, front_pos, atol=1e-12)
    assert (
        poses["front"].frame == "world" and 0.3 < front_pos[2] < 1.0
    )  # above the table top, not robosuite's
    cam_pos, cam_rot = base.camera_frame("robot0_eye_in_hand")
    got_pos, got_rot = poses["wrist"].world_pose(base.tcp_pose())
    np.testing.assert_allclose(got_pos, cam_pos, atol=1e-9)
    np.testing.assert_allclose(got_rot, cam_rot, atol=1e-9)
    env.close()


BAD_KEYWORDS = [
    ({"obs_layout": "lerobot"}, r"obs_layout='lerobot' with obs_mode='state'.*obs_mode='pixels'"),
    (
        {"obs_layout": "flat", "obs_mode": "pixels"},
        r"obs_layout='flat'; expected one of \('tokens', 'lerobot'\)",
    ),
    ({"cameras": ("front",)}, r"cameras=\('front',\) with obs_mode='state'"),
    ({"cameras": (), "obs_mode": "pixels"}, r"cameras=\(\) with obs_mode='pixels'; expected at least one"),
    ({"cameras": ("top",), "obs_mode": "pixels"}, r"cameras=\('top',\) names 'top'; expected names from"),
    ({"cameras": ("wrist", "wrist"), "obs_mode": "pixels"}, r"names a camera twice"),
    ({"cameras": "front", "obs_mode": "pixels"}, r"cameras='front'; expected a sequence of camera names"),
]


@pytest.mark.parametrize(("kwargs", "match"), BAD_KEYWORDS, ids=[m.split("=")[0] + str(i) for i, (_, m) in
                                                                  enumerate(BAD_KEYWORDS)])  # fmt: skip
def test_bad_combinations_raise_errors_naming_the_keyword(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make(STACK, **kwargs)


def test_task_options_that_the_lerobot_layout_cannot_show_are_refused():
    """Guards against an option silently dropped: a point cloud in a layout without one, a wrist mask
    without a wrist camera."""
    mug = "gym_actionflow/MugHanging-v0"
    with pytest.raises(ValueError, match=r"obs_layout='lerobot' observes agent_pos.*\['point_cloud'\]"):
        gym.make(mug, obs_mode="pixels", obs_layout="lerobot", hanger_obs="point_cloud")
    with pytest.raises(ValueError, match=r"mask_after_grasp=True with cameras=\('front',\).*add 'wrist'"):
        gym.make(mug, obs_mode="pixels", cameras=("front",), mask_after_grasp=True)


# ---------------------------------------------------------------------------- lerobot-eval's env config
@dataclass
class _EvalArgs:
    env: EnvConfig | None = None


def test_env_config_builds_the_lerobot_layout_from_lerobot_eval_flags():
    """`--env.cameras='[front,wrist]'` (draccus's list syntax, as lerobot-eval parses it) reaches gym.make,
    and the features are the state and the two cameras, mapped to observation.state / observation.images.*."""
    args = ["--env.type=actionflow", "--env.task=Stack-v0", "--env.obs_mode=pixels",
            "--env.obs_layout=lerobot", "--env.cameras=[front,wrist]", "--env.image_size=80"]  # fmt: skip
    config = draccus.parse(_EvalArgs, args=args).env
    assert config.gym_kwargs == {"variant": "D0", **LEROBOT}
    assert {k: tuple(f.shape) for k, f in config.features.items()} == {
        "action": (10,), "agent_pos": (10,), "pixels/front": (80, 80, 3), "pixels/wrist": (80, 80, 3),
    }  # fmt: skip
    mapped = {config.features_map[k] for k in config.features}
    assert mapped == {"action", "observation.state", "observation.images.front", "observation.images.wrist"}
    assert "obs_layout" not in ActionFlowEnvConfig(task="Stack-v0").gym_kwargs
    with pytest.raises(ValueError, match=r"--env.obs_layout='lerobot' with obs_mode='state'"):
        ActionFlowEnvConfig(task="Stack-v0", obs_layout="lerobot")
    with pytest.raises(ValueError, match=r"--env.cameras=\('side',\) names 'side'"):
        ActionFlowEnvConfig(task="Stack-v0", obs_mode="pixels", cameras=["side"])


def test_schema_features_of_the_lerobot_layout_have_no_token_names():
    shapes = {"agent_pos": (10,), "pixels/front": (80, 80, 3), "pixels/wrist": (80, 80, 3)}
    features = schema.dataset_features(shapes, token_names=["eef", "cube_a", "cube_b"])
    assert set(features) == {schema.STATE, f"{schema.IMAGES}.front", f"{schema.IMAGES}.wrist", schema.ACTION}
    assert schema.obs_layout(shapes) == "lerobot" and schema.obs_layout(schema.token_shapes(3, 4)) == "tokens"


# ---------------------------------------------------------------------------- recording
def _run(argv: list[str], capsys) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as stop:
        code = stop.code
    return code, capsys.readouterr().err


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--obs-layout", "lerobot"], "--obs-layout: obs_layout='lerobot' with obs_mode='state'"),
        (["--obs-mode", "pixels", "--cameras", "top"], "--cameras: got ['top']; expected a list of distinct"),
        (["--cameras", "front"], "--cameras: cameras=('front',) with obs_mode='state'"),
        (["--env-kwarg", "obs_layout=lerobot"], "--env-kwarg obs_layout: obs_layout is a field of its own"),
        (["--env-kwarg", 'cameras=["front"]'], "--env-kwarg cameras: cameras is a field of its own"),
    ],
    ids=[
        "layout-without-pixels",
        "unknown-camera",
        "cameras-without-pixels",
        "layout-kwarg",
        "cameras-kwarg",
    ],
)
def test_bad_layout_flags_exit_2_naming_the_flag_and_write_nothing(flags, message, tmp_path, capsys):
    code, err = _run(["--task", "Stack", "--episodes", "1", "--quiet", *flags, "--root", str(tmp_path / "x")],
                     capsys)  # fmt: skip
    assert code == 2 and message in err, err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ('obs_layout = "flat"', "obs_layout in {path}: got 'flat'; expected one of ('tokens', 'lerobot')"),
        ('obs_layout = "lerobot"', "obs_layout in {path}: obs_layout='lerobot' with obs_mode='state'"),
        ('obs_mode = "pixels"\ncameras = "front"', "cameras in {path}: got 'front'; expected a list of"),
    ],
    ids=["unknown-layout", "layout-without-pixels", "cameras-not-a-list"],
)
def test_bad_layout_recipe_fields_exit_2_naming_the_field(line, message, tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text(f'task = "Stack"\nvariant = "D0"\nepisodes = 1\nrepo_id = "local/bad"\n{line}\n')
    code, err = _run([str(path), "--quiet", "--root", str(tmp_path / "x")], capsys)
    assert code == 2 and message.format(path=path) in err, err
    assert not (tmp_path / "x").exists()


@dataclass
class _PolicyArgs:
    camera_poses: dict[str, list] = field(default_factory=dict)


def test_recording_the_lerobot_recipe_gives_a_plain_lerobot_dataset_with_the_camera_poses(tmp_path):
    """Guards against token keys or object poses leaking into a LeRobot-layout dataset, and against a dataset
    that does not say where its cameras were: 2 episodes of datasets/stack_d0_lerobot_100.toml hold exactly
    the state, the two cameras and the action, info.json and the card give each camera's pose, and the card's
    --policy.camera_poses value parses (draccus) to the env's poses."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    recipe = load_recipe(ROOT / "datasets" / "stack_d0_lerobot_100.toml")
    assert (recipe.obs_mode, recipe.obs_layout, recipe.cameras) == ("pixels", "lerobot", ["front", "wrist"])
    recipe = dataclasses.replace(recipe, episodes=2, repo_id="local/stack_lerobot")
    root = tmp_path / "lr"
    record(recipe, root=root, progress=False)
    ds = LeRobotDataset("local/stack_lerobot", root=root)
    keys = {"observation.state", "observation.images.front", "observation.images.wrist", "action"}
    assert set(ds.features) == keys | BOOKKEEPING and ds.num_episodes == 2
    item = ds[5]
    assert item["observation.state"].shape == (10,) and item["action"].shape == (10,)
    assert item["observation.images.front"].shape == item["observation.images.wrist"].shape == (3, 80, 80)

    env = gym.make(STACK, **LEROBOT)
    poses = env.unwrapped.camera_poses
    env.close()
    flag = None
    card = (root / "README.md").read_text()
    assert "layout `lerobot`" in card and "--obs-layout lerobot --cameras front wrist" in card
    for line in card.splitlines():
        if line.startswith("--policy.camera_poses="):
            flag = line.removeprefix("--policy.camera_poses=").strip("'")
    parsed = draccus.parse(_PolicyArgs, args=[f"--camera_poses={flag}"]).camera_poses
    for camera in ("front", "wrist"):
        info = ds.meta.info.features[f"observation.images.{camera}"]["info"]
        pose = poses[camera]
        assert info["camera.frame"] == pose.frame == parsed[camera][0]
        np.testing.assert_allclose(info["camera.pose"], pose.pose9(), atol=1e-6)
        np.testing.assert_allclose(parsed[camera][1:4], pose.position, atol=1e-6)
        np.testing.assert_allclose(parsed[camera][4:], pose.quaternion(), atol=1e-6)
        assert info["camera.fovy_degrees"] == pose.fovy

    # What a camera saw: eval.diagnostics.camera_view lays the episode's frames side by side, pixel for pixel.
    from PIL import Image

    from eval.diagnostics.camera_view import main as camera_view

    out = tmp_path / "view.png"
    camera_view(["--root", str(root), "--camera", "wrist", "--episode", "1", "--frames", "3", "--scale", "2",
                 "--out", str(out)])  # fmt: skip
    strip = np.asarray(Image.open(out))
    assert strip.shape == (160, 480, 3)
    first = ds[int(ds.meta.episodes["dataset_from_index"][1])]["observation.images.wrist"]
    expected = (first.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    np.testing.assert_array_equal(strip[::2, ::2][:, :80], expected)
    with pytest.raises(SystemExit, match="observation.images.side.*'front', 'wrist'"):
        camera_view(["--root", str(root), "--camera", "side", "--out", str(out)])
