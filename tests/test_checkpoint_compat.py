"""Checkpoints saved by earlier versions keep loading and acting the same: the fixtures under tests/fixtures
were written by make_policy_fixtures.py before the policy was split into a policy over a model."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from fixtures.make_policy_fixtures import CHECKPOINTS, KEY_CONFIGS, LOSS_SEED, SAMPLE_SEED, config
from lerobot.configs import PreTrainedConfig
from safetensors.torch import load_file

from lerobot_actionflow import ActionFlowPolicy
from lerobot_actionflow.modeling_actionflow import LEGACY_DEFAULTS

FIXTURES = Path(__file__).parent / "fixtures"
OBS_KEYS = ("observation.token_poses", "observation.token_features")


@pytest.mark.parametrize("name", sorted(CHECKPOINTS))
def test_old_checkpoint_loads_every_weight_and_gives_the_same_actions_and_loss(name):
    """Guards against a refactor that renames a parameter (from_pretrained only logs missing keys, so such a
    checkpoint would load with random weights) or changes the sampler's or the loss's arithmetic."""
    path = FIXTURES / f"policy_{name}"
    policy = ActionFlowPolicy.from_pretrained(path)
    assert set(policy.state_dict()) == set(load_file(path / "model.safetensors"))
    expected = load_file(path / "expected.safetensors")
    torch.manual_seed(SAMPLE_SEED)
    chunk = policy.predict_action_chunk({k: expected[k] for k in OBS_KEYS})
    # CPU float reductions may be split differently with another thread count: equal to float32 rounding.
    torch.testing.assert_close(chunk, expected["chunk"], atol=1e-5, rtol=0)
    policy.train()
    torch.manual_seed(LOSS_SEED)
    batch = {k: v for k, v in expected.items() if k not in ("chunk", "loss")}
    loss, _ = policy.forward(batch)
    torch.testing.assert_close(loss.reshape(1), expected["loss"], atol=1e-6, rtol=1e-5)


def test_state_dict_keys_and_shapes_are_unchanged():
    """Every architecture, action space and input modality keeps the parameter names and shapes that saved
    checkpoints hold, as such a checkpoint loads (a field added since takes its legacy value)."""
    expected = json.loads((FIXTURES / "state_dict_keys.json").read_text())
    assert set(expected) == set(KEY_CONFIGS)
    for name, overrides in KEY_CONFIGS.items():
        state = ActionFlowPolicy(config(**{**LEGACY_DEFAULTS, **overrides})).state_dict()
        assert {k: list(v.shape) for k, v in state.items()} == expected[name], name


def test_a_checkpoint_saved_before_a_default_changed_keeps_its_value(tmp_path):
    """squash_limit's default became 3 after checkpoints with the paper's tanh (1) were saved without the
    field: they must load with 1, also through lerobot-eval's path (config parsed first, then passed in),
    while a new checkpoint and an explicit setting keep theirs."""

    path = FIXTURES / "policy_ipa_se3"
    assert "squash_limit" not in json.loads((path / "config.json").read_text())
    assert ActionFlowPolicy.from_pretrained(path).config.squash_limit == 1.0
    parsed = PreTrainedConfig.from_pretrained(path)
    assert parsed.squash_limit == 3.0  # LeRobot alone would use today's default ...
    assert ActionFlowPolicy.from_pretrained(path, config=parsed).config.squash_limit == 1.0  # ... not here
    parsed.squash_limit = 5.0
    assert ActionFlowPolicy.from_pretrained(path, config=parsed).config.squash_limit == 5.0
    ActionFlowPolicy(config(squash_limit=3.0)).save_pretrained(tmp_path / "new")
    assert ActionFlowPolicy.from_pretrained(tmp_path / "new").config.squash_limit == 3.0


def test_a_checkpoint_saved_before_rotation_noise_std_keeps_uniform_rotation_noise(tmp_path):
    """rotation_noise_std's default became 0.5 after checkpoints trained with the paper's uniform SO(3)
    noise were saved without the field: they load with None (uniform); one saved with the field keeps it."""
    path = FIXTURES / "policy_ipa_se3"
    assert "rotation_noise_std" not in json.loads((path / "config.json").read_text())
    old = ActionFlowPolicy.from_pretrained(path)
    assert old.config.rotation_noise_std is None and old.model.flow.rotation_noise_std is None
    new = ActionFlowPolicy(config())
    assert new.config.rotation_noise_std == 0.5 and new.model.flow.rotation_noise_std == 0.5
    new.save_pretrained(tmp_path / "new")
    assert ActionFlowPolicy.from_pretrained(tmp_path / "new").model.flow.rotation_noise_std == 0.5
    uniform = ActionFlowPolicy(config(rotation_noise_std=None))
    uniform.save_pretrained(tmp_path / "uniform")
    assert ActionFlowPolicy.from_pretrained(tmp_path / "uniform").config.rotation_noise_std is None


def test_a_euclidean_checkpoint_saved_before_euclidean_frame_keeps_the_eef_frame(tmp_path):
    """euclidean_frame's default became "action" after Euclidean-flow checkpoints were saved without the
    field, their network reading and writing the flat EEF-frame vector: they load with "eef" (the fixture's
    actions are pinned by the test above); new ones keep "action", whose network reads 3 numbers fewer."""
    path = FIXTURES / "policy_multi_token_euclidean"
    assert "euclidean_frame" not in json.loads((path / "config.json").read_text())
    old = ActionFlowPolicy.from_pretrained(path)
    assert old.config.euclidean_frame == "eef" and old.model.flow.frame == "eef"
    # lerobot-eval's path: the config parsed first (today's default), then passed in.
    parsed = PreTrainedConfig.from_pretrained(path)
    assert parsed.euclidean_frame == "action"
    assert ActionFlowPolicy.from_pretrained(path, config=parsed).model.flow.frame == "eef"
    new = ActionFlowPolicy(config(architecture="multi_token", action_space="euclidean"))
    assert new.model.flow.frame == "action"
    assert new.model.network.action_input.in_features == old.model.network.action_input.in_features - 3
    new.save_pretrained(tmp_path / "new")
    assert ActionFlowPolicy.from_pretrained(tmp_path / "new").model.flow.frame == "action"
