"""The dataset card, ``<root>/README.md``: what was recorded, from which seeds, which token is which object
and the command that reproduces it (template: ``dataset_card.md``, inside LeRobot's card with its Hub
metadata).

It is written beside the data whenever a recording stops, so a recorded folder describes itself before it is
shared; ``actionflow-record push`` uploads it as it is.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from importlib import resources
from pathlib import Path

from lerobot_actionflow import schema
from lerobot_actionflow.tools.record.durability import OWN_FILES
from lerobot_actionflow.tools.record.log import RecordingLog
from lerobot_actionflow.tools.record.recipe import Recipe

CARD = "README.md"
PAPER = "ActionFlow: Equivariant, Accurate, and Efficient Policies with Spatially Symmetric Flow Matching"
LICENSE = "apache-2.0"


def _token_lines(features: Mapping[str, dict] | None) -> tuple[str, str]:
    """The token rows and the token-feature columns, from the features' ``names``."""
    names = (features or {}).get(schema.TOKEN_FEATURES, {}).get("names")
    if not isinstance(names, Mapping):
        return "not named in this dataset (recorded before token names)", "not named"
    tokens = ", ".join(f"{i} `{name}`" for i, name in enumerate(names["tokens"]))
    return tokens, ", ".join(f"`{column}`" for column in names["features"])


def dataset_card_text(
    recipe: Recipe, log: RecordingLog, features: Mapping[str, dict] | None = None, fps: int | None = None
) -> str:
    """The dataset description: our part of the card. ``features`` (the dataset's, as in meta/info.json)
    name the tokens; ``fps`` defaults to the recorder's."""
    from gym_actionflow import find_task

    from lerobot_actionflow.tools.record.recorder import FPS  # here: the recorder writes cards

    task = find_task(recipe.task)
    tried = sorted(log.kept_seeds + log.failed_seeds)
    tokens, columns = _token_lines(features)
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
        fps=FPS if fps is None else fps,
        tokens=tokens,
        feature_columns=columns,
        command=recipe.command(),
    )


def dataset_card(root: Path) -> str:
    """The whole ``README.md`` of the dataset recorded at ``root``: LeRobot's card (Hub metadata: tags,
    license, the parquet files for the dataset viewer; the structure from meta/info.json) around our
    description. Needs the recording log (``meta/actionflow_recording.json``)."""
    from gym_actionflow import find_task
    from lerobot.datasets.io_utils import load_info
    from lerobot.datasets.utils import create_lerobot_dataset_card

    log = RecordingLog.load(root)
    if log is None:
        raise FileNotFoundError(f"{root} has no recording log (meta/actionflow_recording.json) to describe")
    info = load_info(root)
    recipe = Recipe(**(log.recipe | {"episodes": max(1, len(log.kept_seeds))}))
    card = create_lerobot_dataset_card(
        tags=["actionflow", "gym_actionflow", find_task(recipe.task).name],
        dataset_info=info,
        license=LICENSE,
        dataset_description=dataset_card_text(recipe, log, info.features, info.fps),
        paper=PAPER,
    )
    return str(card)


def write_card(root: Path) -> None:
    """Write ``<root>/README.md`` atomically (a kill leaves the old card or the new one, never half of one;
    the temporary file is one of our own ``meta/actionflow_*`` files, which a roll-back leaves alone)."""
    tmp = root / f"{OWN_FILES}card.tmp"
    tmp.write_text(dataset_card(root))
    os.replace(tmp, root / CARD)
