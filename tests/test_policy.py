"""ActionFlowPolicy behaviour: construction, persistence, input validation, the action queue, processors."""

import pytest
import synthetic as syn
import torch
from helpers import make_config

from lerobot_actionflow import ActionFlowConfig, ActionFlowPolicy, make_actionflow_pre_post_processors
from lerobot_actionflow.core import geometry as g
from lerobot_actionflow.core.adaptation import squash
from lerobot_actionflow.core.model import ActionFlowModel
from lerobot_actionflow.modeling_actionflow import smooth_action

OBS_KEYS = ("observation.token_poses", "observation.token_features")


def _batch(b: int = 4, seed: int = 0) -> dict[str, torch.Tensor]:
    data = syn.training_windows(syn.rollout_expert(syn.sample_scenes(2, seed), 20), 2, 16)
    return {k: v[:b] for k, v in data.items()}


def test_builds_with_defaults_and_trains_one_step():
    policy = ActionFlowPolicy(make_config())
    assert policy.config.type == "actionflow" and policy.name == "actionflow"
    loss, info = policy.forward(_batch())
    assert loss.ndim == 0 and torch.isfinite(loss)
    assert set(info) == {"loss_translation", "loss_rotation", "loss_gripper"}
    loss.backward()
    assert all(p.grad is not None for p in policy.network.head.parameters())


def test_the_model_alone_gives_the_policys_chunk_and_encodes_once_per_chunk():
    """The model under the policy is usable without LeRobot's wrapper: with the same seed it samples the
    policy's chunk. The observation is encoded once per chunk and the network runs once per Euler step."""
    torch.manual_seed(0)
    policy = ActionFlowPolicy(make_config(num_inference_steps=3)).eval()
    model = policy.model
    assert isinstance(model, ActionFlowModel) and model.network is policy.network
    obs = {k: v for k, v in _batch().items() if k in OBS_KEYS}
    torch.manual_seed(4)
    expected = policy.predict_action_chunk(obs)
    calls = {"encode": 0, "velocity": 0}
    encode, forward = model.network.encode_observation, model.network.forward

    def counting(name, fn):
        def wrapped(*args, **kwargs):
            calls[name] += 1
            return fn(*args, **kwargs)

        return wrapped

    model.network.encode_observation = counting("encode", encode)
    model.network.forward = counting("velocity", forward)
    torch.manual_seed(4)
    with torch.no_grad():
        chunk = model.sample(obs, sampler=policy.config.sampler())
    torch.testing.assert_close(chunk, expected, atol=0, rtol=0)
    assert calls == {"encode": 1, "velocity": 3}


def test_squash_limit_bounds_translations_and_keeps_near_ones():
    """The network's translation squash is bounded by its limit, is the paper's tanh at limit 1, and a larger
    limit keeps far positions apart that the tanh ties together."""
    x = torch.linspace(-20.0, 20.0, 401, dtype=torch.float64)
    assert torch.equal(squash(x), torch.tanh(x))
    for limit in (1.0, 3.0, 10.0):
        y = squash(x, limit)
        assert y.abs().max() <= limit and torch.all(y[1:] >= y[:-1])
        inside = x.abs() <= 3 * limit  # short of float saturation: strictly increasing
        assert torch.all(y[inside][1:] > y[inside][:-1])
        near = x.abs() <= 0.1 * limit
        assert torch.allclose(y[near], x[near], rtol=0.01)
    far = torch.tensor([2.5, 3.0])  # 0.25 m and 0.3 m at the default scale x10
    assert (squash(far)[1] - squash(far)[0]) < 0.01 < (squash(far, 3.0)[1] - squash(far, 3.0)[0])


def test_radial_squash_keeps_directions_and_commutes_with_rotations():
    """The radial squash maps a point to the same direction at distance ``limit * tanh(r / limit)`` (checked
    against that formula in float64), so it commutes with any rotation about the EEF, unlike the per-axis
    squash; it is the identity near the EEF, finite with a finite gradient at the EEF itself, and a wrong mode
    is refused by name."""
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(500, 3, generator=gen, dtype=torch.float64) * 4
    y = squash(x, 3.0, "radial")
    r = x.norm(dim=-1)
    torch.testing.assert_close(y.norm(dim=-1), 3.0 * torch.tanh(r / 3.0))
    torch.testing.assert_close(torch.nn.functional.cosine_similarity(x, y, dim=-1), torch.ones(500,
                               dtype=torch.float64))
    rot = g.random_rotation((), generator=gen, dtype=torch.float64)
    torch.testing.assert_close(squash(x @ rot.T, 3.0, "radial"), y @ rot.T)
    assert not torch.allclose(squash(x @ rot.T, 3.0, "axis"), squash(x, 3.0, "axis") @ rot.T, atol=1e-3)
    near = x[:50] * 0.005  # within about 5 cm * scale of the EEF
    torch.testing.assert_close(squash(near, 3.0, "radial"), near, rtol=1e-3, atol=0)
    origin = torch.zeros(1, 3, dtype=torch.float64, requires_grad=True)
    squash(origin, 3.0, "radial").sum().backward()
    assert torch.isfinite(origin.grad).all()
    with pytest.raises(ValueError, match="squash mode='round'"):
        squash(x, 3.0, "round")
    with pytest.raises(ValueError, match="squash_mode='round'"):
        ActionFlowConfig(squash_mode="round")


def test_loss_weights_are_applied():
    batch = _batch()
    policy = ActionFlowPolicy(make_config(rotation_loss_weight=0.0, gripper_loss_weight=0.0))
    torch.manual_seed(0)
    loss, info = policy.forward(batch)
    assert torch.isclose(loss, torch.tensor(info["loss_translation"]), rtol=1e-6)


def test_padded_actions_are_left_out_of_the_loss():
    """Actions past the episode end (copies of the last one) must not be learned when masking is on."""
    batch = _batch()
    batch["action_is_pad"][:] = True
    batch["action_is_pad"][:, 0] = False
    policy = ActionFlowPolicy(make_config())
    # A fixed zero velocity, so the loss is a function of the per-step targets alone (through attention,
    # padded tokens do influence the network's other outputs, as in any chunked policy).
    policy.model.velocity = lambda scene, x, t: torch.zeros(4, 16, 7)
    torch.manual_seed(0)
    loss_a, _ = policy.forward(batch)
    batch["action"][:, 1:, :3] += 5.0  # only padded steps change
    torch.manual_seed(0)
    loss_b, _ = policy.forward(batch)
    assert torch.equal(loss_a, loss_b)


@pytest.mark.parametrize("ema_decay", [0.0, 0.9])
def test_save_load_round_trip_is_bit_exact(tmp_path, ema_decay):
    torch.manual_seed(0)
    policy = ActionFlowPolicy(make_config(architecture="ipa", num_inference_steps=3, ema_decay=ema_decay))
    if ema_decay:  # a moving average that differs from the weights, and its update count, travel too
        torch.nn.init.normal_(next(policy.network.parameters()))
        policy.update()
    policy.eval()
    obs = {k: v for k, v in _batch().items() if k in OBS_KEYS}
    torch.manual_seed(7)
    before = policy.predict_action_chunk(obs)
    policy.save_pretrained(tmp_path)
    assert (tmp_path / "model.safetensors").exists() and (tmp_path / "config.json").exists()
    loaded = ActionFlowPolicy.from_pretrained(tmp_path)
    assert loaded.config.num_inference_steps == 3
    for (k, a), (_, b) in zip(policy.state_dict().items(), loaded.state_dict().items(), strict=True):
        assert torch.equal(a, b), k
    torch.manual_seed(7)
    after = loaded.predict_action_chunk(obs)
    torch.testing.assert_close(after, before, atol=0, rtol=0)


def test_ema_follows_its_recurrence_and_is_sampled_outside_training():
    """``ema_decay``: the optimiser gets the trained weights only; after each step ``update`` moves the
    average by ``d = min(decay, (1 + n) / (10 + n))``; in eval mode the chunk is the one the averaged weights
    alone would sample, in training mode the one of the trained weights."""
    torch.manual_seed(0)
    policy = ActionFlowPolicy(make_config(ema_decay=0.9, num_inference_steps=2))
    assert ActionFlowPolicy(make_config()).ema_network is None
    trained = {id(p) for p in policy.get_optim_params()}
    assert trained == {id(p) for p in policy.network.parameters()}
    assert not any(id(p) in trained for p in policy.ema_network.parameters())
    expected = [p.detach().clone() for p in policy.network.parameters()]
    opt = torch.optim.SGD(policy.get_optim_params(), lr=0.05)
    batch = _batch()
    for n in range(3):
        loss, _ = policy.forward(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        policy.update()
        d = min(0.9, (1 + n) / (10 + n))
        weights = policy.network.parameters()
        expected = [d * e + (1 - d) * w.detach() for e, w in zip(expected, weights, strict=True)]
    assert int(policy.ema_updates) == 3
    for e, avg in zip(expected, policy.ema_network.parameters(), strict=True):
        torch.testing.assert_close(avg, e)
        assert not avg.requires_grad
    pairs = zip(policy.ema_network.parameters(), policy.network.parameters(), strict=True)
    assert any(not torch.equal(a, w) for a, w in pairs)

    obs = {k: v for k, v in batch.items() if k in OBS_KEYS}
    averaged = ActionFlowPolicy(make_config(num_inference_steps=2)).eval()
    averaged.network.load_state_dict(policy.ema_network.state_dict())
    plain = ActionFlowPolicy(make_config(num_inference_steps=2)).eval()
    plain.network.load_state_dict(policy.network.state_dict())
    for mode, reference in ((False, averaged), (True, plain)):
        policy.train(mode)
        reference.train(mode)
        torch.manual_seed(3)
        chunk = policy.predict_action_chunk(obs)
        torch.manual_seed(3)
        torch.testing.assert_close(chunk, reference.predict_action_chunk(obs), atol=0, rtol=0)
    assert policy.model.network is policy.network  # the swap is undone


def test_select_action_serves_a_queue_of_n_action_steps():
    torch.manual_seed(0)
    policy = ActionFlowPolicy(make_config(n_action_steps=3)).eval()
    calls = []
    original = policy.predict_action_chunk
    policy.predict_action_chunk = lambda batch: calls.append(batch) or original(batch)
    obs = {k: v[:, -1] for k, v in _batch(2).items() if k in OBS_KEYS}  # one step, no history axis
    actions = [policy.select_action(obs) for _ in range(7)]
    assert len(calls) == 3  # at steps 0, 3 and 6
    assert calls[0]["observation.token_poses"].shape == (2, 2, 3, 9)  # history filled with the first frame
    assert all(a.shape == (2, 10) for a in actions)
    policy.reset()
    policy.select_action(obs)
    assert len(calls) == 4


def test_latency_compensation_skips_actions_whose_time_has_passed():
    """Inference that takes 0.12 s at 20 Hz: the first two actions of the new chunk are already late."""
    torch.manual_seed(0)
    policy = ActionFlowPolicy(
        make_config(latency_compensation=True, control_fps=20.0, n_action_steps=4)
    ).eval()
    ticks = iter([0.0, 0.12])
    policy.clock = lambda: next(ticks)
    obs = {k: v[:, -1] for k, v in _batch(2).items() if k in OBS_KEYS}
    torch.manual_seed(5)
    first = policy.select_action(obs)
    torch.manual_seed(5)
    chunk = policy.predict_action_chunk(obs)
    assert torch.equal(first, chunk[:, 2])
    assert len(policy._action_queue) == 3  # actions 3, 4, 5 remain


def test_action_smoothing_blends_on_se3():
    rot_a = torch.eye(3)
    rot_b = g.so3_exp(torch.tensor([0.0, 0.0, 0.4]))
    a = torch.cat([g.rt_to_pose9(rot_a, torch.zeros(3)), torch.tensor([-1.0])])
    b = torch.cat([g.rt_to_pose9(rot_b, torch.tensor([0.1, 0.0, 0.0])), torch.tensor([1.0])])
    out = smooth_action(a, b, alpha=0.75)
    trans_err, rot_err = g.pose9_errors(
        out[:9], g.rt_to_pose9(g.so3_exp(torch.tensor([0.0, 0.0, 0.1])), torch.tensor([0.025, 0.0, 0.0]))
    )
    assert trans_err < 1e-6 and rot_err < 1e-5 and torch.isclose(out[9], torch.tensor(-0.5))


def test_gripper_output_is_clamped():
    policy = ActionFlowPolicy(make_config()).eval()
    obs = {k: v for k, v in _batch().items() if k in OBS_KEYS}
    actions = policy.predict_action_chunk(obs)
    assert actions[..., 9].abs().max() <= 1.0
    rot = g.rot6d_to_matrix(actions[..., 3:9])
    assert torch.allclose(g.matrix_to_rot6d(rot), actions[..., 3:9], atol=1e-5), (
        "rotation columns orthonormal"
    )


# ---------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (
            lambda b: b.pop("observation.token_features"),
            r"missing observation key 'observation.token_features'",
        ),
        (
            lambda b: b.update({"observation.token_poses": b["observation.token_poses"][..., :7]}),
            r"observation.token_poses has shape \(4, 2, 3, 7\); expected .*\(B, T, N, 9\)",
        ),
        (
            lambda b: b.update({"observation.token_features": b["observation.token_features"][:, :, :2]}),
            r"observation.token_features has shape \(4, 2, 2, 4\) but "
            r"observation.token_poses has shape \(4, 2, 3, 9\)",
        ),
        (
            lambda b: b["observation.token_poses"].__setitem__((1, 0, 2, 4), float("nan")),
            r"observation.token_poses contains a non-finite value \(nan at index \[1, 0, 2, 4\]\)",
        ),
        (lambda b: b.update({"action": b["action"][..., :9]}), r"action has shape \(4, 16, 9\); expected"),
        (lambda b: b.pop("action"), r"missing key 'action' for training"),
    ],
    ids=["missing-key", "pose-width", "token-count", "nan-pose", "action-width", "missing-action"],
)
def test_bad_input_gives_clear_value_error(mutate, match):
    policy = ActionFlowPolicy(make_config())
    batch = _batch()
    mutate(batch)
    with pytest.raises(ValueError, match=match):
        policy.forward(batch)


def test_bad_input_at_inference_too():
    policy = ActionFlowPolicy(make_config()).eval()
    obs = {k: v.clone() for k, v in _batch().items() if k in OBS_KEYS}
    obs["observation.token_poses"][0, 0, 0, 0] = float("inf")
    with pytest.raises(ValueError, match=r"non-finite value \(inf"):
        policy.predict_action_chunk(obs)
    with pytest.raises(ValueError, match="missing observation key 'observation.token_poses'"):
        policy.select_action({"observation.token_features": obs["observation.token_features"][:, -1]})


def test_validate_features_names_what_is_missing():
    cfg = make_config()
    del cfg.input_features["observation.token_features"]
    with pytest.raises(ValueError, match=r"needs the input features \['observation.token_features'\]"):
        cfg.validate_features()
    cfg = make_config()
    cfg.output_features["action"] = cfg.output_features["action"].__class__(
        cfg.output_features["action"].type, (7,)
    )
    with pytest.raises(ValueError, match=r"action has shape \(7,\); expected \(10,\)"):
        cfg.validate_features()
    cfg = make_config()
    cfg.input_features["observation.token_poses"] = cfg.input_features["observation.token_poses"].__class__(
        cfg.input_features["observation.token_poses"].type, (3, 7)
    )
    with pytest.raises(ValueError, match=r"observation.token_poses has shape \(3, 7\); expected \(N, 9\)"):
        cfg.validate_features()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"architecture": "gnn"}, "architecture='gnn'"),
        ({"action_space": "so3"}, "action_space='so3'"),
        ({"n_action_steps": 20, "horizon": 16}, "n_action_steps=20, horizon=16"),
        ({"dim": 100, "num_heads": 8}, "dim=100, num_heads=8"),
        ({"action_smoothing": 1.0}, "action_smoothing=1.0"),
        ({"squash_limit": 0.0}, "squash_limit=0.0"),
        ({"ema_decay": 1.0}, "ema_decay=1.0"),
    ],
)
def test_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ActionFlowConfig(**kwargs)


def test_config_refuses_to_normalise_poses():
    from lerobot.configs import NormalizationMode

    with pytest.raises(ValueError, match=r"normalization_mapping\['STATE'\].*IDENTITY"):
        ActionFlowConfig(normalization_mapping={"STATE": NormalizationMode.MEAN_STD})


def test_delta_indices():
    cfg = ActionFlowConfig(n_obs_steps=3, horizon=5, n_action_steps=2)
    assert cfg.observation_delta_indices == [-2, -1, 0]
    assert cfg.action_delta_indices == [0, 1, 2, 3, 4]
    assert cfg.reward_delta_indices is None


def test_processors_batch_a_single_token_observation():
    """LeRobot's own batch step leaves (N, 9) tensors alone; ours must batch them for the policy."""
    cfg = make_config()
    pre, post = make_actionflow_pre_post_processors(cfg, dataset_stats=None)
    batch = _batch(1)
    obs = {k: batch[k][0, -1] for k in OBS_KEYS}  # (3, 9) and (3, 4): one sample, one step
    out = pre(obs)
    assert out["observation.token_poses"].shape == (1, 3, 9)
    assert torch.equal(
        out["observation.token_poses"][0], obs["observation.token_poses"]
    )  # identity normalisation
    policy = ActionFlowPolicy(cfg).eval()
    action = post(policy.select_action(out))
    assert action.shape == (1, 10)
