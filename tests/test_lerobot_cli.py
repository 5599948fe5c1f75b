"""The plugin through LeRobot's own command line, on a tiny dataset written by the test."""

import importlib.metadata
import os
import subprocess
import sys
from pathlib import Path

import synthetic as syn
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors

from lerobot_actionflow import ActionFlowPolicy

REPO_ID = "local/actionflow_synthetic_reach"


def _cli(name: str) -> str:
    return str(Path(sys.executable).parent / name)


def test_distribution_is_named_for_lerobot_discovery():
    """LeRobot imports installed distributions whose name starts with lerobot_policy_ (underscores)."""
    dist = importlib.metadata.distribution("lerobot_policy_actionflow")
    assert dist.metadata["Name"] == "lerobot_policy_actionflow"


def test_synthetic_dataset_has_the_token_schema(tmp_path):
    syn.write_dataset(tmp_path / "ds", REPO_ID, episodes=2, steps=6)
    ds = LeRobotDataset(REPO_ID, root=tmp_path / "ds")
    assert ds.num_episodes == 2 and len(ds) == 12
    item = ds[0]
    assert (
        item["observation.token_poses"].shape == (3, 9)
        and item["observation.token_poses"].dtype == torch.float32
    )
    assert item["observation.token_features"].shape == (3, 4)
    assert item["observation.state"].shape == (10,) and item["action"].shape == (10,)


def test_lerobot_train_runs_actionflow_and_checkpoint_acts(tmp_path):
    syn.write_dataset(tmp_path / "ds", REPO_ID, episodes=2, steps=20)
    out = tmp_path / "train"
    env = {
        **os.environ,
        "HF_HUB_OFFLINE": "1",
        "HF_LEROBOT_HOME": str(tmp_path / "hf_home"),
        "WANDB_MODE": "disabled",
    }
    cmd = [
        _cli("lerobot-train"),
        "--policy.type=actionflow",  # found by the distribution name alone: no discover_packages_path
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        "--policy.dim=32",
        "--policy.ipa_layers=1",
        "--policy.transformer_layers=1",
        "--policy.ema_decay=0.5",  # the weights' moving average, kept through LeRobot's `update()` hook
        f"--dataset.repo_id={REPO_ID}",
        f"--dataset.root={tmp_path / 'ds'}",
        "--steps=4",
        "--batch_size=4",
        "--num_workers=0",
        "--save_freq=4",
        "--log_freq=1",
        f"--output_dir={out}",
    ]
    result = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "loss_translation" in result.stdout + result.stderr  # our loss terms were logged

    ckpt = out / "checkpoints" / "last" / "pretrained_model"
    policy = ActionFlowPolicy.from_pretrained(ckpt)
    assert policy.config.dim == 32 and policy.config.type == "actionflow"
    assert int(policy.ema_updates) == 4  # one per optimiser step
    pairs = zip(policy.ema_network.parameters(), policy.network.parameters(), strict=True)
    assert any(not torch.equal(a, w) for a, w in pairs)
    assert policy.config.input_features["observation.token_poses"].shape == (3, 9)
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(ckpt))
    ds = LeRobotDataset(REPO_ID, root=tmp_path / "ds")
    frame = ds[0]
    obs = {
        k: frame[k] for k in ("observation.token_poses", "observation.token_features", "observation.state")
    }
    action = post(policy.select_action(pre(obs)))
    assert action.shape == (1, 10) and torch.isfinite(action).all()
