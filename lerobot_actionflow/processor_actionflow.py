"""Pre/post-processing pipelines for ActionFlow.

LeRobot's standard steps (rename -> add batch dim -> device -> normalise; unnormalise -> cpu) plus one step
that adds the batch dimension to the token observations, which LeRobot's batch step leaves alone (it only
knows 1-D states and 3-D images; a single ``(N, 9)`` token tensor would reach the policy unbatched).

ActionFlowConfig forces the normalisation of state and action features to IDENTITY, so pose tokens and the
pose parts of ``observation.state`` and ``action`` reach the network in metres and rotation columns:
mean/std scaling would shear rotation matrices and break SE(3) equivariance. The adaptation module does
the geometric normalisation instead (EEF frame, translation scale, tanh).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from lerobot.configs import PipelineFeatureType, PolicyFeature
from lerobot.processor import (
    ObservationProcessorStep,
    PolicyAction,
    PolicyProcessorPipeline,
    ProcessorStepRegistry,
    make_default_policy_processor_steps,
    make_policy_processor_pipelines,
)
from torch import Tensor

from lerobot_actionflow.configuration_actionflow import ActionFlowConfig
from lerobot_actionflow.schema import POINT_CLOUD, TOKEN_FEATURES, TOKEN_POSES


@dataclass
@ProcessorStepRegistry.register(name="actionflow_batch_tokens")
class BatchTokensProcessorStep(ObservationProcessorStep):
    """Add a leading batch dim to an unbatched token observation: poses ``(N, 9) -> (1, N, 9)``, and the
    token features and point cloud with them."""

    def observation(self, observation: dict[str, Tensor]) -> dict[str, Tensor]:
        poses = observation.get(TOKEN_POSES)
        if isinstance(poses, Tensor) and poses.dim() == 2:
            for key in (TOKEN_POSES, TOKEN_FEATURES, POINT_CLOUD):
                if isinstance(observation.get(key), Tensor):
                    observation[key] = observation[key].unsqueeze(0)
        return observation

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        return features


def make_actionflow_pre_post_processors(
    config: ActionFlowConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    s = make_default_policy_processor_steps(config, dataset_stats)
    return make_policy_processor_pipelines(
        input_steps=[
            s.rename_observations,
            s.add_batch_dim,
            BatchTokensProcessorStep(),
            s.to_device,
            s.normalize,
        ],
        output_steps=[s.unnormalize, s.to_cpu],
    )
