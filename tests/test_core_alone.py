"""The policy core is plain torch: usable without LeRobot, built from its own small spec."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from dataclasses import fields

import torch

from lerobot_actionflow import ActionFlowConfig
from lerobot_actionflow.core.spec import ModelSpec

BLOCK_LEROBOT = """
import importlib.abc, sys

class _NoLeRobot(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name == "lerobot" or name.startswith("lerobot."):
            raise ImportError(f"No module named {name!r} (blocked by the test)")
        return None

sys.meta_path.insert(0, _NoLeRobot())
"""


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", BLOCK_LEROBOT + textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_core_imports_builds_and_samples_where_lerobot_cannot_be_imported():
    """Guards against a LeRobot import creeping into core/ (directly or through the package's __init__):
    the core must build a model from a ModelSpec, take a loss and sample a chunk with LeRobot absent."""
    result = _run("""
        import torch
        from lerobot_actionflow.core.model import ActionFlowModel, Sampler
        from lerobot_actionflow.core.spec import ModelSpec
        assert not any(m == "lerobot" or m.startswith("lerobot.") for m in sys.modules), "lerobot imported"
        torch.manual_seed(0)
        model = ActionFlowModel(ModelSpec(tokens_per_step=3, token_feature_dim=4, dim=32, ipa_layers=1,
                                          transformer_layers=1))
        eye = torch.tensor([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0])
        obs = {"observation.token_poses": eye.repeat(2, 2, 3, 1) + 0.1 * torch.randn(2, 2, 3, 9),
               "observation.token_features": torch.randn(2, 2, 3, 4)}
        obs["observation.token_poses"][..., 3:] = eye[3:]
        action = torch.cat([obs["observation.token_poses"][:, -1, :1].repeat(1, 16, 1),
                            torch.ones(2, 16, 1)], -1)
        loss, terms = model.loss(obs, action, torch.ones(2, 16, dtype=torch.bool))
        assert torch.isfinite(loss), loss
        chunk = model.sample(obs, sampler=Sampler(steps=2))
        assert chunk.shape == (2, 16, 10), chunk.shape
        print("ok")
    """)
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.strip().endswith("ok")


def test_the_lerobot_facing_names_say_lerobot_is_missing():
    """Without LeRobot, `from lerobot_actionflow import ActionFlowConfig` names what is missing instead of a
    bare 'cannot import name'."""
    result = _run("""
        try:
            from lerobot_actionflow import ActionFlowConfig
        except ImportError as err:
            print(err)
    """)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "needs LeRobot" in result.stdout and "pip install" in result.stdout


def test_model_spec_defaults_are_the_configs_defaults():
    """One recipe: a model built from a bare ModelSpec is the model a default ActionFlowConfig builds."""
    config_fields = {f.name: f for f in fields(ActionFlowConfig)}
    for name in ModelSpec.settings():
        spec_default = ModelSpec.__dataclass_fields__[name].default
        assert name in config_fields, f"ModelSpec.{name} has no ActionFlowConfig field"
        assert config_fields[name].default == spec_default, (name, config_fields[name].default, spec_default)


def test_default_schedule_is_the_published_recipe_over_the_run():
    """Guards the measured recipe: with no --policy.* flags, `lerobot-train --steps=N` warms up over 100 steps
    to 1e-3 and decays by cosine to 1e-5 at step N, as the explicit flags
    `--policy.optimizer_lr=1e-3 --policy.scheduler_warmup_steps=100 --policy.scheduler_decay_steps=N` did
    (LeRobot's own preset, given a longer decay than the run, would also shrink the warm-up)."""
    from lerobot.optim import CosineDecayWithWarmupSchedulerConfig

    config = ActionFlowConfig()
    steps = 2000

    def lrs(scheduler_config):
        param = torch.nn.Parameter(torch.zeros(1))
        opt = config.get_optimizer_preset().build([param])
        sched = scheduler_config.build(opt, steps)
        out = []
        for _ in range(steps + 1):
            out.append(opt.param_groups[0]["lr"])
            opt.step()
            sched.step()
        return out

    ours = lrs(config.get_scheduler_preset())
    explicit = lrs(CosineDecayWithWarmupSchedulerConfig(100, steps, 1e-3, 1e-5))
    assert ours == explicit
    assert ours[0] < 2e-5 and 0.99e-3 < max(ours) <= 1e-3 and 90 <= ours.index(max(ours)) <= 110
    assert abs(ours[steps] - 1e-5) < 1e-12
