"""ActionFlowModel: the adaptation module, the flow and the velocity network joined: encode / loss / sample.

Plain torch, testable alone: it is built from a :class:`ModelSpec` (plain data, which
``ActionFlowConfig.model_spec()`` fills from a LeRobot config) and takes observation tensors that already have
a history axis. ``ActionFlowPolicy`` (``modeling_actionflow``) wraps it
with what LeRobot needs: input validation, the observation and action queues, and the runtime options.

Data flow for one chunk::

    token poses [B, T, N, 9] --(EEF frame of token 0 at the last step, x scale)--> local poses
    camera poses (fixed, or the EEF token's times a fixed offset) --(same frame)--> image token poses
    token features / images / points --> encoders --> SceneTokens (once per chunk)
    noise in the local frame --(K Euler steps of the flow, network velocity)--> local action poses
    --(back to the world frame)--> actions [B, H, 10] = target EEF pose (9) + gripper
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from lerobot_actionflow.core import geometry as g
from lerobot_actionflow.core.adaptation import EEFFrame
from lerobot_actionflow.core.encoders import random_shift
from lerobot_actionflow.core.flow import SE3State, euler_states, make_flow, time_grid
from lerobot_actionflow.core.network import ActionFlowNetwork, SceneTokens
from lerobot_actionflow.core.spec import ModelSpec
from lerobot_actionflow.schema import GRIPPER_DIM, POINT_CLOUD, POSE_DIM, TOKEN_FEATURES, TOKEN_POSES

LOSS_TERMS = {"translation": "translation", "rotation": "rotation", "gripper": "extra"}
"""Loss term -> the part of the flow's velocity it measures (the flow's extras are the gripper command)."""


@dataclass(frozen=True)
class Sampler:
    """How a chunk is sampled: ``steps`` Euler steps on a ``schedule`` time grid (``rate`` for the
    exponential grid). Read at every call, so an evaluation may change it on a trained model."""

    steps: int = 4
    schedule: str = "uniform"
    rate: float = 2.0


class ActionFlowModel(nn.Module):
    """The flow-matching model: ``encode`` an observation once, then ``loss`` (training) or ``sample``."""

    def __init__(self, spec: ModelSpec):
        super().__init__()
        self.spec = spec
        self.flow = make_flow(spec.action_space, GRIPPER_DIM, spec.rotation_noise_std, spec.euclidean_frame)
        self.image_keys = tuple(spec.image_keys)
        self.has_point_cloud = spec.point_cloud
        self.observation_keys = (TOKEN_POSES, TOKEN_FEATURES, *self.image_keys) + (
            (POINT_CLOUD,) if self.has_point_cloud else ()
        )
        """The observation keys the model reads, each ``[B, T, ...]``."""
        self.network = ActionFlowNetwork(spec, self.flow.network_input_dim, self.flow.velocity_dim)

    def encode(self, obs: dict[str, Tensor]) -> tuple[EEFFrame, SceneTokens]:
        """Adaptation module + encoders, once per chunk: the EEF frame of the current step and the scene
        tokens in it. ``obs`` holds :attr:`observation_keys`, each ``[B, T, ...]``."""
        rot, trans = g.pose9_to_rt(obs[TOKEN_POSES])  # [B, T, N, 3, 3], [B, T, N, 3]
        frame = EEFFrame(rot[:, -1, 0], trans[:, -1, 0], self.spec.translation_scale)
        rot_l, trans_l = frame.to_local(rot, trans)
        images = {k: obs[k] for k in self.image_keys}
        points = frame.points_to_local(obs[POINT_CLOUD]) if self.has_point_cloud else None
        cameras = {  # each camera's pose at each step, from the EEF token's: [B, T, 3, 3], [B, T, 3]
            k: frame.to_local(*camera.world_pose(rot[:, :, 0], trans[:, :, 0]))
            for k, camera in self.spec.camera_poses.items()
        }
        scene = self.network.encode_observation(obs[TOKEN_FEATURES], rot_l, trans_l, images, points, cameras)
        return frame, scene

    def velocity(self, scene: SceneTokens, x, t: Tensor) -> Tensor:
        """The network's velocity ``[B, H, D]`` at the flow's native state ``x`` and flow time ``t [B]``."""
        poses = self.flow.to_poses(x)
        return self.network(scene, poses.rot, poses.trans, self.flow.network_input(x), t)

    def loss(self, obs: dict[str, Tensor], action: Tensor, valid: Tensor) -> tuple[Tensor, dict[str, Tensor]]:
        """Flow-matching loss of world-frame actions ``[B, H, 10]``: the weighted mean squared error of the
        translation, rotation and gripper velocity terms over the ``valid [B, H]`` action steps.

        Returns the loss and each unweighted term.
        """
        shift = self.spec.image_random_shift if self.training else 0
        if shift and self.image_keys:
            obs = {**obs, **{k: random_shift(obs[k], shift) for k in self.image_keys}}
        frame, scene = self.encode(obs)
        rot1, trans1 = frame.to_local(*g.pose9_to_rt(action[..., :POSE_DIM]))
        x1 = self.flow.from_poses(SE3State(rot1, trans1, action[..., POSE_DIM:]))
        b = action.shape[0]
        x0 = self.flow.noise(b, self.spec.horizon, device=action.device, dtype=action.dtype)
        t = torch.rand(b, device=action.device, dtype=action.dtype)
        xt, target = self.flow.interpolate(x0, x1, t)
        sq_err = (self.velocity(scene, xt, t) - target) ** 2  # [B, H, D]

        valid = valid.to(sq_err.dtype)
        denom = valid.sum().clamp_min(1.0)
        parts = self.flow.velocity_parts
        terms = {
            name: (sq_err[..., parts[part]].mean(-1) * valid).sum() / denom
            for name, part in LOSS_TERMS.items()
        }
        weights = {
            "translation": self.spec.translation_loss_weight,
            "rotation": self.spec.rotation_loss_weight,
            "gripper": self.spec.gripper_loss_weight,
        }
        return sum(weights[k] * terms[k] for k in terms), terms

    def sample(self, obs: dict[str, Tensor], noise=None, sampler: Sampler = Sampler()) -> Tensor:
        """A chunk of world-frame actions ``[B, horizon, 10]`` from ``sampler.steps`` Euler steps.

        ``noise`` (optional) is the initial flow state in the EEF frame (an ``SE3State`` for ``se3``, a
        ``[B, H, 10]`` tensor for ``euclidean``); by default it is drawn from torch's global generator.
        """
        frame, _, states = self._flow_states(obs, noise, sampler)
        *_, x = states
        return self.world_actions(frame, x)

    def sample_trajectory(
        self, obs: dict[str, Tensor], noise=None, sampler: Sampler = Sampler()
    ) -> tuple[Tensor, Tensor]:
        """:meth:`sample` with every state kept: the time grid ``[K + 1]`` and the world-frame actions
        ``[K + 1, B, horizon, 10]`` at each of its points, from the noise (t = 0) to the chunk (t = 1); the
        last is :meth:`sample`'s chunk, bit for bit, under the same seed."""
        frame, grid, states = self._flow_states(obs, noise, sampler)
        return grid, torch.stack([self.world_actions(frame, x) for x in states])

    def _flow_states(self, obs: dict[str, Tensor], noise, sampler: Sampler):
        """The EEF frame, the time grid and the (lazy) Euler states of one chunk's flow."""
        frame, scene = self.encode(obs)
        b, device = obs[TOKEN_POSES].shape[0], obs[TOKEN_POSES].device
        x = noise if noise is not None else self.flow.noise(b, self.spec.horizon, device=device)
        grid = time_grid(sampler.steps, sampler.schedule, sampler.rate, device=device)
        return frame, grid, euler_states(self.flow, lambda state, t: self.velocity(scene, state, t), x, grid)

    def world_actions(self, frame: EEFFrame, x) -> Tensor:
        """A flow state (EEF frame) as world-frame actions ``[B, H, 10]``: poses to the world frame, the
        gripper command clamped to [-1, 1]."""
        poses = self.flow.to_poses(x)
        rot, trans = frame.to_world(poses.rot, poses.trans)
        return torch.cat([g.rt_to_pose9(rot, trans), poses.extra.clamp(-1.0, 1.0)], dim=-1)
