"""A checkpoint knows what it was trained on and says so: evaluated on another task, or damaged on disk, it
fails with a message naming the problem, through LeRobot's own commands."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from lerobot_actionflow import ActionFlowPolicy
from lerobot_actionflow.tools.record.recipe import Recipe
from lerobot_actionflow.tools.record.recorder import record

REPO_ID = "local/guards_stack"
STACK = "Stack the red cube on the green cube."


def _cli(name: str) -> str:
    return str(Path(sys.executable).parent / name)


def _env(tmp: Path) -> dict[str, str]:
    return {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled",
            "HF_LEROBOT_HOME": str(tmp / "hf_lerobot")}  # fmt: skip


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """A 2-step Stack checkpoint from the real lerobot-train on 2 recorded episodes."""
    tmp = tmp_path_factory.mktemp("guards")
    record(Recipe(task="Stack", variant="D0", episodes=2, repo_id=REPO_ID), root=tmp / "data", progress=False)
    cmd = [
        _cli("lerobot-train"), "--policy.type=actionflow", "--policy.device=cpu",
        "--policy.push_to_hub=false", "--policy.dim=32", "--policy.ipa_layers=1",
        "--policy.transformer_layers=1",
        f"--dataset.repo_id={REPO_ID}", f"--dataset.root={tmp / 'data'}", "--steps=2", "--batch_size=4",
        "--num_workers=0", "--save_freq=2", f"--output_dir={tmp / 'train'}",
    ]  # fmt: skip
    res = subprocess.run(cmd, env=_env(tmp), capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    return tmp / "train" / "checkpoints" / "last" / "pretrained_model"


def _eval(checkpoint: Path, task: str, tmp: Path, *extra: str) -> subprocess.CompletedProcess:
    cmd = [
        _cli("lerobot-eval"), f"--policy.path={checkpoint}", "--policy.device=cpu", *extra,
        "--env.type=actionflow", f"--env.task={task}", "--eval.n_episodes=1", "--eval.batch_size=1",
        "--eval.use_async_envs=false", "--seed=100000", f"--output_dir={tmp / 'eval'}",
    ]  # fmt: skip
    return subprocess.run(cmd, env=_env(tmp), capture_output=True, text=True, timeout=900)


def test_the_checkpoint_records_its_task(checkpoint):
    config = ActionFlowPolicy.from_pretrained(checkpoint).config
    assert config.trained_tasks == [STACK]
    assert config.token_names == ["eef", "cube_a", "cube_b"]  # from the dataset's feature names


def test_lerobot_eval_on_another_task_is_a_clear_error(checkpoint, tmp_path):
    """A Stack checkpoint on MugHanging-v0 (the same token shapes: 3 tokens of 4 features) used to run to 0 %
    with exit 0; it must fail naming both tasks and the way to run it anyway."""
    res = _eval(checkpoint, "MugHanging-v0", tmp_path)
    out = res.stdout + res.stderr
    assert res.returncode != 0
    assert f"trained on the task ['{STACK}']" in out and "Pick up the mug" in out, out[-3000:]
    assert "--policy.check_task=false" in out
    policy = ActionFlowPolicy.from_pretrained(checkpoint)
    policy.config.check_task = False  # what --policy.check_task=false sets: the foreign task is let through
    policy._check_task({"task": ["Pick up the mug and hang it by its handle on the hanger's peg."]})


def test_a_truncated_weights_file_is_named(checkpoint, tmp_path):
    damaged = tmp_path / "damaged"
    shutil.copytree(checkpoint, damaged)
    weights = damaged / "model.safetensors"
    weights.write_bytes(weights.read_bytes()[: weights.stat().st_size // 2])
    with pytest.raises(ValueError, match=f"cannot read the policy weights {weights}.*damaged or incomplete"):
        ActionFlowPolicy.from_pretrained(damaged)
