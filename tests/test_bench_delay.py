"""eval/bench/delay.py: the delayed-inference runner's exact action sequence, the jerk metric and the CLI."""

from __future__ import annotations

import math

import numpy as np
import pytest
import synthetic as syn
import torch
from helpers import make_config

from eval.bench import delay as bench_delay
from eval.bench.delay import DelayedPolicyRunner, parse_delays, reported_elapsed, rms_jerk
from lerobot_actionflow import ActionFlowPolicy, schema
from lerobot_actionflow.core import geometry as g
from lerobot_actionflow.modeling_actionflow import smooth_action

TINY = {"dim": 32, "num_heads": 4, "ipa_layers": 1, "transformer_layers": 1}
HORIZON, N_ACTION_STEPS = 8, 4


def _observation(step: int) -> dict[str, torch.Tensor]:
    """A one-step observation whose EEF x coordinate is the step number (to see which step a chunk saw)."""
    poses, feats = syn.observe(syn.sample_scenes(1, seed=step), torch.tensor([syn.GRIPPER_OPEN_WIDTH]))
    poses[:, 0, 0] = float(step)
    return {schema.TOKEN_POSES: poses, schema.TOKEN_FEATURES: feats}


def _scripted_policy(**overrides) -> tuple[ActionFlowPolicy, list[int]]:
    """A tiny ActionFlowPolicy (its real select_action: queue, skip, smoothing) whose chunks are known:
    chunk k's action j has x = 100 k + j, identity rotation, gripper 0. Also returns the steps (EEF x) of
    the observations each chunk was sampled from."""
    policy = ActionFlowPolicy(
        make_config(horizon=HORIZON, n_action_steps=N_ACTION_STEPS, control_fps=20.0, **TINY, **overrides)
    ).eval()
    queried: list[int] = []

    def chunk(batch: dict[str, torch.Tensor], noise=None) -> torch.Tensor:
        k = len(queried)
        queried.append(int(batch[schema.TOKEN_POSES][0, -1, 0, 0]))
        actions = torch.zeros(1, HORIZON, schema.ACTION_DIM)
        actions[..., :9] = g.rt_to_pose9(torch.eye(3), torch.zeros(3))
        actions[0, :, 0] = 100.0 * k + torch.arange(HORIZON)
        return actions

    policy.predict_action_chunk = chunk
    return policy, queried


def _run(runner: DelayedPolicyRunner, steps: int) -> list[torch.Tensor]:
    runner.reset()
    return [runner.act(_observation(t)) for t in range(steps)]


def _labels(actions: list[torch.Tensor]) -> list[tuple[int, int]]:
    """(chunk, index in the chunk) of each executed action of :func:`_scripted_policy`."""
    return [divmod(int(round(a[0, 0].item())), 100) for a in actions]


def test_delay_zero_executes_exactly_what_select_action_gives():
    """The runner must not change anything without a delay (smoothing and compensation on, real sampler):
    otherwise the delay-0 row would not be the policy's plain evaluation."""
    policy = ActionFlowPolicy(
        make_config(latency_compensation=True, action_smoothing=0.3, n_action_steps=3, **TINY)
    ).eval()
    policy.clock = lambda: 0.0  # instantaneous inference, as in a plain simulation
    policy.reset()
    torch.manual_seed(3)
    plain = [policy.select_action(_observation(t)) for t in range(10)]
    runner = DelayedPolicyRunner(policy, 0)
    torch.manual_seed(3)
    delayed = _run(runner, 10)
    for a, b in zip(plain, delayed, strict=True):
        assert torch.equal(a, b)


def test_without_compensation_the_previous_chunk_continues_then_the_new_chunk_runs_late():
    """Delay 2, queue of 4: chunk 1 is sampled from the observation of step 4; steps 4 and 5 run chunk 0's
    actions 4 and 5, and chunk 1 starts at its action 0 at step 6 (two steps late)."""
    policy, queried = _scripted_policy()
    actions = _run(DelayedPolicyRunner(policy, 2), 19)
    assert _labels(actions) == [(0, j) for j in range(6)] + [(1, j) for j in range(6)] + [
        (2, j) for j in range(6)
    ] + [(3, 0)]
    assert queried == [0, 4, 10, 16]  # each chunk sees the observation of the step it was asked at


def test_with_compensation_the_policy_skips_exactly_the_delayed_actions():
    """Delay 2 with latency compensation: the policy's clock sees exactly two control periods, so every
    chunk (the first one too) starts at its action 2, and the previous chunk's actions 6 and 7 fill the
    two steps of the inference."""
    policy, queried = _scripted_policy(latency_compensation=True)
    actions = _run(DelayedPolicyRunner(policy, 2), 13)
    assert _labels(actions) == [(0, j) for j in range(2, 8)] + [(1, j) for j in range(2, 8)] + [(2, 2)]
    assert queried == [0, 4, 10]


@pytest.mark.parametrize(
    ("compensation", "delay", "first_cycle"),
    [(False, 5, [0, 1, 2, 3, 4, 5, 6, 7, 7]), (True, 3, [3, 4, 5, 6, 7, 7, 7])],
)
def test_the_robot_holds_its_last_action_when_the_previous_chunk_runs_out(compensation, delay, first_cycle):
    """Chunks of 8 with a queue of 4: without compensation 4 actions remain for a 5-step delay; with it
    (skip 3) one remains for a 3-step delay. The rest of the delay repeats the last executed action."""
    policy, _ = _scripted_policy(latency_compensation=compensation)
    skip = delay if compensation else 0
    actions = _run(DelayedPolicyRunner(policy, delay), len(first_cycle) + 1)
    assert _labels(actions) == [(0, j) for j in first_cycle] + [(1, skip)]


def test_smoothing_filters_the_executed_stream_across_the_delay():
    """With smoothing, every executed action (the previous chunk's continuation and the new chunk's first
    action included) is the filter applied to the unsmoothed action of that step after the last executed
    one: the stream is one filtered sequence, not restarted from a stale action when a chunk arrives."""
    policy, _ = _scripted_policy()
    raw = _run(DelayedPolicyRunner(policy, 2), 14)
    policy, _ = _scripted_policy(action_smoothing=0.5)
    smoothed = _run(DelayedPolicyRunner(policy, 2), 14)
    expected = [raw[0]]
    for action in raw[1:]:
        expected.append(smooth_action(expected[-1], action, 0.5))
    for a, b in zip(smoothed, expected, strict=True):
        torch.testing.assert_close(a, b, atol=0, rtol=0)


def test_the_reported_delay_gives_the_policy_exactly_d_steps():
    """The policy skips int(elapsed * fps): a float one ulp under d / fps would skip d - 1."""
    for fps in (10.0, 15.0, 20.0, 30.0, 50.0, 100.0, 7.0):
        for d in range(200):
            assert int(reported_elapsed(d, fps) * fps) == d


def test_rms_jerk_of_a_cubic_path_is_its_third_derivative():
    """p(t) = a t^3 + b t^2 + c t has jerk 6 a everywhere; the third finite difference is exact on it."""
    fps = 20.0
    a, b, c = np.array([0.5, -1.0, 2.0]), np.array([0.3, 0.1, -0.2]), np.array([0.1, 0.0, 0.4])
    t = np.arange(30)[:, None] / fps
    path = a * t**3 + b * t**2 + c * t
    assert rms_jerk(path, fps) == pytest.approx(6 * np.linalg.norm(a), rel=1e-6)
    assert rms_jerk(c * t, fps) == pytest.approx(0.0, abs=1e-6)  # constant velocity: no jerk
    assert math.isnan(rms_jerk(path[:3], fps))


def test_bad_delays_are_rejected():
    assert parse_delays(["0", "50", "measured"]) == [0.0, 50.0, "measured"]
    with pytest.raises(ValueError, match="expected milliseconds >= 0 or 'measured'"):
        parse_delays(["-5"])
    with pytest.raises(ValueError, match="expected a whole number of control steps"):
        DelayedPolicyRunner(ActionFlowPolicy(make_config(**TINY)), -1)


def test_cli_writes_the_table_for_a_saved_checkpoint(tmp_path):
    """The command end to end on one Stack episode per cell with an untrained tiny checkpoint."""
    torch.manual_seed(0)
    ckpt = tmp_path / "ckpt"
    ActionFlowPolicy(make_config(**TINY)).save_pretrained(ckpt)
    args = "--task Stack --variant D0 --episodes 1 --delay-ms 100 measured".split()
    bench_delay.main(["--checkpoint", str(ckpt), *args, "--out", str(tmp_path)])
    text = (tmp_path / "delay_Stack.md").read_text()
    assert f"Command: `python -m eval.bench.delay --checkpoint {ckpt}" in text
    assert "Provenance: commit" in text
    rows = [
        line for line in text.splitlines() if line.startswith("| 100 ms") or line.startswith("| measured")
    ]
    assert len(rows) == 8  # 2 delays x compensation off / on x smoothing 0 / 0.5
    assert all("| 2 |" in row for row in rows[:4]) and all("(0/1)" in r or "(1/1)" in r for r in rows)
