"""The image options ``image_encoder="resnet18"``, ``image_placement="eef"`` and ``image_random_shift``:
shapes, the ResNet's architecture and gradients, the policy's SE(3) equivariance with them, the token count,
the augmentation, the config fields and their checkpoints."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import torch
from helpers import N_TOKENS, chunks_before_and_after, make_config, random_se3
from torch import nn
from torchvision.models.resnet import BasicBlock

from lerobot_actionflow import ActionFlowConfig, ActionFlowPolicy
from lerobot_actionflow.core import geometry as g
from lerobot_actionflow.core.encoders import ImageEncoder, ResNet18ImageEncoder, random_shift

FIXTURES = Path(__file__).parent / "fixtures"
IMAGE, POINTS = "observation.images.wrist", "observation.point_cloud"
DIM = 64


def _images(seed: int, size: int, lead: tuple[int, ...] = (2, 3)) -> torch.Tensor:
    """Random RGB images ``[*lead, 3, size, size]`` in [0, 1]."""
    return torch.rand(*lead, 3, size, size, generator=torch.Generator().manual_seed(seed))


def _first_conv(encoder: nn.Module) -> nn.Conv2d:
    return next(m for m in encoder.backbone.modules() if isinstance(m, nn.Conv2d))


@pytest.mark.parametrize("encoder_cls", [ImageEncoder, ResNet18ImageEncoder])
@pytest.mark.parametrize("size", [80, 48])
def test_image_encoders_keep_the_leading_dims(encoder_cls, size):
    """Images ``[B, T, 3, H, W]`` -> ``[B, T, dim]``: a reshape that mixed up batch and history would pair a
    step's image with another step's tokens."""
    torch.manual_seed(0)
    encoder = encoder_cls(DIM).eval()
    images = _images(1, size)
    with torch.no_grad():
        out = encoder(images)
        one = encoder(images[1, 2])
    assert out.shape == (2, 3, DIM)
    torch.testing.assert_close(out[1, 2], one, atol=1e-5, rtol=0)


def test_resnet18_encoder_is_a_resnet18_with_group_norm_and_keypoints():
    """The paper's encoder: torchvision's ResNet18 layout (stem 7x7 stride 2, max pooling, 4 stages of 2 basic
    blocks, 20 convolutions) with no BatchNorm left (a prediction must not depend on the batch), and a 3x3
    feature map at 80x80 reduced to spatial-softmax keypoints."""
    encoder = ResNet18ImageEncoder(DIM)
    stem = _first_conv(encoder)
    assert (stem.kernel_size, stem.stride, stem.in_channels) == ((7, 7), (2, 2), 3)
    assert any(isinstance(m, nn.MaxPool2d) for m in encoder.backbone)
    assert sum(isinstance(m, BasicBlock) for m in encoder.backbone.modules()) == 8
    assert sum(isinstance(m, nn.Conv2d) for m in encoder.backbone.modules()) == 20
    assert not any(isinstance(m, nn.modules.batchnorm._BatchNorm) for m in encoder.modules())
    assert sum(isinstance(m, nn.GroupNorm) for m in encoder.modules()) == 20
    with torch.no_grad():
        assert encoder.backbone(torch.zeros(1, 3, 80, 80)).shape == (1, 512, 3, 3)
    # Batch-size independent: one image alone gives what it gives inside a batch.
    images = _images(2, 48, (4,))
    with torch.no_grad():
        torch.testing.assert_close(encoder(images)[:1], encoder(images[:1]), atol=1e-5, rtol=0)


def test_gradients_reach_the_resnet_first_convolution():
    """Trained from scratch: the loss must reach the stem (a detached or frozen backbone would train only the
    keypoint head on random features)."""
    torch.manual_seed(0)
    encoder = ResNet18ImageEncoder(DIM)
    encoder(_images(3, 48)).square().sum().backward()
    assert _first_conv(encoder).weight.grad.abs().sum() > 0


def _observation(seed: int, size: int, b: int = 2, t: int = 2) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    rot = g.random_rotation((b, t, N_TOKENS), generator=gen)
    trans = torch.randn(b, t, N_TOKENS, 3, generator=gen) * 0.2
    return {
        "observation.token_poses": g.rt_to_pose9(rot, trans),
        "observation.token_features": torch.randn(b, t, N_TOKENS, 4, generator=gen),
        IMAGE: torch.rand(b, t, 3, size, size, generator=gen),
        POINTS: torch.randn(b, t, 32, 3, generator=gen) * 0.05 + 0.3,
    }


def _policy(image_encoder: str, image_placement: str, size: int, **overrides) -> ActionFlowPolicy:
    torch.manual_seed(0)
    cfg = make_config(
        extra_inputs={"pixels/wrist": (size, size, 3), "point_cloud": (32, 3)},
        image_encoder=image_encoder,
        image_placement=image_placement,
        **overrides,
    )
    return ActionFlowPolicy(cfg).eval()


@pytest.mark.parametrize("architecture", ["ipa", "multi_token", "single_token"])
@pytest.mark.parametrize(
    ("image_encoder", "image_placement", "size"),
    [("cnn", "eef", 32), ("resnet18", "token", 80), ("resnet18", "eef", 80)],
)
def test_policy_with_image_options_is_se3_equivariant(architecture, image_encoder, image_placement, size):
    """As test_equivariance.py::test_policy_with_image_and_point_cloud_tokens with the new options: every pose
    and the point cloud moved by a random rigid transform, the wrist images unchanged (the camera moves with
    the gripper), the sampled chunk moves by the same transform and keeps its gripper commands; the loss
    reaches the image encoder's first convolution and the image changes the actions."""
    policy = _policy(image_encoder, image_placement, size, architecture=architecture)
    obs = _observation(1, size)
    batch = {
        **obs,
        "action": torch.cat(
            [obs["observation.token_poses"][:, -1, :1].expand(2, 16, 9), torch.ones(2, 16, 1)], -1
        ),
    }
    loss, _ = policy.forward(batch)
    loss.backward()
    assert torch.isfinite(loss)
    assert _first_conv(policy.network.image_encoders["observation_images_wrist"]).weight.grad.abs().sum() > 0

    d_rot, d_trans = random_se3(2)
    actions, actions_moved, trans_err, rot_err = chunks_before_and_after(policy, obs, d_rot, d_trans)
    assert trans_err.max() < 1e-4, f"translation error {trans_err.max():.2e} m"
    assert rot_err.max() < 1e-4, f"rotation error {rot_err.max():.2e} rad"
    torch.testing.assert_close(actions_moved[..., 9], actions[..., 9], atol=1e-5, rtol=0)
    # Not trivially satisfied: another image gives other actions.
    torch.manual_seed(9)
    other = policy.predict_action_chunk({**obs, IMAGE: _images(5, size, (2, 2))})
    assert (other - actions).abs().max() > 1e-4


@pytest.mark.parametrize("architecture", ["ipa", "multi_token", "single_token"])
@pytest.mark.parametrize("image_history", [None, 1])
def test_eef_placement_has_one_token_fewer_per_step(architecture, image_history):
    """With "eef" the wrist image has no token of its own: one token fewer per imaged history step than
    "token" (single_token pools them all, so its pooling layer must be built for that count). With
    ``image_history=1`` only the current step has an image token; None gives every step one."""
    obs, n_steps = _observation(2, 32), 2
    counts = {}
    for placement in ("token", "eef"):
        policy = _policy("cnn", placement, 32, architecture=architecture, image_history=image_history)
        with torch.no_grad():
            _, scene = policy.model.encode(obs)
            policy.predict_action_chunk(obs)
        counts[placement] = scene.features.shape[1]
        if architecture == "single_token":
            assert counts[placement] == 1
            counts[placement] = policy.network.obs_pool[0].in_features // policy.config.dim
    imaged = n_steps if image_history is None else image_history
    assert counts["token"] == n_steps * (N_TOKENS + 1) + imaged  # scene tokens, the point cloud, the images
    assert counts["eef"] == n_steps * (N_TOKENS + 1)


@pytest.mark.parametrize("image_history", [None, 1])
def test_eef_placement_adds_the_image_feature_to_the_eef_token_only(image_history):
    """The paper's placement: the EEF token's feature is its own encoding plus the encoded image of the same
    step (of the imaged steps: the current one with ``image_history=1``); the other tokens do not see the
    image (before the transformer)."""
    model = _policy("cnn", "eef", 32, image_history=image_history).model
    network = model.network
    obs = _observation(3, 32)
    with torch.no_grad():
        _, scene = model.encode(obs)
        feats = network.feature_encoder(obs["observation.token_features"]) + network.step_embed[None, :, None]
        image = network.image_encoders["observation_images_wrist"](obs[IMAGE])  # [B, T, C]
    scene_feats = scene.features.unflatten(1, (2, N_TOKENS + 1))  # [B, T, N + point cloud, C]
    first = 0 if image_history is None else 2 - image_history
    torch.testing.assert_close(scene_feats[:, first:, 0], feats[:, first:, 0] + image[:, first:], atol=1e-5,
                               rtol=0)  # fmt: skip
    torch.testing.assert_close(scene_feats[:, :first, 0], feats[:, :first, 0], atol=0, rtol=0)
    torch.testing.assert_close(scene_feats[:, :, 1:N_TOKENS], feats[:, :, 1:], atol=0, rtol=0)


@pytest.mark.parametrize("placement", ["token", "eef"])
def test_image_history_one_ignores_the_earlier_images(placement):
    """``image_history=1`` (the default): the chunk depends on the current image only; a different image at
    the earlier history step leaves it bit for bit unchanged, a different current image changes it."""
    assert ActionFlowConfig.image_history == 1
    policy = _policy("cnn", placement, 32)
    obs = _observation(4, 32)
    other = _images(11, 32, (2, 2))
    chunks = []
    for images in (obs[IMAGE], torch.cat([other[:, :1], obs[IMAGE][:, 1:]], 1), torch.cat([obs[IMAGE][:, :1],
                   other[:, 1:]], 1)):  # fmt: skip
        torch.manual_seed(3)
        chunks.append(policy.predict_action_chunk({**obs, IMAGE: images}))
    torch.testing.assert_close(chunks[1], chunks[0], atol=0, rtol=0)
    assert (chunks[2] - chunks[0]).abs().max() > 1e-4


@pytest.mark.parametrize("image_history", [None, 1])
def test_image_history_token_order(image_history):
    """The observation tokens step by step, read from their positions: with ``image_history=None`` each step
    holds the scene tokens, the image (at the EEF), then the point cloud (at its centroid), the order that
    checkpoints trained before the field existed hold; with 1 the earlier step has no image token."""
    model = _policy("cnn", "token", 32, image_history=image_history).model
    obs = _observation(5, 32)
    with torch.no_grad():
        frame, scene = model.encode(obs)
    rot, trans = frame.to_local(*g.pose9_to_rt(obs["observation.token_poses"]))  # [B, T, N, 3]
    centroid = frame.points_to_local(obs[POINTS]).mean(-2)  # [B, T, 3]
    steps = []
    for t in range(2):
        image = [trans[:, t, :1]] if image_history is None or t == 1 else []
        steps += [trans[:, t], *image, centroid[:, t, None]]
    torch.testing.assert_close(scene.trans, torch.cat(steps, 1), atol=1e-6, rtol=0)


@pytest.mark.parametrize("value", [0, 3, -1])
def test_bad_image_history_is_rejected(value):
    with pytest.raises(ValueError, match=rf"image_history={value}.*n_obs_steps=2"):
        make_config(image_history=value)


def test_a_checkpoint_saved_before_image_history_loads_with_every_step():
    """Checkpoints saved before ``image_history`` existed encoded every step's image: they load with None,
    not today's default of 1."""
    path = FIXTURES / "policy_ipa_se3"
    assert "image_history" not in json.loads((path / "config.json").read_text())
    assert ActionFlowPolicy.from_pretrained(path).config.image_history is None


@pytest.mark.parametrize(
    ("field", "choices"), [("image_encoder", "('cnn', 'resnet18')"), ("image_placement", "('token', 'eef')")]
)
def test_unknown_image_option_is_rejected(field, choices):
    """A typo must fail at configuration time, naming the field, the value and the choices, instead of
    silently training today's encoder or placement."""
    with pytest.raises(ValueError, match=re.escape(f"{field}='bogus'; expected one of {choices}")):
        make_config(**{field: "bogus"})


def test_encoders_reject_images_too_small_for_their_feature_map():
    """At 32 px the ResNet's feature map is 1x1 (at 16 px the CNN's) and its keypoints are constant: the
    policy would silently ignore the camera."""
    with pytest.raises(ValueError, match=r"image_encoder='resnet18' needs H, W >= 33"):
        ActionFlowPolicy(make_config(extra_inputs={"pixels/wrist": (32, 80, 3)}, image_encoder="resnet18"))
    ActionFlowPolicy(make_config(extra_inputs={"pixels/wrist": (32, 80, 3)}))  # the CNN accepts it
    with pytest.raises(ValueError, match=r"image_encoder='cnn' needs H, W >= 17"):
        ActionFlowPolicy(make_config(extra_inputs={"pixels/wrist": (16, 80, 3)}))
    ActionFlowPolicy(make_config(extra_inputs={"pixels/wrist": (17, 17, 3)}))


def test_resnet18_eef_policy_save_load_round_trip_is_bit_exact(tmp_path):
    """Both fields are saved with the checkpoint: a resnet18 + eef policy must not come back with the CNN or
    an image token (its weights would be dropped, or an untrained token embedding added)."""
    policy = _policy("resnet18", "eef", 48, num_inference_steps=2)
    obs = _observation(4, 48)
    torch.manual_seed(7)
    before = policy.predict_action_chunk(obs)
    policy.save_pretrained(tmp_path)
    saved = json.loads((tmp_path / "config.json").read_text())
    assert (saved["image_encoder"], saved["image_placement"]) == ("resnet18", "eef")
    loaded = ActionFlowPolicy.from_pretrained(tmp_path).eval()
    assert (loaded.config.image_encoder, loaded.config.image_placement) == ("resnet18", "eef")
    assert isinstance(loaded.network.image_encoders["observation_images_wrist"], ResNet18ImageEncoder)
    assert policy.state_dict().keys() == loaded.state_dict().keys()
    for k, v in policy.state_dict().items():
        assert torch.equal(v, loaded.state_dict()[k]), k
    torch.manual_seed(7)
    torch.testing.assert_close(loaded.predict_action_chunk(obs), before, atol=0, rtol=0)


def test_a_checkpoint_saved_before_the_image_fields_loads_with_todays_image_defaults():
    """Checkpoints saved before the fields existed hold the CNN and an image token: they must load with
    "cnn" and "token", which stay the defaults."""
    assert (ActionFlowConfig.image_encoder, ActionFlowConfig.image_placement) == ("cnn", "token")
    path = FIXTURES / "policy_ipa_se3"
    saved = json.loads((path / "config.json").read_text())
    assert "image_encoder" not in saved and "image_placement" not in saved
    config = ActionFlowPolicy.from_pretrained(path).config
    assert (config.image_encoder, config.image_placement) == ("cnn", "token")


# ---------------------------------------------------------------- image_random_shift
def test_random_shift_is_an_edge_padded_crop_with_one_offset_per_sample():
    """Each sample is its frames moved by one offset of at most ``pad`` pixels each way (every history step
    alike), the uncovered border filled with the edge pixels: checked against a direct pixel-by-pixel
    reference for every offset the batch drew."""
    pad, size = 3, 12
    images = _images(0, size, lead=(16, 2))
    shifted = random_shift(images, pad, torch.Generator().manual_seed(1))
    assert shifted.shape == images.shape
    rows = torch.arange(size)
    seen = set()
    for i in range(images.shape[0]):
        matches = []
        for dy in range(-pad, pad + 1):
            for dx in range(-pad, pad + 1):
                r = (rows + dy).clamp(0, size - 1)
                c = (rows + dx).clamp(0, size - 1)
                reference = images[i][:, :, r][:, :, :, c]  # out[y, x] = in[clamp(y + dy), clamp(x + dx)]
                if torch.equal(shifted[i], reference):
                    matches.append((dy, dx))
        assert matches, f"sample {i} is not one edge-padded shift of its frames within {pad} px"
        seen.add(matches[0])
    assert len(seen) > 4, "the offsets do not vary between samples"
    assert random_shift(images, 0) is images


def test_random_shift_changes_training_only():
    """The augmentation is drawn in the training loss only: actions sampled in evaluation mode are the same
    with and without it, and the training loss on the same batch and noise is not."""
    plain = _policy("cnn", "token", 32, num_inference_steps=2)
    shifted = _policy("cnn", "token", 32, num_inference_steps=2, image_random_shift=4)
    shifted.load_state_dict(plain.state_dict())
    obs = _observation(3, 32)
    torch.manual_seed(5)
    a = plain.predict_action_chunk(obs)
    torch.manual_seed(5)
    torch.testing.assert_close(shifted.predict_action_chunk(obs), a, atol=0, rtol=0)
    action = torch.zeros(2, plain.config.horizon, 10)
    action[..., 3] = action[..., 7] = 1.0  # identity rotation columns
    valid = torch.ones(2, plain.config.horizon, dtype=torch.bool)
    losses = []
    for policy in (plain, shifted):
        policy.train()
        torch.manual_seed(9)
        losses.append(policy.model.loss(obs, action, valid)[0])
    assert not torch.equal(losses[0], losses[1])


@pytest.mark.parametrize("value", [-1, 2.5])
def test_bad_random_shift_is_rejected(value):
    with pytest.raises(ValueError, match=re.escape(f"image_random_shift={value!r}; expected an int >= 0")):
        make_config(image_random_shift=value)
