"""A dataset recipe (``datasets/*.toml``): what to record, and the task's recipe for training and evaluating
on it, which the file's own ``[train]`` / ``[eval]`` tables may override."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from lerobot_actionflow.recipes import TaskRecipe, task_recipe
from lerobot_actionflow.tools.record.recipe import Recipe, read_recipe_file


@dataclass(frozen=True)
class DatasetRecipe:
    record: Recipe
    """What ``actionflow-record`` records."""
    recipe: TaskRecipe
    """How ``lerobot-train`` and ``lerobot-eval`` train and evaluate on it."""

    @classmethod
    def for_task(cls, task: str, variant: str, episodes: int, repo_id: str, **record) -> DatasetRecipe:
        """A recording of ``task`` with the task's own recipe."""
        rec = Recipe(task, variant, episodes, repo_id, **record)
        return cls(rec, task_recipe(rec.task))


def load_dataset_recipe(path: str | Path) -> DatasetRecipe:
    """Read a dataset recipe file: its record fields (checked by ``actionflow-record``'s rules) and its
    ``[train]`` / ``[eval]`` tables over the task's recipe."""
    record, tables = read_recipe_file(path)
    return DatasetRecipe(record, task_recipe(record.task).with_overrides(tables, str(path)))
