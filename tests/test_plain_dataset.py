"""A plain LeRobot camera dataset (``observation.state`` + ``observation.images.*`` + an EEF-pose action, no
token keys): the EEF token from the state, camera tokens posed where they were taken, actions in the
dataset's layout, SE(3) equivariance through all of it, and the errors that say what to set."""

from __future__ import annotations

import pytest
import torch
from helpers import make_config, random_se3
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_actionflow import ActionFlowConfig, ActionFlowPolicy
from lerobot_actionflow.core import geometry as g
from lerobot_actionflow.core.pose_layouts import POSE_LAYOUTS, layout_to_rt, rt_to_layout, to_pose9
from lerobot_actionflow.schema import ACTION, ACTION_NAMES, STATE, STATE_NAMES

FRONT, WRIST = "observation.images.front", "observation.images.wrist"
CAMERAS = {  # [frame, x, y, z, qw, qx, qy, qz]
    "wrist": ["eef", 0.0, 0.02, 0.05, 0.9659, 0.2588, 0.0, 0.0],
    "front": ["world", 0.6, 0.1, 0.5, 0.0, 0.7071, 0.7071, 0.0],
}
TINY = {"dim": 32, "ipa_layers": 1, "transformer_layers": 1, "horizon": 8, "n_action_steps": 4}
SIZE, B, T = 24, 2, 2
OURS = {"state": (10, list(STATE_NAMES), {}), "action": (10, list(ACTION_NAMES), {})}
QUAT = {  # a robot's own convention: state [x, y, z, qw, qx, qy, qz, gripper], action with a xyzw quaternion
    "state": (8, None, {"state_pose_layout": "xyz_quat_wxyz", "state_gripper_index": 7}),
    "action": (8, None, {"action_layout": "xyz_quat_xyzw"}),
}


def plain_config(convention: dict = OURS, cameras: dict | None = CAMERAS, **overrides) -> ActionFlowConfig:
    """A tiny CPU config for a dataset with a state, the front and wrist cameras and an action, set up as
    ``make_policy`` does it: features first, then the dataset's names."""
    (state_dim, state_names, state_fields), (action_dim, action_names, action_fields) = convention.values()
    cfg = ActionFlowConfig(
        device="cpu", camera_poses=cameras or {}, **TINY, **state_fields, **action_fields, **overrides
    )
    image = PolicyFeature(FeatureType.VISUAL, (3, SIZE, SIZE))
    cfg.input_features = {STATE: PolicyFeature(FeatureType.STATE, (state_dim,)), FRONT: image, WRIST: image}
    cfg.output_features = {ACTION: PolicyFeature(FeatureType.ACTION, (action_dim,))}
    cfg.set_dataset_feature_metadata({
        STATE: {"dtype": "float32", "shape": (state_dim,), "names": state_names},
        ACTION: {"dtype": "float32", "shape": (action_dim,), "names": action_names},
    })  # fmt: skip
    return cfg


def _state(
    cfg: ActionFlowConfig, rot: torch.Tensor, trans: torch.Tensor, gripper: torch.Tensor
) -> torch.Tensor:
    """A state vector in the config's layout from EEF poses ``[*, 3, 3], [*, 3]`` and openings ``[*, 1]``."""
    return torch.cat([rt_to_layout(cfg.state_pose_layout, rot, trans), gripper], -1)


def _batch(cfg: ActionFlowConfig, seed: int = 0) -> dict[str, torch.Tensor]:
    """A training batch: states and images with a history axis, and a chunk of actions in the dataset's
    layout."""
    gen = torch.Generator().manual_seed(seed)
    rot, trans = g.random_rotation((B, T), gen), torch.randn(B, T, 3, generator=gen) * 0.2
    act_rot, act_trans = (
        g.random_rotation((B, TINY["horizon"]), gen),
        torch.randn(B, TINY["horizon"], 3) * 0.2,
    )
    gripper = torch.rand(B, TINY["horizon"], 1, generator=gen) * 2 - 1
    return {
        STATE: _state(cfg, rot, trans, torch.rand(B, T, 1, generator=gen) * 0.08),
        FRONT: torch.rand(B, T, 3, SIZE, SIZE, generator=gen),
        WRIST: torch.rand(B, T, 3, SIZE, SIZE, generator=gen),
        ACTION: torch.cat([rt_to_layout(cfg.action_layout, act_rot, act_trans), gripper], -1),
    }


@pytest.mark.parametrize("convention", [OURS, QUAT], ids=["ours", "quaternions"])
def test_a_camera_dataset_trains_and_acts_in_its_own_action_shape(convention):
    """The state-only EEF token and the two camera tokens train, and the policy returns actions of the
    dataset's shape in its layout (a unit quaternion for the quaternion dataset)."""
    torch.manual_seed(0)
    cfg = plain_config(convention)
    policy = ActionFlowPolicy(cfg)
    spec = policy.model.spec
    assert (spec.tokens_per_step, spec.image_keys, set(spec.camera_poses)) == (
        1,
        (FRONT, WRIST),
        {FRONT, WRIST},
    )
    batch = _batch(cfg)
    optim = torch.optim.Adam(policy.parameters(), lr=1e-3)
    losses = []
    for _ in range(3):
        loss, terms = policy.forward(batch)
        optim.zero_grad()
        loss.backward()
        optim.step()
        losses.append(loss.item())
    assert all(torch.isfinite(torch.tensor(losses))) and losses[-1] != losses[0]
    assert {"loss_translation", "loss_rotation", "loss_gripper"} <= set(terms)

    policy.eval()
    obs = {k: v[:, -1] for k, v in batch.items() if k != ACTION}  # one step, as an environment gives it
    action = policy.select_action(obs)
    size = convention["action"][0]
    assert action.shape == (B, size) and torch.isfinite(action).all()
    chunk = policy.predict_action_chunk(obs)
    assert chunk.shape == (B, TINY["horizon"], size)
    if cfg.action_layout != "pose9":
        torch.testing.assert_close(chunk[..., 3:7].norm(dim=-1), torch.ones(B, TINY["horizon"]))


def _moved_state(cfg: ActionFlowConfig, state: torch.Tensor, rot: torch.Tensor, trans: torch.Tensor):
    """The state with its EEF pose moved by the world transform ``(rot, trans)``; the rest unchanged."""
    n = POSE_LAYOUTS[cfg.state_pose_layout]
    r, p = layout_to_rt(cfg.state_pose_layout, state[..., :n])
    moved = rt_to_layout(cfg.state_pose_layout, *g.compose(rot.expand_as(r), trans.expand_as(p), r, p))
    return torch.cat([moved, state[..., n:]], -1)


def _moved_cameras(rot: torch.Tensor, trans: torch.Tensor) -> dict:
    """CAMERAS with the world camera's extrinsics moved by ``(rot, trans)``; the wrist's offset rides the
    EEF."""
    front = torch.tensor(CAMERAS["front"][1:], dtype=torch.float64)
    r, p = layout_to_rt("xyz_quat_wxyz", front)
    moved = rt_to_layout("xyz_quat_wxyz", *g.compose(rot.double(), trans.double(), r, p))
    return {**CAMERAS, "front": ["world", *moved.tolist()]}


@pytest.mark.parametrize("convention", [OURS, QUAT], ids=["ours", "quaternions"])
def test_moving_the_eef_the_world_camera_and_the_actions_together_moves_the_sampled_actions(convention):
    """Same images, same noise; the state's EEF pose and the front camera's extrinsics moved by a random g:
    every sampled action pose moves by g (the gripper command stays). And the camera poses are really used:
    moving the front camera alone, or changing the wrist camera's offset, changes the actions."""
    torch.manual_seed(0)
    cfg = plain_config(convention)
    policy = ActionFlowPolicy(cfg).eval()
    obs = {k: v for k, v in _batch(cfg, seed=1).items() if k != ACTION}
    d_rot, d_trans = random_se3(5)
    moved_cfg = plain_config(convention, cameras=_moved_cameras(d_rot, d_trans))
    moved_policy = ActionFlowPolicy(moved_cfg).eval()
    moved_policy.load_state_dict(policy.state_dict())
    moved_obs = {**obs, STATE: _moved_state(cfg, obs[STATE], d_rot, d_trans)}

    def sample(p: ActionFlowPolicy, o: dict) -> torch.Tensor:
        torch.manual_seed(7)
        return p.predict_action_chunk(o)

    actions, actions_moved = sample(policy, obs), sample(moved_policy, moved_obs)
    layout = cfg.action_layout
    rot, trans = layout_to_rt(layout, actions[..., :-1])
    expected = g.rt_to_pose9(*g.compose(d_rot.expand_as(rot), d_trans.expand_as(trans), rot, trans))
    trans_err, rot_err = g.pose9_errors(to_pose9(layout, actions_moved[..., :-1]), expected)
    assert trans_err.max() < 1e-4 and rot_err.max() < 1e-3, (trans_err.max(), rot_err.max())
    torch.testing.assert_close(actions_moved[..., -1], actions[..., -1], atol=1e-5, rtol=0)

    assert (sample(moved_policy, obs) - actions).abs().max() > 1e-4  # the front camera alone moved
    offset = {**CAMERAS, "wrist": ["eef", 0.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.0]}
    other_wrist = ActionFlowPolicy(plain_config(convention, cameras=offset)).eval()
    other_wrist.load_state_dict(policy.state_dict())
    assert (sample(other_wrist, obs) - actions).abs().max() > 1e-4


def test_a_saved_camera_dataset_policy_loads_with_its_layouts_and_acts_the_same(tmp_path):
    """The camera poses and the resolved layouts are saved with the checkpoint: loaded back without the
    dataset, the policy gives the same chunk bit for bit."""
    torch.manual_seed(0)
    policy = ActionFlowPolicy(plain_config(QUAT)).eval()
    policy.save_pretrained(tmp_path)
    loaded = ActionFlowPolicy.from_pretrained(tmp_path).eval()
    assert loaded.config.camera_poses == policy.config.camera_poses
    assert (loaded.config.state_pose_layout, loaded.config.action_layout) == (
        "xyz_quat_wxyz",
        "xyz_quat_xyzw",
    )
    obs = {k: v[:, -1] for k, v in _batch(policy.config).items() if k != ACTION}
    torch.manual_seed(3)
    chunk = policy.predict_action_chunk(obs)
    torch.manual_seed(3)
    torch.testing.assert_close(loaded.predict_action_chunk(obs), chunk, atol=0, rtol=0)


def test_our_state_names_choose_the_layout_and_a_token_dataset_keeps_its_fields_unset():
    """STATE_NAMES give pose9 at 0 with the gripper at 9; a token dataset (which also has our state) leaves
    the state fields alone, so its saved config is as before."""
    cfg = plain_config()
    assert (cfg.state_pose_layout, cfg.state_pose_start, cfg.state_gripper_index) == ("pose9", 0, 9)
    assert cfg.action_layout == "pose9"
    tokens = make_config()
    tokens.set_dataset_feature_metadata(
        {STATE: {"names": list(STATE_NAMES)}, ACTION: {"names": list(ACTION_NAMES)}}
    )
    assert (tokens.state_pose_layout, tokens.state_gripper_index, tokens.state_layout()) == (None, None, None)


def test_camera_poses_come_from_the_datasets_camera_info_unless_given():
    """A dataset recorded by actionflow-record says where its cameras were (each image feature's ``info``):
    without token keys those poses fill camera_poses, an entry given on the command line wins, and a token
    dataset keeps posing images at the EEF token (its behaviour before the field existed)."""
    info = {  # as schema.camera_info writes them: the pose9 and the same rotation as a quaternion
        FRONT: {"camera.frame": "world", "camera.pose": [0.5, 0, 0.4, 0, 1, 0, 0, 0, -1],
                "camera.quaternion_wxyz": [0.5, -0.5, -0.5, 0.5]},
        WRIST: {"camera.frame": "eef", "camera.pose": [0, 0, 0.05, 1, 0, 0, 0, 1, 0],
                "camera.quaternion_wxyz": [1, 0, 0, 0]},
    }  # fmt: skip
    features = {key: {"dtype": "video", "shape": (SIZE, SIZE, 3), "info": cam} for key, cam in info.items()}
    cfg = plain_config(cameras={"wrist": CAMERAS["wrist"]})
    cfg.set_dataset_feature_metadata({**features, STATE: {"names": list(STATE_NAMES)}})
    assert cfg.camera_poses == {
        "wrist": CAMERAS["wrist"],
        "front": ["world", 0.5, 0, 0.4, 0.5, -0.5, -0.5, 0.5],
    }
    ActionFlowPolicy(cfg)  # every camera has its pose now
    tokens = make_config(extra_inputs={"pixels/wrist": (SIZE, SIZE, 3)})
    tokens.set_dataset_feature_metadata({WRIST: features[WRIST]})
    assert tokens.camera_poses == {}


def test_camera_pose_numbers_are_read_as_floats():
    """YAML reads ``-1e-3`` as a string: the entry is stored as numbers, as the checkpoint saves it."""
    cfg = ActionFlowConfig(device="cpu", camera_poses={"wrist": ["eef", 0, "-1e-3", 0.05, 1, 0, 0, 0]})
    assert cfg.camera_poses == {"wrist": ["eef", 0.0, -0.001, 0.05, 1.0, 0.0, 0.0, 0.0]}


def test_a_camera_pose_moves_an_image_token_of_a_token_dataset_too():
    """With token keys, a camera without an entry is posed at the EEF token (as before the field existed);
    an entry poses it elsewhere, which changes the actions."""
    torch.manual_seed(0)
    base = ActionFlowPolicy(make_config(extra_inputs={"pixels/wrist": (SIZE, SIZE, 3)})).eval()
    posed = ActionFlowPolicy(
        make_config(extra_inputs={"pixels/wrist": (SIZE, SIZE, 3)}, camera_poses={"wrist": CAMERAS["front"]})
    ).eval()
    posed.load_state_dict(base.state_dict())
    gen = torch.Generator().manual_seed(2)
    poses = g.rt_to_pose9(g.random_rotation((B, T, 3), gen), torch.randn(B, T, 3, 3, generator=gen) * 0.2)
    obs = {
        "observation.token_poses": poses,
        "observation.token_features": torch.randn(B, T, 3, 4, generator=gen),
        WRIST: torch.rand(B, T, 3, SIZE, SIZE, generator=gen),
    }
    torch.manual_seed(1)
    a = base.predict_action_chunk(obs)
    torch.manual_seed(1)
    assert (posed.predict_action_chunk(obs) - a).abs().max() > 1e-4


# ---------------------------------------------------------------------------- errors that say what to set


def test_a_camera_without_a_pose_is_named_with_the_field_to_set():
    with pytest.raises(ValueError, match=r"\['observation.images.front'\] have no entry in camera_poses.*"
                       r"--policy.camera_poses='\{front: \[world, "):  # fmt: skip
        ActionFlowPolicy(plain_config(cameras={"wrist": CAMERAS["wrist"]}))


def test_images_added_to_the_eef_token_need_no_camera_pose():
    """image_placement="eef" (the paper's): each image joins the EEF token's feature; no camera is posed."""
    cfg = plain_config(cameras=None, image_placement="eef")
    batch = _batch(cfg)
    loss, _ = ActionFlowPolicy(cfg).forward(batch)
    assert torch.isfinite(loss)


def test_a_state_with_unknown_names_asks_where_the_pose_is():
    """Nothing says where the pose is: the error names observation.state, its shape and names, and the
    fields to set."""
    unnamed = {"state": (14, [f"joint_{i}" for i in range(14)], {}), "action": OURS["action"]}
    with pytest.raises(
        ValueError,
        match=r"observation.state has shape \(14,\) \(names \['joint_0'.*nothing says where the pose is.*"
        r"--policy.state_pose_layout.*--policy.state_pose_start.*--policy.state_gripper_index",
    ):
        ActionFlowPolicy(plain_config(unnamed))


def test_the_state_slice_must_fit_the_state():
    short = {
        "state": (8, None, {"state_pose_layout": "pose9", "state_gripper_index": 9}),
        "action": OURS["action"],
    }
    with pytest.raises(ValueError, match=r"observation.state has shape \(8,\); state_pose_layout='pose9'"):
        ActionFlowPolicy(plain_config(short))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"state_pose_layout": "quat"}, r"state_pose_layout='quat'; expected None .* or one of \('pose9'"),
        ({"action_layout": "joints"}, r"action_layout='joints'; expected None"),
        ({"state_gripper_index": -1}, r"state_gripper_index=-1; expected indices >= 0"),
        ({"camera_poses": {"wrist": ["base", *[0] * 7]}}, r"camera_poses\['wrist'\]=\['base'.*frame in"),
        ({"camera_poses": {"wrist": ["eef", 0, 0, 0]}}, r"expected \[frame, x, y, z, qw, qx, qy, qz\]"),
        ({"camera_poses": {"wrist": ["eef", 0, 0, 0, 0, 0, 0, 0]}}, r"a non-zero scalar-first quaternion"),
        (
            {"camera_poses": {"wrist": CAMERAS["wrist"]}, "image_placement": "eef"},
            r"camera_poses=\['wrist'\] with image_placement='eef'",
        ),
    ],
    ids=[
        "state-layout",
        "action-layout",
        "gripper-index",
        "camera-frame",
        "camera-pose",
        "zero-quaternion",
        "eef-placement",
    ],
)
def test_bad_plain_dataset_fields_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ActionFlowConfig(device="cpu", **kwargs)


def test_a_camera_pose_for_a_camera_the_dataset_lacks_is_refused():
    with pytest.raises(ValueError, match=r"camera_poses names the cameras \['side'\], which are not inputs"):
        ActionFlowPolicy(plain_config(cameras={**CAMERAS, "side": CAMERAS["front"]}))


def test_joint_space_actions_are_refused_with_the_reason():
    joints = {"state": OURS["state"], "action": (7, [f"joint_{i}" for i in range(7)], {})}
    with pytest.raises(
        ValueError,
        match=r"action has shape \(7,\) \(names \['joint_0'.*Joint-space actions .* cannot be converted",
    ):
        ActionFlowPolicy(plain_config(joints))


def test_an_action_of_another_size_than_its_layout_is_refused():
    wrong = {"state": OURS["state"], "action": (10, None, {"action_layout": "xyz_rotvec"})}
    with pytest.raises(
        ValueError, match=r"action has shape \(10,\); action_layout='xyz_rotvec' expects \(7,\)"
    ):
        ActionFlowPolicy(plain_config(wrong))


def test_a_gripper_value_outside_minus_one_one_is_refused():
    """A dataset gripper in [0, 255] could never be commanded: the sampled command is clamped to [-1, 1]."""
    stats = {ACTION: {"min": torch.zeros(10), "max": torch.tensor([1.0] * 9 + [255.0])}}
    with pytest.raises(ValueError, match=r"gripper value .* ranges over \[0, 255\]; .* \[-1, 1\]"):
        ActionFlowPolicy(plain_config(), dataset_stats=stats)


def test_a_batch_without_the_state_names_it():
    policy = ActionFlowPolicy(plain_config()).eval()
    obs = {k: v for k, v in _batch(policy.config).items() if k in (FRONT, WRIST)}
    with pytest.raises(
        ValueError, match=r"missing observation key 'observation.state'.*observation.state \(10,\)"
    ):
        policy.predict_action_chunk(obs)
