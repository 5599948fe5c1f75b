"""SE(3) invariance of the network and equivariance of the whole policy under random rigid transforms."""

import pytest
import torch
from helpers import chunks_before_and_after, make_config, random_se3, transform_pose9

from lerobot_actionflow import ActionFlowPolicy
from lerobot_actionflow.core import geometry as g
from lerobot_actionflow.core.ipa import InvariantPointAttention, SE3InvariantTransformer


def _frames(b: int, n: int, seed: int):
    gen = torch.Generator().manual_seed(seed)
    rot = g.random_rotation((b, n), generator=gen)
    trans = torch.randn(b, n, 3, generator=gen) * 0.3
    return rot, trans


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ipa_layer_is_invariant(seed):
    torch.manual_seed(seed)
    layer = InvariantPointAttention(dim=32, num_heads=4, head_dim=8, query_points=4, value_points=4)
    s = torch.randn(2, 7, 32)
    rot, trans = _frames(2, 7, seed)
    d_rot, d_trans = random_se3(seed + 10)
    rot2, trans2 = g.compose(d_rot.expand_as(rot), d_trans.expand_as(trans), rot, trans)
    out, out2 = layer(s, rot, trans), layer(s, rot2, trans2)
    assert (out - out2).abs().max() < 1e-4
    # And it really uses the poses: moving one token changes the output.
    trans3 = trans.clone()
    trans3[:, 0] += 0.5
    assert (layer(s, rot, trans3) - out).abs().max() > 1e-3


def test_se3_invariant_transformer_is_invariant():
    torch.manual_seed(0)
    net = SE3InvariantTransformer(
        dim=64,
        num_heads=4,
        ipa_layers=2,
        transformer_layers=2,
        head_dim=16,
        query_points=4,
        value_points=4,
        dropout=0.0,
    ).eval()
    s = torch.randn(3, 9, 64)
    rot, trans = _frames(3, 9, 5)
    d_rot, d_trans = random_se3(6)
    rot2, trans2 = g.compose(d_rot.expand_as(rot), d_trans.expand_as(trans), rot, trans)
    assert (net(s, rot, trans) - net(s, rot2, trans2)).abs().max() < 1e-4


def _observation(seed: int, b: int = 3, t: int = 2):
    gen = torch.Generator().manual_seed(seed)
    rot = g.random_rotation((b, t, 3), generator=gen)
    trans = torch.randn(b, t, 3, 3, generator=gen) * 0.2
    feats = torch.randn(b, t, 3, 4, generator=gen)
    poses = g.rt_to_pose9(rot, trans)
    state = torch.cat([poses[:, :, 0], torch.rand(b, t, 1, generator=gen)], -1)
    return {"observation.token_poses": poses, "observation.token_features": feats, "observation.state": state}


@pytest.mark.parametrize("architecture", ["ipa", "multi_token", "single_token"])
@pytest.mark.parametrize(
    ("action_space", "euclidean_frame"),
    [("se3", "action"), ("euclidean", "action"), ("euclidean", "eef")],
    ids=["se3", "euclidean", "euclidean-eef"],
)
@pytest.mark.parametrize(
    ("squash_limit", "squash_mode", "rotation_noise_std"),
    [(1.0, "axis", None), (3.0, "axis", None), (3.0, "axis", 0.5), (3.0, "radial", 0.5)],
)
def test_policy_is_equivariant(
    architecture, action_space, euclidean_frame, squash_limit, squash_mode, rotation_noise_std
):
    """Same seed, every observed pose (tokens and the pose part of the state) moved by g: every generated
    action pose moves by g, the gripper command is unchanged (also with the rotation noise concentrated
    around the gripper's orientation: it is drawn in the EEF frame, which moves with g)."""
    torch.manual_seed(0)
    cfg = make_config(
        architecture=architecture, action_space=action_space, euclidean_frame=euclidean_frame,
        squash_limit=squash_limit, squash_mode=squash_mode, rotation_noise_std=rotation_noise_std,
    )  # fmt: skip
    policy = ActionFlowPolicy(cfg).eval()
    obs = _observation(1)
    d_rot, d_trans = random_se3(2)
    moved = dict(obs)
    moved["observation.token_poses"] = transform_pose9(d_rot, d_trans, obs["observation.token_poses"])
    moved["observation.state"] = torch.cat(
        [
            transform_pose9(d_rot, d_trans, obs["observation.state"][..., :9]),
            obs["observation.state"][..., 9:],
        ],
        -1,
    )
    torch.manual_seed(123)
    actions = policy.predict_action_chunk(obs)
    torch.manual_seed(123)
    actions_moved = policy.predict_action_chunk(moved)

    expected = transform_pose9(d_rot, d_trans, actions[..., :9])
    trans_err, rot_err = g.pose9_errors(actions_moved[..., :9], expected)
    assert trans_err.max() < 1e-4, f"translation error {trans_err.max():.2e} m"
    assert rot_err.max() < 1e-4, f"rotation error {rot_err.max():.2e} rad"
    assert torch.allclose(actions_moved[..., 9], actions[..., 9], atol=1e-5)
    # Not trivially satisfied: the actions do depend on where the objects are.
    shifted = dict(obs)
    shifted["observation.token_poses"] = obs["observation.token_poses"].clone()
    shifted["observation.token_poses"][:, :, 1, :3] += 0.1
    torch.manual_seed(123)
    assert (policy.predict_action_chunk(shifted) - actions).abs().max() > 1e-4


def test_policy_with_image_and_point_cloud_tokens():
    """Wrist images (posed at the EEF) and a fixture point cloud (posed at its centroid) train, sample, and
    keep the policy equivariant when the cloud moves with the scene."""
    torch.manual_seed(0)
    cfg = make_config(extra_inputs={"pixels/wrist": (32, 32, 3), "point_cloud": (32, 3)})
    policy = ActionFlowPolicy(cfg).eval()
    obs = _observation(3, b=2)
    gen = torch.Generator().manual_seed(4)
    obs["observation.images.wrist"] = torch.rand(2, 2, 3, 32, 32, generator=gen)
    obs["observation.point_cloud"] = torch.randn(2, 2, 32, 3, generator=gen) * 0.05 + 0.3
    batch = {
        **obs,
        "action": torch.cat(
            [obs["observation.token_poses"][:, -1, :1].expand(2, 16, 9), torch.ones(2, 16, 1)], -1
        ),
    }
    loss, _ = policy.forward(batch)
    loss.backward()
    assert policy.network.point_encoder.point_mlp[0].weight.grad.abs().sum() > 0
    image_encoder = next(iter(policy.network.image_encoders.values()))
    assert image_encoder.out[0].weight.grad.abs().sum() > 0
    assert image_encoder.backbone[0][0].weight.grad.abs().sum() > 0  # the image itself reaches the loss

    d_rot, d_trans = random_se3(5)
    actions, actions_moved, trans_err, rot_err = chunks_before_and_after(policy, obs, d_rot, d_trans)
    assert trans_err.max() < 1e-4 and rot_err.max() < 1e-4
    # The cloud matters: moving it alone changes the actions.
    shifted = dict(obs)
    shifted["observation.point_cloud"] = obs["observation.point_cloud"] + 0.05
    torch.manual_seed(9)
    assert (policy.predict_action_chunk(shifted) - actions).abs().max() > 1e-4
