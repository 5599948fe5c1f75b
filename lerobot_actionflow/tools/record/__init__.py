"""``actionflow-record``: scripted-expert demonstrations of a gym_actionflow task into a LeRobotDataset.

One module per concern: :mod:`.recipe` (what to record), :mod:`.recorder` (the recording loop),
:mod:`.simulate` (expert episodes in seed order, here or in worker processes), :mod:`.log` (which seeds were
kept, for resuming), :mod:`.journal` (kept episodes not yet finalized in the dataset), :mod:`.durability`
(checkpoints, and the roll-back after a kill), :mod:`.card` (the dataset card, ``README.md`` beside the
data), :mod:`.hub` (upload a recorded folder as it is) and :mod:`.cli` (the command line).
"""

from lerobot_actionflow.tools.record.card import dataset_card, dataset_card_text, write_card
from lerobot_actionflow.tools.record.cli import main
from lerobot_actionflow.tools.record.hub import check_hub_credentials, push
from lerobot_actionflow.tools.record.log import LOG_NAME, RecordingLog
from lerobot_actionflow.tools.record.recipe import Recipe, check_fields, load_recipe
from lerobot_actionflow.tools.record.recorder import RecordResult, make_env, record

__all__ = [
    "LOG_NAME",
    "RecordResult",
    "Recipe",
    "RecordingLog",
    "check_fields",
    "check_hub_credentials",
    "dataset_card",
    "dataset_card_text",
    "load_recipe",
    "main",
    "make_env",
    "push",
    "record",
    "write_card",
]
