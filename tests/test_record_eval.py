"""Recording datasets from the experts, LeRobot's commands on them, and the rerun recording of a rollout."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_actionflow.env_config import ActionFlowEnvConfig
from lerobot_actionflow.tools.record import LOG_NAME, Recipe, load_recipe, record

REPO_ID = "local/stack_d0_test"
LEROBOT_KEYS = {"timestamp", "frame_index", "episode_index", "index", "task_index", "task"}
SCHEMA = {  # Stack: 3 tokens (EEF, cube A, cube B), features = one-hot (3) + gripper opening
    "observation.token_poses": (3, 9),
    "observation.token_features": (3, 4),
    "observation.state": (10,),
    "observation.environment_state": (18,),
    "action": (10,),
}
DATASETS_DIR = Path(__file__).resolve().parents[1] / "datasets"


def _cli(name: str) -> str:
    return str(Path(sys.executable).parent / name)


def _env(tmp: Path, **extra: str) -> dict[str, str]:
    return {
        **os.environ,
        "HF_HUB_OFFLINE": "1",
        "WANDB_MODE": "disabled",
        "HF_LEROBOT_HOME": str(tmp / "hf_lerobot"),
        **extra,
    }


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("rec") / "stack"
    result = record(
        Recipe(task="Stack", variant="D0", episodes=2, repo_id=REPO_ID), root=root, progress=False
    )
    assert result.episodes == 2
    return root


@pytest.fixture(scope="module")
def checkpoint(dataset, tmp_path_factory) -> Path:
    """A tiny ActionFlow checkpoint trained for 2 steps by the real lerobot-train on the recorded dataset."""
    out = tmp_path_factory.mktemp("train") / "run"
    cmd = [
        _cli("lerobot-train"), "--policy.type=actionflow", "--policy.device=cpu",
        "--policy.push_to_hub=false",
        "--policy.dim=32", "--policy.ipa_layers=1", "--policy.transformer_layers=1",
        f"--dataset.repo_id={REPO_ID}", f"--dataset.root={dataset}", "--steps=2", "--batch_size=4",
        "--num_workers=0", "--save_freq=2", f"--output_dir={out}",
        # Evaluation during training, through the env plugin: one episode at step 2.
        "--env.type=actionflow", "--env.task=Stack-v0", "--env_eval_freq=2", "--eval.n_episodes=1",
        "--eval.batch_size=1",
    ]  # fmt: skip
    res = subprocess.run(cmd, env=_env(out.parent), capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    return out / "checkpoints" / "last" / "pretrained_model"


def test_recorded_dataset_loads_with_exactly_the_schema(dataset):
    ds = LeRobotDataset(REPO_ID, root=dataset)
    assert ds.num_episodes == 2 and ds.fps == 20
    item = ds[0]
    assert set(item) == set(SCHEMA) | LEROBOT_KEYS
    for key, shape in SCHEMA.items():
        assert tuple(item[key].shape) == shape, key
        assert item[key].dtype == torch.float32, key
    assert item["task"] == "Stack the red cube on the green cube."
    # The state is the EEF token + gripper opening; the environment state the object tokens, flattened.
    torch.testing.assert_close(item["observation.state"][:9], item["observation.token_poses"][0])
    torch.testing.assert_close(
        item["observation.environment_state"], item["observation.token_poses"][1:].flatten()
    )
    log = json.loads((dataset / "meta" / LOG_NAME).read_text())
    assert log["kept_seeds"] == [0, 1] and log["failed_seeds"] == []


def test_recorded_actions_replay_to_success(dataset):
    """The stored actions are the expert's: replaying episode 0 on seed 0 solves the task again."""
    ds = LeRobotDataset(REPO_ID, root=dataset)
    actions = [ds[i]["action"].numpy() for i in range(ds.meta.episodes["length"][0])]
    env = gym.make("gym_actionflow/Stack-v0")
    env.reset(seed=0)
    for action in actions:
        *_, info = env.step(action)
    assert info["is_success"]
    env.close()


def test_wrist_camera_is_recorded_as_video(tmp_path):
    recipe = Recipe(task="Stack", variant="D0", episodes=1, repo_id="local/px", obs_mode="pixels",
                    image_storage="video")  # fmt: skip
    record(recipe, root=tmp_path / "px", progress=False)
    ds = LeRobotDataset("local/px", root=tmp_path / "px")
    assert ds.meta.video_keys == ["observation.images.wrist"]
    image = ds[3]["observation.images.wrist"]
    assert (
        image.shape == (3, 84, 84) and image.dtype == torch.float32 and 0 <= image.min() <= image.max() <= 1
    )


@pytest.mark.parametrize(("workers", "episodes"), [(1, 4), (2, 10)])  # workers simulate ahead: a longer run
def test_interrupted_recording_keeps_finished_episodes_and_resumes(tmp_path, workers, episodes):
    root = tmp_path / "rec"
    cmd = [
        _cli("actionflow-record"), "--task", "Stack", "--episodes", str(episodes), "--repo-id", "local/int",
        "--root", str(root), "--quiet", "--workers", str(workers),
    ]  # fmt: skip
    proc = subprocess.Popen(
        cmd, env=_env(tmp_path), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    log_path = root / "meta" / LOG_NAME
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if log_path.is_file() and json.loads(log_path.read_text())["kept_seeds"]:
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the recording ended before it could be interrupted:\n" + proc.stdout.read()
    proc.send_signal(signal.SIGINT)  # Ctrl-C after the first episode
    output, _ = proc.communicate(timeout=120)
    assert proc.returncode == 130, output
    assert "run the same command again to resume" in output
    kept = json.loads(log_path.read_text())["kept_seeds"]
    assert 1 <= len(kept) < episodes
    partial = LeRobotDataset("local/int", root=root)
    assert partial.num_episodes == len(kept)
    assert len(partial) == sum(partial.meta.episodes["length"])

    done = subprocess.run(cmd, env=_env(tmp_path), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    full = LeRobotDataset("local/int", root=root)
    assert full.num_episodes == episodes
    assert json.loads(log_path.read_text())["kept_seeds"] == list(range(episodes))  # resumed, no seed twice
    # The finished episodes are unchanged by the resume.
    np.testing.assert_array_equal(full[0]["action"].numpy(), partial[0]["action"].numpy())


KILL_DURING_SECOND_EPISODE = """
import os, sys
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot_actionflow.tools.record import Recipe, record

save = LeRobotDataset.save_episode
calls = []

def save_then_die(self, *args, **kwargs):
    calls.append(1)
    save(self, *args, **kwargs)
    if len(calls) == 2:
        os._exit(9)  # killed with the episodes' files written but not finalised: no parquet footers

LeRobotDataset.save_episode = save_then_die
record(Recipe(task="Stack", variant="D0", episodes=3, repo_id="local/kill"), root=sys.argv[1], progress=False)
"""


def test_a_kill_while_an_episode_is_written_is_undone_on_resume(tmp_path):
    """A hard kill (no Python cleanup) in the middle of writing episode 2 leaves a parquet file without its
    footer, which LeRobot cannot load; the rerun removes it, restores LeRobot's metadata, writes the journaled
    episodes again (without simulating them) and ends with a valid dataset, equal to one recorded without the
    kill."""
    root = tmp_path / "kill"
    res = subprocess.run(
        [sys.executable, "-c", KILL_DURING_SECOND_EPISODE, str(root)],
        env=_env(tmp_path), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 9, res.stderr[-2000:]
    half_written = root / "data" / "chunk-000" / "file-000.parquet"  # episodes 1 and 2, not finalized
    assert half_written.is_file() and half_written.read_bytes()[-4:] != b"PAR1"  # no parquet footer
    log = json.loads((root / "meta" / LOG_NAME).read_text())
    assert log["kept_seeds"] == [0, 1]  # both durable in the journal
    assert sorted(p.name for p in (root / "meta" / "actionflow_journal").iterdir()) == ["0.npz", "1.npz"]
    recipe = Recipe(task="Stack", variant="D0", episodes=3, repo_id="local/kill")
    result = record(recipe, root=root, progress=False)
    assert result.episodes == 3 and result.log.kept_seeds == [0, 1, 2]
    assert result.replayed == 2 and result.kept_now == 1
    assert not (root / "meta" / "actionflow_pending").exists()
    assert not (root / "meta" / "actionflow_journal").exists()
    ds = LeRobotDataset("local/kill", root=root)
    assert ds.num_episodes == 3 and len(ds) == sum(ds.meta.episodes["length"])
    assert [int(e) for e in ds.meta.episodes["episode_index"]] == [0, 1, 2]
    ref_recipe = Recipe(task="Stack", variant="D0", episodes=3, repo_id="local/ref")
    reference = record(ref_recipe, root=tmp_path / "ref", progress=False)
    assert reference.episodes == 3
    ref = LeRobotDataset("local/ref", root=tmp_path / "ref")
    np.testing.assert_array_equal(
        np.stack([ds[i]["action"].numpy() for i in range(len(ds))]),
        np.stack([ref[i]["action"].numpy() for i in range(len(ref))]),
    )


def test_lerobot_eval_runs_a_checkpoint_through_env_type_actionflow(checkpoint, tmp_path):
    out = tmp_path / "eval"
    cmd = [
        _cli("lerobot-eval"), f"--policy.path={checkpoint}", "--policy.device=cpu", "--env.type=actionflow",
        "--env.task=Stack-v0", "--eval.n_episodes=2", "--eval.batch_size=2", "--seed=100000",
        f"--output_dir={out}",
    ]  # fmt: skip
    res = subprocess.run(cmd, env=_env(tmp_path), capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    info = json.loads((out / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 2  # two sub-envs in worker processes (async vector env)
    assert "pc_success" in info["overall"]
    episode = info["per_task"][0]["metrics"] if "per_task" in info else None
    assert episode is None or len(episode["successes"]) == 2
    assert list(out.rglob("*.mp4")), "lerobot-eval wrote no video"


def test_diffusion_baseline_trains_and_evaluates_through_the_same_commands(dataset, tmp_path):
    """LeRobot's diffusion policy reads observation.state + observation.environment_state: same data, same
    commands, with the benchmark's flags. Those min-max normalise the object poses (LeRobot's default mapping
    has no ENV entry and would pass them raw), and ``eval/diagnostics/open_loop.py`` reads the checkpoint back
    through its processors to raw actions, on the recorded dataset read with the policy's own windows."""
    from lerobot.policies.factory import make_pre_post_processors

    from eval.diagnostics.open_loop import demonstrations, load_policy, override, respace
    from eval.paper.profiles import DIFFUSION_FLAGS

    out = tmp_path / "diffusion"
    cmd = [
        _cli("lerobot-train"), "--policy.type=diffusion", "--policy.device=cpu", "--policy.push_to_hub=false",
        "--policy.down_dims=[32,64]", *DIFFUSION_FLAGS, "--policy.num_inference_steps=4",
        f"--dataset.repo_id={REPO_ID}", f"--dataset.root={dataset}", "--steps=2", "--batch_size=4",
        "--num_workers=0", "--save_freq=2", "--log_freq=1", f"--output_dir={out}",
    ]  # fmt: skip
    res = subprocess.run(cmd, env=_env(tmp_path), capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert "loss" in res.stdout + res.stderr
    ckpt = out / "checkpoints" / "last" / "pretrained_model"
    config = json.loads((ckpt / "config.json").read_text())
    assert config["type"] == "diffusion"
    assert "observation.environment_state" in config["input_features"]

    columns = LeRobotDataset(REPO_ID, root=dataset).hf_dataset.with_format("numpy")
    data = {k: np.stack(columns[k]) for k in SCHEMA}
    env_state = torch.from_numpy(data["observation.environment_state"])
    pre, _ = make_pre_post_processors(PreTrainedConfig.from_pretrained(ckpt), pretrained_path=str(ckpt))
    state = torch.zeros(len(env_state), 10)
    seen = pre({"observation.environment_state": env_state, "observation.state": state})
    normalised = seen["observation.environment_state"]
    varying = env_state.std(0) > 1e-4  # the cubes' positions (their rotations may barely change)
    assert normalised.abs().max() <= 1 + 1e-5, "object poses are not min-max normalised"
    assert (normalised.amax(0) - normalised.amin(0))[varying].min() > 1.99  # each spans [-1, 1]

    loaded = load_policy(ckpt)
    assert (loaded.config.n_obs_steps, loaded.horizon) == (2, 8)  # the executed actions, from the frame on
    demo = demonstrations(loaded.config, dataset, REPO_ID, loaded.horizon, episodes=1)
    length = int(LeRobotDataset(REPO_ID, root=dataset).meta.episodes["length"][0])
    assert demo.actions.shape == (length, 8, 10) and set(demo.episode.tolist()) == {0}
    np.testing.assert_array_equal(demo.actions[:, 0].numpy(), data["action"][:length])  # from the frame on
    assert demo.observations["observation.state"].shape == (length, 2, 10)  # the policy's history
    observation = {k: v[:5] for k, v in demo.observations.items()}
    predict = loaded.predict
    chunk = predict(observation)
    assert chunk.shape == (5, 8, 10) and torch.isfinite(chunk).all()
    low, high = data["action"].min(0), data["action"].max(0)  # the DDPM sample is clipped to the data's range
    assert ((chunk.numpy() >= low - 1e-4) & (chunk.numpy() <= high + 1e-4)).all()
    # The open-loop probe's --set overrides the sampler as lerobot-eval's --policy.* flags do.
    saved = PreTrainedConfig.from_pretrained(ckpt)
    settings = {"noise_scheduler_type": "DDIM", "num_inference_steps": "3", "clip_sample": "false"}
    ddim = override(saved, settings)
    assert (ddim.noise_scheduler_type, ddim.num_inference_steps, ddim.clip_sample) == ("DDIM", 3, False)
    assert saved.noise_scheduler_type == "DDPM" and saved.clip_sample  # the saved config is left alone
    with pytest.raises(SystemExit, match="no field 'num_steps'"):
        override(saved, {"num_steps": "3"})
    with pytest.raises(SystemExit, match="clip_sample=maybe: expected true or false"):
        override(saved, {"clip_sample": "maybe"})
    predict_ddim = load_policy(ckpt, {"noise_scheduler_type": "DDIM", "num_inference_steps": "3"}).predict
    torch.manual_seed(0)
    ddpm_chunk = predict(observation)
    torch.manual_seed(0)
    ddim_chunk = predict_ddim(observation)
    assert ddim_chunk.shape == (5, 8, 10) and torch.isfinite(ddim_chunk).all()
    assert not torch.allclose(ddim_chunk, ddpm_chunk)  # the same noise, another sampler: the override took
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

    policy = DiffusionPolicy.from_pretrained(ckpt, config=ddim)
    respace(policy, "trailing")  # K = 3 from the noisiest step, not from t = 100 - 100 / 3
    policy.diffusion.noise_scheduler.set_timesteps(3)
    assert policy.diffusion.noise_scheduler.timesteps.tolist() == [99, 66, 32]
    assert type(policy.diffusion.noise_scheduler).__name__ == "DDIMScheduler"
    cmd = [
        _cli("lerobot-eval"), f"--policy.path={ckpt}", "--policy.device=cpu", "--env.type=actionflow",
        "--env.task=Stack-v0", "--eval.n_episodes=1", "--eval.batch_size=1",
        f"--output_dir={tmp_path / 'ev'}",
    ]  # fmt: skip
    res = subprocess.run(cmd, env=_env(tmp_path), capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert json.loads((tmp_path / "ev" / "eval_info.json").read_text())["overall"]["n_episodes"] == 1


def test_rerun_recording_is_written_and_reads_back(checkpoint, tmp_path):
    import rerun as rr
    from lerobot.policies.factory import make_pre_post_processors
    from rerun.error_utils import RerunWarning

    from lerobot_actionflow import ActionFlowPolicy
    from lerobot_actionflow.tools.visualize import record_rollout

    policy = ActionFlowPolicy.from_pretrained(checkpoint)
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    env = gym.make("gym_actionflow/Stack-v0", obs_mode="pixels", max_episode_steps=12)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RerunWarning)  # rerun reports malformed data as warnings
        result = record_rollout(policy, pre, post, env, seed=0, path=tmp_path / "roll.rrd")
    env.close()
    assert result["steps"] == 12 and result["path"].stat().st_size > 0
    recording = rr.recording.load_recording(str(result["path"]))
    paths = {str(p) for p in recording.schema().entity_paths()} if hasattr(recording, "schema") else set()
    if not paths:  # older readers: the entity paths are in the chunk store
        paths = {c.entity_path for c in recording.chunks()}
    for entity in ("/world/scene/eef", "/world/scene/cube_a", "/world/chunk", "/world/eef_path", "/wrist"):
        assert entity in paths, (entity, sorted(paths))


# ---------------------------------------------------------------------------- bad input, nothing written


def test_unknown_task_is_a_clear_error_and_writes_nothing(tmp_path):
    res = subprocess.run(
        [_cli("actionflow-record"), "--task", "Juggle", "--episodes", "2", "--root", str(tmp_path / "x")],
        env=_env(tmp_path), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2
    assert "unknown task 'Juggle'" in res.stderr and "StackThree" in res.stderr
    assert not (tmp_path / "x").exists()
    with pytest.raises(ValueError, match="'Juggle-v0' is not a gym_actionflow task"):
        ActionFlowEnvConfig(task="Juggle-v0")


def test_env_config_passes_mughanging_options_and_refuses_them_elsewhere():
    """--env.mug_yaw / --env.hanger_obs reach gym.make for MugHanging (the paper's protocol through
    lerobot-eval) and are clear errors on any other task; a bad value fails when the env is made."""
    config = ActionFlowEnvConfig(task="MugHanging-v0", variant="scene_moved", mug_yaw="slight")
    assert config.gym_kwargs == {"variant": "scene_moved", "obs_mode": "state", "mug_yaw": "slight"}
    with pytest.raises(ValueError, match="--env.mug_yaw is a MugHanging option; the task is Stack"):
        ActionFlowEnvConfig(task="Stack-v0", mug_yaw="slight")
    with pytest.raises(ValueError, match="mug_yaw='tiny'; expected one of"):
        ActionFlowEnvConfig(task="MugHanging-v0", mug_yaw="tiny")


def test_recipe_with_a_missing_field_is_a_clear_error(tmp_path):
    recipe = tmp_path / "bad.toml"
    recipe.write_text('task = "Stack"\nvariant = "D0"\nrepo_id = "local/bad"\n')
    with pytest.raises(ValueError, match=r"missing the field\(s\) \['episodes'\]"):
        load_recipe(recipe)
    res = subprocess.run(
        [_cli("actionflow-record"), str(recipe), "--root", str(tmp_path / "x")],
        env=_env(tmp_path), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2 and "episodes" in res.stderr
    assert not (tmp_path / "x").exists()


def test_push_without_credentials_fails_before_recording(tmp_path):
    env = _env(tmp_path, HF_HOME=str(tmp_path / "hf_home"), HF_HUB_OFFLINE="0")
    env.pop("HF_TOKEN", None)
    res = subprocess.run(
        [_cli("actionflow-record"), "--task", "Stack", "--episodes", "1", "--push-to-hub", "someone/stack",
         "--root", str(tmp_path / "x")],
        env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2
    assert "needs Hugging Face credentials" in res.stderr
    assert not (tmp_path / "x").exists()


def test_dataset_card_tells_what_was_recorded_and_how(dataset):
    from lerobot_actionflow.tools.record import RecordingLog, dataset_card_text

    log = RecordingLog.load(dataset)
    recipe = Recipe(**(log.recipe | {"episodes": 2}))
    card = dataset_card_text(recipe, log)
    for text in ("gym_actionflow/Stack-v0", "`D0`", "| episodes | 2", "0..1", "expert noise | 1", "100.0%"):
        assert text in card, text
    assert "actionflow-record --task Stack --variant D0 --episodes 2 --seed 0 --noise 1" in card


def test_resuming_with_a_different_recipe_is_refused(dataset, tmp_path):
    with pytest.raises(ValueError, match="holds a different recording"):
        record(Recipe(task="Stack", variant="D1", episodes=3, repo_id=REPO_ID), root=dataset, progress=False)


def test_every_recipe_in_datasets_is_valid():
    from gym_actionflow import TASKS

    recipes = sorted(DATASETS_DIR.glob("*.toml"))
    assert len(recipes) >= 10
    names = {t.name: t for t in TASKS}
    for path in recipes:
        recipe = load_recipe(path)
        assert recipe.variant in names[recipe.task].variants, path
        assert path.stem == recipe.repo_id.split("/")[-1], path
