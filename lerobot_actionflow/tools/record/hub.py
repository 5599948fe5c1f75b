"""Sharing a recorded dataset on the Hugging Face Hub: the folder as it is, with its card (``README.md``).

The Hub repo id is where a copy goes, not part of what was recorded: :func:`push` uploads ``<root>`` to any
repo id without touching the local dataset (its ``repo_id``, its log, its files), so a dataset can be pushed
after recording, pushed again, or pushed to a second repo.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from lerobot_actionflow.tools.record.card import CARD, dataset_card
from lerobot_actionflow.tools.record.durability import PENDING
from lerobot_actionflow.tools.record.journal import JOURNAL
from lerobot_actionflow.tools.record.log import LOG_NAME

IGNORED = ["images/*", f"meta/{JOURNAL}/*", f"meta/{PENDING}/*", "meta/actionflow_*.tmp"]
"""Not uploaded: LeRobot's temporary frame images and the recording's transient state (the journal, the
roll-back snapshot, half-written files); an unfinished recording is refused anyway
(:func:`check_pushable`)."""


def check_hub_credentials(command: str = "--push-to-hub") -> None:
    """Fail before recording or uploading anything if a push could not succeed; ``command`` names what
    needs the Hub in the message."""
    from huggingface_hub import get_token

    if os.environ.get("HF_HUB_OFFLINE", "0") not in ("0", "", "false", "False"):
        raise RuntimeError(f"{command} needs the network, but HF_HUB_OFFLINE is set; unset it to upload")
    if get_token() is None:
        raise RuntimeError(
            f"{command} needs Hugging Face credentials: run `hf auth login` or set HF_TOKEN "
            "(nothing was recorded or uploaded)"
        )


def check_pushable(root: Path) -> None:
    """A finished dataset folder: LeRobot's metadata, no episode still in the journal, a card or the
    recording log to write one from."""
    if not root.is_dir():
        raise FileNotFoundError(f"push {root}: no such folder; expected a dataset folder (its --root)")
    if not (root / "meta" / "info.json").is_file():
        raise ValueError(f"push {root}: not a LeRobot dataset (no meta/info.json); expected a dataset folder")
    journal = root / "meta" / JOURNAL
    if (root / "meta" / PENDING).exists() or (journal.is_dir() and any(journal.iterdir())):
        raise ValueError(
            f"push {root}: the recording there was interrupted and has episodes not yet finalized; run the "
            "command that recorded it again (it resumes and finishes), then push"
        )
    if not (root / CARD).is_file() and not (root / "meta" / LOG_NAME).is_file():
        raise ValueError(
            f"push {root}: no dataset card ({CARD}) and no recording log (meta/{LOG_NAME}) to write one "
            "from; expected a dataset recorded by actionflow-record"
        )


def push(root: str | Path, repo_id: str, private: bool = False) -> str:
    """Upload the dataset folder ``root`` as it is to the Hub dataset repo ``repo_id`` (created if needed;
    ``private`` for a new one) with its card, and tag it with LeRobot's codebase version as
    ``LeRobotDataset.push_to_hub`` does (LeRobot loads a Hub dataset at that tag). Nothing local changes: a
    dataset recorded before cards were written locally gets its card generated in memory. Returns the
    dataset's URL."""
    from huggingface_hub import HfApi
    from huggingface_hub.errors import RevisionNotFoundError
    from lerobot.datasets.dataset_metadata import CODEBASE_VERSION

    root = Path(root)
    check_pushable(root)
    api = HfApi()
    api.create_repo(repo_id=repo_id, repo_type="dataset", private=True if private else None, exist_ok=True)
    api.upload_folder(
        repo_id=repo_id,
        folder_path=root,
        repo_type="dataset",
        ignore_patterns=IGNORED,
        commit_message="Upload dataset recorded with actionflow-record",
    )
    if not (root / CARD).is_file():
        api.upload_file(
            path_or_fileobj=dataset_card(root).encode(),
            path_in_repo=CARD,
            repo_id=repo_id,
            repo_type="dataset",
            commit_message="Add the dataset card",
        )
    with contextlib.suppress(RevisionNotFoundError):
        api.delete_tag(repo_id, tag=CODEBASE_VERSION, repo_type="dataset")
    api.create_tag(repo_id, tag=CODEBASE_VERSION, repo_type="dataset")
    return f"https://huggingface.co/datasets/{repo_id}"
