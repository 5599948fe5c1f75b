"""The sampler's intermediate states (``sample_trajectory``), their rerun recordings (a rollout and one
dataset frame), and the latency clock's device synchronisation."""

from __future__ import annotations

import warnings
from pathlib import Path

import gym_actionflow  # noqa: F401 - registers the gym_actionflow/ environments
import gymnasium as gym
import numpy as np
import pyarrow as pa
import pytest
import synthetic as syn
import torch
from helpers import make_config

from lerobot_actionflow import ActionFlowPolicy, make_actionflow_pre_post_processors
from lerobot_actionflow.core.flow import SE3State, time_grid
from lerobot_actionflow.tools import visualize

OBS_KEYS = ("observation.token_poses", "observation.token_features")
TINY = {"dim": 32, "num_heads": 4, "ipa_layers": 1, "transformer_layers": 1}
REPO_ID = "local/actionflow_flow_viz"
DATASET_FRAMES = 12


def _obs(b: int = 2, seed: int = 0) -> dict[str, torch.Tensor]:
    """Synthetic observations with a 2-step history: ``[B, 2, 3, 9]`` poses, ``[B, 2, 3, 4]`` features."""
    data = syn.training_windows(syn.rollout_expert(syn.sample_scenes(2, seed), 20), 2, 16)
    return {k: data[k][:b] for k in OBS_KEYS}


def _read_rrd(path: Path) -> dict[str, pa.Table]:
    """Entity path -> its rows (all chunks, static ones left out), read with rerun's own reader."""
    from rerun.experimental import RrdReader

    batches: dict[str, list[pa.RecordBatch]] = {}
    for chunk in RrdReader(path).stream():
        if not chunk.is_static:
            batches.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return {entity: pa.Table.from_batches(b) for entity, b in batches.items()}


def _seconds(column: pa.ChunkedArray) -> list[float]:
    return [ns / 1e9 for ns in column.cast(pa.int64()).to_pylist()]


def _flow_entities(table: dict[str, pa.Table]) -> list[str]:
    return sorted(
        (e for e in table if e.startswith("/world/flow/step_")), key=lambda e: int(e.split("_")[-1])
    )


# ---------------------------------------------------------------------------- sample_trajectory


@pytest.mark.parametrize(
    "overrides",
    [{}, {"action_space": "euclidean"}, {"time_schedule": "exponential", "rotation_noise_std": None}],
    ids=["se3", "euclidean", "exponential-uniform-rotations"],
)
def test_trajectory_ends_bit_exactly_at_the_sampled_chunk(overrides):
    """The trajectory repeats the sampler's computation: its last state is the chunk predict_action_chunk
    samples under the same seed, to the bit. A second copy of the sampler that drifted (another noise draw
    order, another world conversion) would show the user a flow that is not the policy's."""
    k = 3
    torch.manual_seed(0)
    policy = ActionFlowPolicy(make_config(num_inference_steps=k, **TINY, **overrides)).eval()
    obs = _obs()
    torch.manual_seed(11)
    chunk = policy.predict_action_chunk(obs)
    torch.manual_seed(11)
    flow = policy.sample_trajectory(obs)
    assert flow.actions.shape == (k + 1, 2, policy.config.horizon, 10)
    torch.testing.assert_close(flow.actions[-1], chunk, atol=0, rtol=0)
    torch.testing.assert_close(flow.times, time_grid(k, policy.config.time_schedule), atol=0, rtol=0)
    assert flow.times[0] == 0 and flow.times[-1] == 1
    assert not torch.equal(flow.actions[0], flow.actions[-1])  # the noise is not already the chunk


def test_trajectory_starts_at_the_noise_in_the_world_frame():
    """State 0 is the noise moved to the world frame: noise at the EEF frame's origin with the identity
    rotation sits exactly at the current end-effector pose (token 0 at the last history step)."""
    policy = ActionFlowPolicy(make_config(num_inference_steps=2, **TINY)).eval()
    obs = _obs()
    b, h = 2, policy.config.horizon
    noise = SE3State(torch.eye(3).expand(b, h, 3, 3), torch.zeros(b, h, 3), torch.zeros(b, h, 1))
    flow = policy.sample_trajectory(obs, noise=noise)
    eef = obs["observation.token_poses"][:, -1, 0]  # [B, 9]
    torch.testing.assert_close(flow.actions[0, ..., :9], eef[:, None].expand(b, h, 9))


def test_recording_the_flow_does_not_change_the_actions():
    """select_action with record_flow gives the same actions and keeps the K + 1 states of each chunk."""
    obs = {k: v[:, -1] for k, v in _obs().items()}
    actions = {}
    for record in (False, True):
        torch.manual_seed(0)
        policy = ActionFlowPolicy(make_config(num_inference_steps=3, n_action_steps=2, **TINY)).eval()
        policy.record_flow = record
        torch.manual_seed(3)
        actions[record] = torch.stack([policy.select_action(obs) for _ in range(5)])
        assert (policy.last_flow is not None) == record
    torch.testing.assert_close(actions[True], actions[False], atol=0, rtol=0)
    assert policy.last_flow.actions.shape[0] == 4
    assert torch.equal(policy.last_flow.actions[-1], policy.last_chunk)


# ---------------------------------------------------------------------------- the rollout recording


def test_rollout_recording_has_every_euler_step_of_every_chunk(tmp_path):
    """Each generated chunk logs K + 1 paths world/flow/step_k of H points, on the rollout's step timeline
    and on flow_t at t_k (0 ... 1); the rest of the rollout stays off flow_t."""
    from rerun.error_utils import RerunWarning

    k = 3
    torch.manual_seed(0)
    cfg = make_config(num_inference_steps=k, n_action_steps=4, **TINY)  # Stack: 3 tokens, 4 features
    policy = ActionFlowPolicy(cfg).eval()
    pre, post = make_actionflow_pre_post_processors(cfg, dataset_stats=None)
    env = gym.make("gym_actionflow/Stack-v0", max_episode_steps=6)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RerunWarning)  # rerun reports malformed data as warnings
        result = visualize.record_rollout(policy, pre, post, env, seed=0, path=tmp_path / "roll.rrd")
    env.close()
    assert result["steps"] == 6 and policy.record_flow is False  # the policy's setting is restored

    table = _read_rrd(result["path"])
    assert _flow_entities(table) == [f"/world/flow/step_{i}" for i in range(k + 1)]
    grid = time_grid(k).tolist()
    for i in range(k + 1):
        rows = table[f"/world/flow/step_{i}"]
        assert rows.column("step").to_pylist() == [0, 4]  # two chunks in 6 steps of 4 actions
        assert _seconds(rows.column("flow_t")) == pytest.approx([grid[i]] * 2, abs=1e-6)
        points = rows.column("Points3D:positions").to_pylist()
        assert [len(p) for p in points] == [cfg.horizon] * 2
        assert [len(a) for a in rows.column("Arrows3D:vectors").to_pylist()] == [3 * cfg.horizon] * 2
    assert "flow_t" not in table["/gripper/command"].column_names
    assert "flow_t" not in table["/world/chunk"].column_names


# ---------------------------------------------------------------------------- the dataset frame (CLI)


@pytest.fixture(scope="module")
def checkpoint_and_dataset(tmp_path_factory) -> tuple[Path, Path]:
    """An untrained tiny checkpoint saved as lerobot-train saves one (config, weights, processors), and a
    one-episode synthetic LeRobotDataset of the same token schema."""
    tmp = tmp_path_factory.mktemp("flow")
    syn.write_dataset(tmp / "ds", REPO_ID, episodes=1, steps=DATASET_FRAMES)
    torch.manual_seed(0)
    cfg = make_config(num_inference_steps=4, **TINY)
    ckpt = tmp / "pretrained_model"
    ActionFlowPolicy(cfg).save_pretrained(ckpt)
    for pipeline in make_actionflow_pre_post_processors(cfg, dataset_stats=None):
        pipeline.save_pretrained(ckpt)
    return ckpt, tmp / "ds"


def _flow_cli(ckpt: Path, root: Path, frame: int, out: Path) -> None:
    args = ["--root", str(root), "--repo-id", REPO_ID, "--frame", str(frame), "--out", str(out)]
    visualize.main(["flow", str(ckpt), *args])


def test_dataset_frame_flow_recording(checkpoint_and_dataset, tmp_path, capsys):
    """One frame, no environment: the scene, the expert's recorded actions from that frame on (7 real ones
    of the 16-step window, 5 frames before the episode ends) and the K + 1 Euler steps on flow_t."""
    ckpt, root = checkpoint_and_dataset
    frame, k, horizon = 5, 4, 16
    _flow_cli(ckpt, root, frame, tmp_path / "flow.rrd")
    assert "frame 5: 4 Euler steps" in capsys.readouterr().out

    table = _read_rrd(tmp_path / "flow.rrd")
    for entity in ("/world/scene/eef", "/world/scene/token_1", "/world/scene/token_2", "/world/chunk"):
        assert entity in table, (entity, sorted(table))
    assert len(table["/world/expert"].column("Points3D:positions").to_pylist()[0]) == DATASET_FRAMES - frame
    assert len(table["/world/chunk"].column("Points3D:positions").to_pylist()[0]) == horizon
    assert _flow_entities(table) == [f"/world/flow/step_{i}" for i in range(k + 1)]
    times = []
    for i in range(k + 1):
        rows = table[f"/world/flow/step_{i}"]
        assert rows.num_rows == 1 and rows.column("frame").to_pylist() == [frame]
        assert len(rows.column("Points3D:positions").to_pylist()[0]) == horizon
        assert len(rows.column("LineStrips3D:strips").to_pylist()[0][0]) == horizon
        times += _seconds(rows.column("flow_t"))
    assert times == pytest.approx(np.linspace(0, 1, k + 1), abs=1e-6)


def test_dataset_flow_is_the_policys_chunk_for_that_frame(checkpoint_and_dataset, tmp_path):
    """The recorded chunk is what the policy samples from the frame's window under the same seed."""
    ckpt, root = checkpoint_and_dataset
    policy = ActionFlowPolicy.from_pretrained(ckpt).eval()
    pre, _ = make_actionflow_pre_post_processors(policy.config, dataset_stats=None)
    dataset = visualize.load_dataset(policy.config, root, REPO_ID)
    visualize.record_dataset_flow(policy, pre, dataset, 3, tmp_path / "f.rrd", seed=5)
    torch.manual_seed(5)
    chunk = policy.predict_action_chunk({k: dataset[3][k][None] for k in OBS_KEYS})
    logged = _read_rrd(tmp_path / "f.rrd")["/world/chunk"].column("Points3D:positions").to_pylist()[0]
    np.testing.assert_array_equal(np.array(logged, dtype=np.float32), chunk[0, :, :3].numpy())


def test_out_of_range_frame_names_the_frame_and_the_dataset_length(checkpoint_and_dataset, tmp_path, capsys):
    ckpt, root = checkpoint_and_dataset
    with pytest.raises(SystemExit) as exit_info:
        _flow_cli(ckpt, root, DATASET_FRAMES, tmp_path / "x.rrd")
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert f"frame {DATASET_FRAMES} is out of range" in err and f"has {DATASET_FRAMES} frames" in err
    assert not (tmp_path / "x.rrd").exists()


@pytest.mark.parametrize("missing", ["checkpoint", "root"])
def test_missing_paths_are_clear_errors(checkpoint_and_dataset, tmp_path, capsys, missing):
    ckpt, root = checkpoint_and_dataset
    paths = {"checkpoint": ckpt, "root": root} | {missing: tmp_path / "nowhere"}
    with pytest.raises(SystemExit) as exit_info:
        _flow_cli(paths["checkpoint"], paths["root"], 0, tmp_path / "x.rrd")
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    expected = {"checkpoint": "pretrained_model directory", "root": "LeRobotDataset directory"}[missing]
    assert f"{tmp_path / 'nowhere'} does not exist" in err and expected in err


# ---------------------------------------------------------------------------- the latency clock


def test_latency_clock_synchronises_cuda_before_reading_the_end_time(monkeypatch):
    """CUDA runs kernels asynchronously: the clock must be read after the device has finished the chunk, or
    latency compensation under-counts and serves actions whose time has passed. On the CPU there is nothing
    to wait for, and torch.cuda must not be touched."""
    calls = []
    monkeypatch.setattr(torch.cuda, "synchronize", lambda device=None: calls.append(("synchronize", device)))
    torch.manual_seed(0)
    policy = ActionFlowPolicy(
        make_config(latency_compensation=True, control_fps=20.0, n_action_steps=4, **TINY)
    ).eval()
    ticks = iter([0.0, 0.12, 1.0, 1.12])

    def clock() -> float:
        calls.append("clock")
        return next(ticks)

    policy.clock = clock
    obs = {k: v[:, -1] for k, v in _obs().items()}
    policy.select_action(obs)
    assert calls == ["clock", "clock"]  # a CPU policy: no synchronisation

    cuda = torch.device("cuda", 0)
    monkeypatch.setattr(policy, "_device", lambda: cuda)  # as if the weights were on the GPU
    policy.reset()
    calls.clear()
    policy.select_action(obs)
    assert calls == ["clock", ("synchronize", cuda), "clock"]
    assert len(policy._action_queue) == 3  # still 0.12 s at 20 Hz: two actions skipped, 3 of 4 remain
