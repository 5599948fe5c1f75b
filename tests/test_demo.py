"""The main job (`make demo`) end to end at tiny sizes: its commands come from the task's recipe and run."""

from __future__ import annotations

import json

from lerobot_actionflow.tools.demo import main as demo


def test_main_job_records_trains_evaluates_and_visualises_with_the_recipe(tmp_path, capsys, monkeypatch):
    """Guards `make demo`: every stage runs, lerobot-train gets no optimiser flags (the config's defaults are
    the recipe), and MugHanging is evaluated on both layouts its recipe names."""
    monkeypatch.setenv("HF_LEROBOT_HOME", str(tmp_path / "hf"))
    monkeypatch.setenv("WANDB_MODE", "disabled")
    out = tmp_path / "demo"
    demo(["--task", "MugHanging", "--episodes", "2", "--steps", "2", "--batch-size", "4",
          "--eval-episodes", "1", "--output-dir", str(out)])  # fmt: skip
    printed = capsys.readouterr().out
    train_line = next(line for line in printed.splitlines() if "lerobot-train" in line)
    assert "--policy.action_smoothing=0.5" in train_line and "--num_workers=2" in train_line
    assert "optimizer_lr" not in train_line and "scheduler" not in train_line
    for variant in ("train", "test"):
        info = json.loads((out / "eval" / variant / "eval_info.json").read_text())
        assert info["overall"]["n_episodes"] == 1
    assert (out / "rollout.rrd").stat().st_size > 0
    assert "new test layouts" in printed and "new train layouts" in printed
