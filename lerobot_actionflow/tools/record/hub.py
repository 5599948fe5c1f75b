"""Sharing a recorded dataset on the Hugging Face Hub, with a dataset card (template: ``dataset_card.md``)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from lerobot_actionflow.tools.record.log import RecordingLog
from lerobot_actionflow.tools.record.recipe import Recipe
from lerobot_actionflow.tools.record.recorder import FPS


def check_hub_credentials() -> None:
    """Fail before recording anything if a push could not succeed."""
    import os

    from huggingface_hub import get_token

    if os.environ.get("HF_HUB_OFFLINE", "0") not in ("0", "", "false", "False"):
        raise RuntimeError("--push-to-hub needs the network, but HF_HUB_OFFLINE is set")
    if get_token() is None:
        raise RuntimeError(
            "--push-to-hub needs Hugging Face credentials: run `hf auth login` or set HF_TOKEN "
            "(nothing was recorded)"
        )


def dataset_card_text(recipe: Recipe, log: RecordingLog) -> str:
    """The dataset description shown on the Hub."""
    from gym_actionflow import find_task

    task = find_task(recipe.task)
    tried = sorted(log.kept_seeds + log.failed_seeds)
    template = resources.files(__package__).joinpath("dataset_card.md").read_text()
    return template.format(
        env_id=task.env_id,
        variant=recipe.variant,
        episodes=len(log.kept_seeds),
        seed_range=f"{tried[0]}..{tried[-1]}" if tried else "none",
        failed=", ".join(map(str, log.failed_seeds)) or "none",
        noise=f"{recipe.noise:g}",
        success=f"{log.success_rate:.1%}",
        obs_mode=recipe.obs_mode,
        fps=FPS,
        command=recipe.command(),
    )


def push(recipe: Recipe, root: Path, private: bool = False) -> None:
    from gym_actionflow import find_task
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    log = RecordingLog.load(root)
    ds = LeRobotDataset(recipe.repo_id, root=root)
    ds.push_to_hub(
        tags=["actionflow", "gym_actionflow", find_task(recipe.task).name],
        private=private,
        dataset_description=dataset_card_text(recipe, log),
        paper="ActionFlow: Equivariant, Accurate, and Efficient Policies with Spatially Symmetric Flow "
        "Matching",
    )
