"""A recipe as the standard commands a LeRobot user runs: ``actionflow-record``, ``lerobot-train``,
``lerobot-eval``. The main job, the paper harness and ``actionflow-recipe`` build their command lines here, so
a printed command can be pasted and run by hand. Commands name console scripts bare (``lerobot-train``);
:func:`lerobot_actionflow.tools.run.run` finds them beside the running interpreter."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from lerobot_actionflow.recipes import TaskRecipe, _flag_value


def checkpoint(train_dir: Path) -> Path:
    """The last checkpoint ``lerobot-train`` saved under its ``--output_dir``."""
    return Path(train_dir) / "checkpoints" / "last" / "pretrained_model"


def train_command(
    recipe: TaskRecipe,
    repo_id: str,
    root: Path,
    out: Path,
    *,
    steps: int | None = None,
    device: str = "cpu",
    seed: int = 1,
    policy_type: str = "actionflow",
    extra: Sequence[str] = (),
) -> list[str]:
    """``lerobot-train`` on a recorded dataset with the recipe's settings (``steps`` overrides the recipe's).

    ``extra`` flags come after the recipe's, so a caller's ``--policy.*`` wins; a policy other than ActionFlow
    (``policy_type="diffusion"``) gets the recipe's loader, steps and batch size but not its ActionFlow
    settings."""
    train = recipe.train if steps is None else replace(recipe.train, steps=steps)
    policy = train.policy_flags() if policy_type == "actionflow" else []
    return [
        "lerobot-train", f"--policy.type={policy_type}", f"--policy.device={device}",
        "--policy.push_to_hub=false", *policy, f"--dataset.repo_id={repo_id}", f"--dataset.root={root}",
        *train.loader_flags(), f"--steps={train.steps}", f"--batch_size={train.batch_size}", *extra,
        f"--seed={seed}", f"--output_dir={out}",
    ]  # fmt: skip


def eval_command(
    recipe: TaskRecipe,
    variant: str,
    policy_path: Path,
    out: Path,
    *,
    env_kwargs: Mapping[str, Any] | None = None,
    episodes: int | None = None,
    batch_size: int | None = None,
    device: str = "cpu",
    extra: Sequence[str] = (),
) -> list[str]:
    """``lerobot-eval`` of a checkpoint on ``variant``'s layouts from the recipe's first layout seed, with
    the recorded env keywords (``--env.mug_yaw=slight``...)."""
    episodes = episodes or recipe.eval.episodes
    batch = min(batch_size or recipe.eval.batch_size, episodes)
    kwargs = [f"--env.{k}={_flag_value(v)}" for k, v in (env_kwargs or {}).items()]
    return [
        "lerobot-eval", f"--policy.path={policy_path}", f"--policy.device={device}", *extra,
        "--env.type=actionflow", f"--env.task={recipe.task}-v0", f"--env.variant={variant}", *kwargs,
        f"--eval.n_episodes={episodes}", f"--eval.batch_size={batch}", "--eval.use_async_envs=false",
        f"--seed={recipe.eval.first_seed}", f"--output_dir={out}",
    ]  # fmt: skip
