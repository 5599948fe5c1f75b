"""The token schema is the one contract between the env, the dataset and the policy."""

from __future__ import annotations

import gym_actionflow  # noqa: F401  (registers the tasks)
import gymnasium as gym
import numpy as np
import pytest
import torch
from lerobot.envs.utils import env_to_policy_features, preprocess_observation

from lerobot_actionflow import schema
from lerobot_actionflow.env_config import ActionFlowEnvConfig


@pytest.fixture(scope="module")
def mug():
    """The observation with every modality: tokens, the hanger's point cloud and the wrist camera."""
    kwargs = {"variant": "test", "hanger_obs": "point_cloud", "obs_mode": "pixels"}
    env = gym.make("gym_actionflow/MugHanging-v0", **kwargs)
    obs, _ = env.reset(seed=0)
    yield env, obs, kwargs
    env.close()


def test_dataset_frame_matches_the_dataset_features(mug):
    """Guards against the recorder writing a frame its own feature spec does not describe."""
    env, obs, _ = mug
    features = schema.dataset_features(schema.observation_shapes(env.observation_space))
    frame = schema.dataset_frame(obs, np.zeros(schema.ACTION_DIM), "hang the mug")
    assert set(frame) == set(features) | {"task"}
    for key, spec in features.items():
        assert np.shape(frame[key]) == spec["shape"], key
    assert features["observation.images.wrist"]["dtype"] == "video"
    assert list(features) == [
        "observation.token_poses",
        "observation.token_features",
        "observation.state",
        "observation.environment_state",
        "observation.point_cloud",
        "observation.images.wrist",
        "action",
    ]


def test_policy_batch_is_what_lerobot_eval_gives_the_policy(mug):
    """Guards against the visualiser feeding the policy something other than lerobot-eval does: the batch
    equals LeRobot's own env preprocessing of the same observation, and LeRobot maps the env config's
    features to exactly the schema's policy features."""
    env, obs, kwargs = mug
    batch = schema.policy_batch(obs)
    batched = {k: v[None] for k, v in obs.items() if k != "pixels"}
    batched["pixels"] = {cam: image[None] for cam, image in obs["pixels"].items()}
    reference = preprocess_observation(batched)
    assert set(batch) == set(reference)
    for key in batch:
        torch.testing.assert_close(batch[key], reference[key], atol=0, rtol=0)
    inputs, outputs = schema.policy_features(schema.observation_shapes(env.observation_space))
    assert set(batch) == set(inputs)
    for key, feature in inputs.items():
        assert tuple(batch[key].shape) == (1, *feature.shape), key
    config = ActionFlowEnvConfig(task="MugHanging-v0", **kwargs)
    assert env_to_policy_features(config) == {**inputs, **outputs}


def test_an_unknown_observation_key_is_a_clear_error():
    with pytest.raises(KeyError, match="'tactile' is not an observation key of the token schema"):
        schema.dataset_features({"tactile": (4,)})


def test_token_names_name_the_rows_and_columns_of_the_token_keys():
    """Guards against ``names: None`` on the token keys (a dataset that does not say which row is which
    object) and against names that do not match the shapes they name."""
    env = gym.make("gym_actionflow/Coffee-v0")
    unwrapped = env.unwrapped
    shapes = schema.observation_shapes(env.observation_space)
    features = schema.dataset_features(shapes, unwrapped.token_names, unwrapped.scalar_names)
    env.close()
    tokens = ["eef", "pod", "machine", "lid"]
    assert unwrapped.token_names == tuple(tokens)
    assert features["observation.token_poses"]["names"] == {"tokens": tokens, "pose": list(schema.POSE_NAMES)}
    columns = features["observation.token_features"]["names"]["features"]
    assert columns == ["is_eef", "is_pod", "is_machine", "is_lid", "gripper_opening", "lid_angle"]
    assert len(columns) == shapes["token_features"][1]
    env_state = features["observation.environment_state"]["names"]
    assert len(env_state) == shapes["environment_state"][0] and env_state[9] == "machine.x"
    assert schema.dataset_features(shapes)["observation.token_poses"]["names"] is None  # names are optional
    with pytest.raises(ValueError, match=r"token_poses has shape \(4, 9\) but token_names \['eef', 'pod'\]"):
        schema.dataset_features(shapes, ["eef", "pod"], unwrapped.scalar_names)
