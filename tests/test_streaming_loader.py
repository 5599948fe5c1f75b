"""The main job trains with ``--dataset.streaming=true``: LeRobot's streaming dataset must hand ActionFlow the
same training windows as the map-style LeRobotDataset, only faster."""

import synthetic as syn
import torch
from lerobot.datasets.factory import resolve_delta_timestamps
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.datasets.streaming_dataset import StreamingLeRobotDataset

from lerobot_actionflow import ActionFlowConfig

REPO_ID = "local/actionflow_synthetic_stream"


def test_streamed_windows_equal_map_style_windows(tmp_path):
    """Every frame of an epoch arrives once, with the history and action chunk (and their padding at both
    episode ends) of the map-style dataset: a streamed window that crossed into the next episode, or padded
    differently, would train the policy on actions that never followed the observation."""
    # Episodes shorter than the horizon (16): every window is padded at one end or both.
    syn.write_dataset(tmp_path / "ds", REPO_ID, episodes=4, steps=12)
    map_style = LeRobotDataset(REPO_ID, root=tmp_path / "ds")
    delta_timestamps = resolve_delta_timestamps(ActionFlowConfig(), map_style.meta)
    map_style = LeRobotDataset(REPO_ID, root=tmp_path / "ds", delta_timestamps=delta_timestamps)
    # As lerobot-train builds it with --num_workers=1 (max_num_shards is its num_workers).
    streamed = StreamingLeRobotDataset(
        REPO_ID, root=tmp_path / "ds", delta_timestamps=delta_timestamps, max_num_shards=1, return_uint8=True
    )
    seen = []
    for item in streamed:
        index = int(item["index"])
        seen.append(index)
        expected = map_style[index]
        for key, value in expected.items():
            if isinstance(value, torch.Tensor):  # scalars (timestamp, index, ...) stream as Python numbers
                got = torch.as_tensor(item[key]).to(value.dtype).reshape(value.shape)
                assert torch.equal(got, value), f"{key} differs at frame {index}"
    assert sorted(seen) == list(range(len(map_style)))
