"""The Vector-Neuron point-cloud encoder (``point_encoder="vn"``): invariance and equivariance of the encoder
under random rotations, its frame, degenerate clouds, the policy's SE(3) equivariance with it, the config
field and its checkpoints."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import chunks_before_and_after, make_config
from scipy.spatial.transform import Rotation

from lerobot_actionflow import ActionFlowConfig, ActionFlowPolicy
from lerobot_actionflow.core import geometry as g
from lerobot_actionflow.core.encoders import (
    PointCloudEncoder,
    VNLinear,
    VNLinearLeakyReLU,
    VNPointNetEncoder,
)

FIXTURES = Path(__file__).parent / "fixtures"
POINTS = "observation.point_cloud"
DIM = 64


def _rotation(seed: int, dtype=torch.float32) -> torch.Tensor:
    """One Haar-random rotation ``[3, 3]`` from scipy (independent of the project's own sampler)."""
    return torch.as_tensor(Rotation.random(random_state=seed).as_matrix(), dtype=dtype)


def _cloud(seed: int, shape: tuple[int, ...] = (2, 3, 48)) -> torch.Tensor:
    """An anisotropic random cloud ``[*shape, 3]`` off the origin (so it has an orientation of its own)."""
    gen = torch.Generator().manual_seed(seed)
    return torch.randn(*shape, 3, generator=gen) * torch.tensor([1.0, 0.5, 0.2]) + 0.7


def _encoder(seed: int = 0) -> VNPointNetEncoder:
    torch.manual_seed(seed)
    return VNPointNetEncoder(DIM).eval()


def _rotate(rot: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``R @ x`` for points ``[*, 3]``."""
    return points @ rot.T


def _is_proper_rotation(frame: torch.Tensor, atol: float = 1e-5) -> bool:
    eye = torch.eye(3, dtype=frame.dtype).expand_as(frame)
    orthonormal = torch.allclose(frame.transpose(-1, -2) @ frame, eye, atol=atol)
    return orthonormal and torch.allclose(torch.linalg.det(frame), torch.ones(frame.shape[:-2]), atol=atol)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_vn_layers_rotate_with_their_input(seed):
    """A VN linear layer or leaky ReLU that mixed the xyz axis (or had a bias) would not commute with R."""
    torch.manual_seed(seed)
    v = torch.randn(5, 3, 7)  # [*, 3, C]: 7 vector channels
    rot = _rotation(seed)
    for layer in (VNLinear(7, 4), VNLinearLeakyReLU(7, 4)):
        torch.testing.assert_close(layer(rot @ v), rot @ layer(v), atol=1e-5, rtol=0)
    # The leaky ReLU really is non-linear (a plain linear map would pass the check above as well).
    relu, w = VNLinearLeakyReLU(7, 4), torch.randn(5, 3, 7)
    assert (relu(v + w) - relu(v) - relu(w)).abs().max() > 1e-3


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_vn_feature_is_invariant_and_frame_equivariant_under_random_rotations(seed):
    """Turning (and moving) the cloud must leave the feature unchanged and turn the frame with it:
    ``feature(R x + p) = feature(x)``, ``frame(R x + p) = R frame(x)``, for clouds ``[B, T, P, 3]``."""
    enc = _encoder(seed)
    points = _cloud(seed)
    rot = _rotation(100 + seed)
    with torch.no_grad():
        feature, frame = enc(points)
        feature_r, frame_r = enc(_rotate(rot, points) + torch.tensor([0.3, -1.0, 2.0]))
    assert feature.shape == (2, 3, DIM) and frame.shape == (2, 3, 3, 3)
    torch.testing.assert_close(feature_r, feature, atol=1e-4, rtol=0)
    torch.testing.assert_close(frame_r, rot @ frame, atol=1e-4, rtol=0)
    # Not trivially satisfied: another shape of cloud gives another feature.
    with torch.no_grad():
        stretched, _ = enc(points * torch.tensor([1.0, 2.0, 1.0]))
    assert (stretched - feature).abs().max() > 1e-3


def test_vn_frame_is_a_proper_rotation():
    """The frame becomes a token's rotation: a reflection (det -1) or a non-orthonormal matrix would break
    the IPA's geometry."""
    _, frame = _encoder()(_cloud(5, (4, 2, 40)))
    assert _is_proper_rotation(frame.detach())


def test_vn_encoder_ignores_the_order_of_the_points():
    """A point cloud is a set: shuffling the points must not change the feature or the frame."""
    enc = _encoder(1)
    points = _cloud(6, (3, 2, 50))
    perm = torch.randperm(50, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        feature, frame = enc(points)
        feature_p, frame_p = enc(points[..., perm, :])
    torch.testing.assert_close(feature_p, feature, atol=1e-5, rtol=0)
    torch.testing.assert_close(frame_p, frame, atol=1e-5, rtol=0)


@pytest.mark.parametrize(
    "points",
    [
        torch.full((2, 1, 32, 3), 0.4),  # all points equal
        torch.linspace(-1.0, 1.0, 32)[:, None] * torch.tensor([0.3, -0.5, 0.8]) + 0.2,  # collinear
        torch.randn(1, 1, 3) + 0.1,  # a single point (fewer points than neighbours)
        torch.zeros(1, 2, 3),  # two points at the origin
    ],
    ids=["equal", "collinear", "single", "zeros"],
)
def test_vn_degenerate_clouds_give_finite_features_and_a_rotation(points):
    """A cloud without an orientation of its own (a filtered-out fixture, a depth artefact) must not send NaN
    into the policy or its gradients, and its token still needs a valid rotation."""
    enc = _encoder(2)
    points = points.clone().requires_grad_(True)
    feature, frame = enc(points)
    (feature.sum() + frame.sum()).backward()
    assert torch.isfinite(feature).all() and torch.isfinite(frame).all()
    assert torch.isfinite(points.grad).all()
    assert all(torch.isfinite(p.grad).all() for p in enc.parameters() if p.grad is not None)
    assert _is_proper_rotation(frame.detach())


def _network_inputs(seed: int, b: int = 2, t: int = 2, n: int = 3):
    gen = torch.Generator().manual_seed(seed)
    feats = torch.randn(b, t, n, 4, generator=gen)
    rot = g.random_rotation((b, t, n), generator=gen)
    trans = torch.randn(b, t, n, 3, generator=gen)
    rot[:, :, 0], trans[:, :, 0] = torch.eye(3), 0.0  # token 0 is the EEF, at the origin of its frame
    return feats, rot, trans


@pytest.mark.parametrize("point_encoder", ["pointnet", "vn"])
def test_point_token_feature_ignores_how_the_cloud_turns_relative_to_the_gripper(point_encoder):
    """With "vn", turning the cloud about its centroid (in the EEF frame) leaves the point token's feature
    alone and turns its rotation; the plain PointNet's feature changes and its rotation stays the identity
    (the orientation has to be learned from the feature)."""
    torch.manual_seed(0)
    cfg = make_config(extra_inputs={"point_cloud": (40, 3)}, point_encoder=point_encoder)
    network = ActionFlowPolicy(cfg).eval().network
    assert isinstance(
        network.point_encoder, VNPointNetEncoder if point_encoder == "vn" else PointCloudEncoder
    )
    feats, rot, trans = _network_inputs(1)
    points = _cloud(2, (2, 2, 40)) * 3.0
    centroid = points.mean(dim=-2, keepdim=True)
    d_rot = _rotation(3)
    turned = _rotate(d_rot, points - centroid) + centroid
    with torch.no_grad():
        scene = network.encode_observation(feats, rot, trans, {}, points)
        scene_t = network.encode_observation(feats, rot, trans, {}, turned)

    def point_token(x: torch.Tensor) -> torch.Tensor:  # [B, T * (N + 1), ...] -> [B, T, ...]
        return x.unflatten(1, (2, 4))[:, :, -1]

    torch.testing.assert_close(point_token(scene_t.trans), point_token(scene.trans), atol=1e-5, rtol=0)
    feature_change = (point_token(scene_t.features) - point_token(scene.features)).abs().max()
    if point_encoder == "vn":
        assert feature_change < 1e-4
        torch.testing.assert_close(
            point_token(scene_t.rot), d_rot @ point_token(scene.rot), atol=1e-4, rtol=0
        )
        assert _is_proper_rotation(point_token(scene.rot))
    else:
        assert feature_change > 1e-3
        assert torch.equal(point_token(scene_t.rot), torch.eye(3).expand(2, 2, 3, 3))


def _observation(seed: int, b: int = 2, t: int = 2):
    gen = torch.Generator().manual_seed(seed)
    rot = g.random_rotation((b, t, 3), generator=gen)
    trans = torch.randn(b, t, 3, 3, generator=gen) * 0.2
    poses = g.rt_to_pose9(rot, trans)
    return {
        "observation.token_poses": poses,
        "observation.token_features": torch.randn(b, t, 3, 4, generator=gen),
        "observation.images.wrist": torch.rand(b, t, 3, 32, 32, generator=gen),
        # An elongated fixture 0.3 m away, about 10 cm long.
        POINTS: torch.randn(b, t, 32, 3, generator=gen) * torch.tensor([0.05, 0.02, 0.01]) + 0.3,
    }


@pytest.mark.parametrize("architecture", ["ipa", "multi_token", "single_token"])
@pytest.mark.parametrize("seed", [0, 1])
def test_policy_with_vn_point_cloud_is_se3_equivariant(architecture, seed):
    """As test_equivariance.py::test_policy_with_image_and_point_cloud_tokens with point_encoder="vn": the
    point token, now posed with the encoder's frame, trains and keeps the policy exactly SE(3)-equivariant
    when the cloud moves with the scene (a random scipy rotation and translation); the cloud's position and
    its orientation (carried by the token's rotation, not its feature) both change the actions."""
    torch.manual_seed(0)
    cfg = make_config(
        extra_inputs={"pixels/wrist": (32, 32, 3), "point_cloud": (32, 3)},
        point_encoder="vn",
        architecture=architecture,
    )
    policy = ActionFlowPolicy(cfg).eval()
    obs = _observation(10 + seed)
    batch = {
        **obs,
        "action": torch.cat(
            [obs["observation.token_poses"][:, -1, :1].expand(2, 16, 9), torch.ones(2, 16, 1)], -1
        ),
    }
    loss, _ = policy.forward(batch)
    loss.backward()
    assert torch.isfinite(loss)
    assert policy.network.point_encoder.edge.feature.map.weight.grad.abs().sum() > 0

    d_rot = _rotation(20 + seed)
    d_trans = torch.as_tensor(np.random.default_rng(seed).normal(scale=0.5, size=3), dtype=torch.float32)
    actions, actions_moved, trans_err, rot_err = chunks_before_and_after(policy, obs, d_rot, d_trans)
    assert trans_err.max() < 1e-4, f"translation error {trans_err.max():.2e} m"
    assert rot_err.max() < 1e-4, f"rotation error {rot_err.max():.2e} rad"
    torch.testing.assert_close(actions_moved[..., 9], actions[..., 9], atol=1e-5, rtol=0)
    # The cloud matters: moving it alone, or turning it about its centroid alone, changes the actions.
    centroid = obs[POINTS].mean(dim=-2, keepdim=True)
    for changed in (obs[POINTS] + 0.05, _rotate(_rotation(30 + seed), obs[POINTS] - centroid) + centroid):
        torch.manual_seed(9)
        assert (policy.predict_action_chunk({**obs, POINTS: changed}) - actions).abs().max() > 1e-4


def test_unknown_point_encoder_is_rejected():
    """A typo must fail at configuration time, naming the field, the value and the choices, instead of
    silently training the plain PointNet."""
    with pytest.raises(ValueError, match=r"point_encoder='bogus'; expected one of \('pointnet', 'vn'\)"):
        make_config(point_encoder="bogus")


def test_vn_policy_save_load_round_trip_is_bit_exact(tmp_path):
    """The field is saved with the checkpoint: a "vn" policy must not come back with a PointNet (its weights
    would then be silently dropped)."""
    torch.manual_seed(0)
    cfg = make_config(extra_inputs={"point_cloud": (32, 3)}, point_encoder="vn", num_inference_steps=2)
    policy = ActionFlowPolicy(cfg).eval()
    obs = {k: v for k, v in _observation(4).items() if k != "observation.images.wrist"}
    torch.manual_seed(7)
    before = policy.predict_action_chunk(obs)
    policy.save_pretrained(tmp_path)
    assert json.loads((tmp_path / "config.json").read_text())["point_encoder"] == "vn"
    loaded = ActionFlowPolicy.from_pretrained(tmp_path).eval()
    assert loaded.config.point_encoder == "vn"
    assert isinstance(loaded.network.point_encoder, VNPointNetEncoder)
    assert policy.state_dict().keys() == loaded.state_dict().keys()
    for k, v in policy.state_dict().items():
        assert torch.equal(v, loaded.state_dict()[k]), k
    torch.manual_seed(7)
    torch.testing.assert_close(loaded.predict_action_chunk(obs), before, atol=0, rtol=0)


def test_a_checkpoint_saved_before_point_encoder_loads_with_the_plain_pointnet():
    """Checkpoints saved before the field existed hold PointNet weights: they must load with "pointnet",
    which stays the default."""
    assert ActionFlowConfig.point_encoder == "pointnet"
    path = FIXTURES / "policy_ipa_se3"
    assert "point_encoder" not in json.loads((path / "config.json").read_text())
    assert ActionFlowPolicy.from_pretrained(path).config.point_encoder == "pointnet"
