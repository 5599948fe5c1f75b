"""The dataset card, ``<root>/README.md``: what was recorded, from which seeds, which token is which object
(or, in the LeRobot layout, where each camera is) and the command that reproduces it (template:
``dataset_card.md``, inside LeRobot's card with its Hub metadata).

It is written beside the data whenever a recording stops, so a recorded folder describes itself before it is
shared; ``actionflow-record push`` uploads it as it is.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from importlib import resources
from pathlib import Path

import numpy as np

from lerobot_actionflow import schema
from lerobot_actionflow.tools.record.durability import OWN_FILES
from lerobot_actionflow.tools.record.log import RecordingLog
from lerobot_actionflow.tools.record.recipe import Recipe

CARD = "README.md"
PAPER = "ActionFlow: Equivariant, Accurate, and Efficient Policies with Spatially Symmetric Flow Matching"
LICENSE = "apache-2.0"


TOKEN_FEATURES_TEXT = """\
Features follow the ActionFlow token schema: `observation.token_poses` (N, 9) world poses
`[x, y, z, r00, r10, r20, r01, r11, r21]` (position, then the first two columns of the rotation matrix;
token 0 is the end effector), `observation.token_features` (N, F) one-hot entity ids + gripper opening + task
scalars, `observation.state` (10) end-effector pose + gripper opening, `observation.environment_state` the
object poses flattened (for baselines), and `action` (10) the absolute target end-effector pose + gripper
command in [-1, 1].

Tokens (the rows of `observation.token_poses` and `observation.token_features`; `meta/info.json` names them
too, as each feature's `names`): {tokens}. Columns of `observation.token_features`: {feature_columns}."""

LEROBOT_FEATURES_TEXT = """\
Features follow the plain LeRobot layout (`obs_layout = "lerobot"`): `observation.state` (10) the
end-effector pose `[x, y, z, r00, r10, r20, r01, r11, r21]` (position, then the first two columns of the
rotation matrix) + the gripper opening in metres, {images} (videos), and `action` (10) the absolute target
end-effector pose + gripper command in [-1, 1]. No token keys and no object poses: the objects are seen only
through the cameras.

Cameras (`meta/info.json` gives them too, as each image feature's `info` entries `camera.*`). A pose is that
of MuJoCo's camera frame (the camera looks along its -z axis, x is the image's right, y its up); `world`: a
static camera's pose in the world frame (table top at z = 0); `eef`: a hand camera's fixed pose in the
end-effector frame of `observation.state` (its world pose is the end-effector pose times this one). Square
pixels, focal length (H / 2) / tan(fovy / 2) pixels, principal point at the centre.

| camera | frame | position (m) | rotation (quaternion w, x, y, z) | fovy (degrees) |
|---|---|---|---|---|
{camera_rows}

ActionFlow places each image where its camera was; the cameras' poses as its `camera_poses` option:

```bash
--policy.camera_poses='{camera_poses}'
```"""


GENERATED_HEAD = """\
Demonstrations of **`{env_id}`** (variant `{variant}`) generated with `actionflow-generate` from the
demonstrations of the source dataset `{source}`, by MimicGen's protocol: each source episode is cut into the
task's object-centric subtasks, and every generated episode replays, for each subtask, one source episode's
segment moved with the object it acts on, linked to the previous one; only successes are kept. The source
episode of each segment of each episode is listed in `meta/actionflow_generation.json`.

"""


GENERATED_ROWS = (
    ("successful expert episodes only", "successful generated episodes only"),
    ("| expert noise |", "| target jitter |"),
    ("(waypoint offsets and action jitter scale; 0 = deterministic)",
     "(per-step jitter of the targets; 0 = none)"),
    ("| expert success rate |", "| generation success rate |"),
)


POLICY_HEAD = """\
Successful rollouts of a trained policy (checkpoint `{policy}`) on **`{env_id}`** (variant `{variant}`),
recorded with `actionflow-record --policy` from the `gym_actionflow` simulation suite: each seed's layout was
run closed loop by the policy and only the episodes it finished successfully were kept. Such a recording is
a source for `actionflow-generate`.

"""
POLICY_ROWS = (
    ("successful expert episodes only", "successful policy rollouts only"),
    ("| expert noise | {noise} (waypoint offsets and action jitter scale; 0 = deterministic) |\n", ""),
    ("| expert success rate |", "| policy success rate |"),
)


def _numbers(values: list[float]) -> str:
    """Numbers as info.json has them (rounded to 1e-6), without trailing zeros: ``0.55, 0, -0.0984``."""
    return ", ".join(np.format_float_positional(v, trim="-") for v in values)


def camera_infos(features: Mapping[str, dict] | None) -> dict[str, dict]:
    """``{camera: its info's camera.* entries}`` of the image features that have them (the recorder writes
    them: :func:`lerobot_actionflow.schema.camera_info`)."""
    prefix = f"{schema.IMAGES}."
    infos = {}
    for key, feature in (features or {}).items():
        info = feature.get("info") or {}
        if key.startswith(prefix) and "camera.frame" in info:
            infos[key.removeprefix(prefix)] = info
    return infos


def camera_poses_flag(features: Mapping[str, dict] | None) -> str:
    """The value of ``--policy.camera_poses`` for a dataset's cameras: ``{front: [world, x, y, z, qw, qx, qy,
    qz], wrist: [eef, ...]}`` (a YAML mapping, which draccus parses), the pose of each camera's frame."""
    entries = []
    for camera, info in camera_infos(features).items():
        numbers = [*info["camera.pose"][:3], *info["camera.quaternion_wxyz"]]
        entries.append(f"{camera}: [{info['camera.frame']}, {_numbers(numbers)}]")
    return "{" + ", ".join(entries) + "}"


def _features_text(features: Mapping[str, dict] | None, obs_layout: str) -> str:
    """The card's paragraphs on the features: the token rows and columns, from the features' ``names``, or
    in the LeRobot layout the cameras and their poses."""
    features = features or {}
    if obs_layout == "lerobot":
        images = [key for key in features if key.startswith(f"{schema.IMAGES}.")]
        rows = [
            f"| `{camera}` | {info['camera.frame']} | {_numbers(info['camera.pose'][:3])} "
            f"| {_numbers(info['camera.quaternion_wxyz'])} | {info['camera.fovy_degrees']:g} |"
            for camera, info in camera_infos(features).items()
        ]
        return LEROBOT_FEATURES_TEXT.format(
            images=", ".join(f"`{key}` {tuple(features[key]['shape'])}" for key in images),
            camera_rows="\n".join(rows),
            camera_poses=camera_poses_flag(features),
        )
    names = features.get(schema.TOKEN_FEATURES, {}).get("names")
    if not isinstance(names, Mapping):
        return TOKEN_FEATURES_TEXT.format(
            tokens="not named in this dataset (recorded before token names)", feature_columns="not named"
        )
    tokens = ", ".join(f"{i} `{name}`" for i, name in enumerate(names["tokens"]))
    columns = ", ".join(f"`{column}`" for column in names["features"])
    return TOKEN_FEATURES_TEXT.format(tokens=tokens, feature_columns=columns)


def dataset_card_text(
    recipe: Recipe, log: RecordingLog, features: Mapping[str, dict] | None = None, fps: int | None = None
) -> str:
    """The dataset description: our part of the card. ``features`` (the dataset's, as in meta/info.json)
    name the tokens; ``fps`` defaults to the recorder's."""
    from gym_actionflow import find_task

    from lerobot_actionflow.tools.record.recorder import FPS  # here: the recorder writes cards

    task = find_task(recipe.task)
    tried = sorted(log.kept_seeds + log.failed_seeds)
    template = resources.files(__package__).joinpath("dataset_card.md").read_text()
    if recipe.source is not None or recipe.policy is not None:
        generated = recipe.source is not None
        head, rows = (GENERATED_HEAD, GENERATED_ROWS) if generated else (POLICY_HEAD, POLICY_ROWS)
        template = head + template.split("\n\n", 1)[1]
        for expert, other in rows:
            template = template.replace(expert, other)
    return template.format(
        env_id=task.env_id,
        variant=recipe.variant,
        episodes=len(log.kept_seeds),
        seed_range=f"{tried[0]}..{tried[-1]}" if tried else "none",
        failed=", ".join(map(str, log.failed_seeds)) or "none",
        noise=f"{recipe.noise:g}",
        success=f"{log.success_rate:.1%}",
        obs_mode=recipe.obs_mode,
        obs_layout=recipe.obs_layout,
        fps=FPS if fps is None else fps,
        features=_features_text(features, recipe.obs_layout),
        command=recipe.command(),
        source=recipe.source,
        policy=recipe.policy,
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
