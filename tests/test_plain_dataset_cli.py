"""`lerobot-train --policy.type=actionflow` on a plain LeRobot camera dataset (observation.state with our
state names, two cameras, our action; no token keys), with the camera poses given on the command line; the
checkpoint loads and acts."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors

from lerobot_actionflow import ActionFlowPolicy
from lerobot_actionflow.core import geometry as g
from lerobot_actionflow.schema import ACTION, ACTION_NAMES, STATE, STATE_NAMES

REPO_ID = "local/actionflow_plain_cameras"
SIDE = 40
CAMERA_POSES = {  # [frame, x, y, z, qw, qx, qy, qz]; the front camera looks back at the robot along -x
    "wrist": ["eef", 0.0, 0.0, 0.05, 1.0, 0.0, 0.0, 0.0],
    "front": ["world", 0.8, 0.0, 0.4, 0.5, -0.5, -0.5, 0.5],
}
CAMERA_FLAG = "{wrist: [eef, 0, 0, 0.05, 1, 0, 0, 0]}"
"""The flag's value as typed in single quotes: a YAML mapping, as the docs and the dataset cards write it."""
FRONT_INFO = {  # the front camera's pose as actionflow-record writes it in its feature's info
    "camera.frame": "world",
    "camera.pose": [0.8, 0.0, 0.4, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0],
    "camera.quaternion_wxyz": [0.5, -0.5, -0.5, 0.5],
}


def _write_camera_dataset(root: Path, episodes: int = 2, frames: int = 10) -> None:
    """A LeRobotDataset as a user's robot records it: the EEF pose + gripper opening as the state, a wrist
    and a front camera (video; the front one says where it was, as actionflow-record writes it), the next EEF
    pose + gripper command as the action."""
    image = {"dtype": "video", "shape": (SIDE, SIDE, 3), "names": ["height", "width", "channels"]}
    features = {
        STATE: {"dtype": "float32", "shape": (10,), "names": list(STATE_NAMES)},
        "observation.images.wrist": image,
        "observation.images.front": {**image, "info": FRONT_INFO},
        ACTION: {"dtype": "float32", "shape": (10,), "names": list(ACTION_NAMES)},
    }
    ds = LeRobotDataset.create(repo_id=REPO_ID, fps=10, features=features, root=root, use_videos=True)
    gen = torch.Generator().manual_seed(0)
    rng = np.random.default_rng(0)
    for _ in range(episodes):
        rot = g.random_rotation((), gen)
        path = torch.cumsum(torch.randn(frames + 1, 3, generator=gen) * 0.01, 0) + torch.tensor(
            [0.5, 0.0, 0.3]
        )
        poses = g.rt_to_pose9(rot.expand(frames + 1, 3, 3), path)
        for i in range(frames):
            closing = float(i >= frames // 2)
            ds.add_frame({
                STATE: torch.cat([poses[i], torch.tensor([0.08 * (1 - closing)])]).numpy(),
                "observation.images.wrist": rng.integers(0, 256, (SIDE, SIDE, 3), dtype=np.uint8),
                "observation.images.front": rng.integers(0, 256, (SIDE, SIDE, 3), dtype=np.uint8),
                ACTION: torch.cat([poses[i + 1], torch.tensor([2 * closing - 1])]).numpy(),
                "task": "reach and close",
            })  # fmt: skip
        ds.save_episode()
    ds.finalize()


def test_lerobot_train_on_a_camera_dataset_with_camera_poses_from_the_command_line(tmp_path):
    """Guards the whole path a LeRobot user takes: the real command parses --policy.camera_poses (the wrist
    camera), reads the front camera's pose from the dataset, picks the state and action layouts from the
    dataset's names, trains, saves; the checkpoint acts on a frame."""
    _write_camera_dataset(tmp_path / "ds")
    out = tmp_path / "train"
    env = {
        **os.environ,
        "HF_HUB_OFFLINE": "1",
        "HF_LEROBOT_HOME": str(tmp_path / "hf_home"),
        "WANDB_MODE": "disabled",
    }
    cmd = [
        str(Path(sys.executable).parent / "lerobot-train"),
        "--policy.type=actionflow", "--policy.device=cpu", "--policy.push_to_hub=false",
        "--policy.dim=32", "--policy.ipa_layers=1", "--policy.transformer_layers=1",
        "--policy.horizon=8", "--policy.n_action_steps=4",
        f"--policy.camera_poses={CAMERA_FLAG}",
        f"--dataset.repo_id={REPO_ID}", f"--dataset.root={tmp_path / 'ds'}",
        "--steps=2", "--batch_size=2", "--num_workers=0", "--save_freq=2", "--log_freq=1",
        f"--output_dir={out}",
    ]  # fmt: skip
    result = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "loss_translation" in result.stdout + result.stderr

    ckpt = out / "checkpoints" / "last" / "pretrained_model"
    policy = ActionFlowPolicy.from_pretrained(ckpt).eval()
    cfg = policy.config
    assert (cfg.state_pose_layout, cfg.state_pose_start, cfg.state_gripper_index) == ("pose9", 0, 9)
    assert cfg.action_layout == "pose9"
    assert cfg.camera_poses == CAMERA_POSES  # from the flag and the dataset, saved, loaded back
    assert policy.model.spec.tokens_per_step == 1
    pre, post = make_pre_post_processors(cfg, pretrained_path=str(ckpt))
    frame = LeRobotDataset(REPO_ID, root=tmp_path / "ds")[3]
    obs = {k: frame[k] for k in (STATE, "observation.images.wrist", "observation.images.front")}
    action = post(policy.select_action(pre(obs)))
    assert action.shape == (1, 10) and torch.isfinite(action).all()
