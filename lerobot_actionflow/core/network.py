"""The velocity network: observation and action tokens in, one velocity per action step out.

It sees only tensors already brought into the scaled EEF frame by :mod:`lerobot_actionflow.core.adaptation`.
The encoders turn each modality into tokens with poses; the architecture's mixer
(:mod:`lerobot_actionflow.core.mixers`, selected by ``ModelSpec.architecture``) mixes them with the action
tokens; a linear head reads one velocity per action token.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from lerobot_actionflow.core.adaptation import squash
from lerobot_actionflow.core.encoders import (
    ImageEncoder,
    PointCloudEncoder,
    ResNet18ImageEncoder,
    VectorEncoder,
    VNPointNetEncoder,
)
from lerobot_actionflow.core.mixers import MIXERS
from lerobot_actionflow.core.spec import ModelSpec


@dataclass
class SceneTokens:
    """Everything the network needs that does not change during a chunk's flow: the encoded observation
    tokens and the constant part of the action tokens, computed once per chunk and reused at every Euler step.

    ``features [B, M, C]``, ``rot [B, M, 3, 3]``, ``trans [B, M, 3]`` (scaled EEF frame, not squashed),
    ``squashed_trans [B, M, 3]`` (what IPA sees), ``action_embed [H, C]`` (the action tokens' learnable
    feature plus their index in the chunk).
    """

    features: Tensor
    rot: Tensor
    trans: Tensor
    squashed_trans: Tensor
    action_embed: Tensor


class FlowTimeEmbedding(nn.Module):
    """Flow time ``t [B]`` in [0, 1] -> ``[B, dim]`` with sinusoidal features and an MLP."""

    def __init__(self, dim: int):
        super().__init__()
        half = dim // 2
        self.register_buffer(
            "freqs", torch.exp(torch.linspace(0.0, math.log(1000.0), half)), persistent=False
        )
        self.mlp = nn.Sequential(nn.Linear(2 * half, dim), nn.GELU(), nn.Linear(dim, dim))

    def forward(self, t: Tensor) -> Tensor:
        angles = t[:, None] * self.freqs  # [B, half]
        return self.mlp(torch.cat([angles.sin(), angles.cos()], dim=-1))


class ActionFlowNetwork(nn.Module):
    """Observation and action tokens in (scaled EEF frame), one velocity per action token out."""

    def __init__(self, spec: ModelSpec, action_input_dim: int, velocity_dim: int):
        """``action_input_dim``: per-step action quantities fed as features (the gripper; the flat vector of
        the Euclidean flow); ``velocity_dim``: the flow's velocity per action step."""
        super().__init__()
        if spec.architecture not in MIXERS:
            raise ValueError(f"architecture={spec.architecture!r}; expected one of {tuple(MIXERS)}")
        self.spec, dim = spec, spec.dim
        self.feature_encoder = VectorEncoder(spec.token_feature_dim, dim)
        image_encoder = ResNet18ImageEncoder if spec.image_encoder == "resnet18" else ImageEncoder
        self.image_encoders = nn.ModuleDict({_module_key(k): image_encoder(dim) for k in spec.image_keys})
        point_encoder = VNPointNetEncoder if spec.point_encoder == "vn" else PointCloudEncoder
        self.point_encoder = point_encoder(dim) if spec.point_cloud else None
        image_tokens = len(spec.image_keys) if spec.image_placement == "token" else 0
        extra_tokens = image_tokens + int(spec.point_cloud)
        # Which entity kind (scene token, each camera, the point cloud) and which history step a token is.
        self.extra_token_embed = nn.Parameter(torch.randn(max(extra_tokens, 1), dim) * 0.02)
        self.step_embed = nn.Parameter(torch.randn(spec.n_obs_steps, dim) * 0.02)
        # Action tokens: a learnable feature, their index in the chunk, the flow time, their current values.
        self.action_feature = nn.Parameter(torch.randn(dim) * 0.02)
        self.action_index_embed = nn.Parameter(torch.randn(spec.horizon, dim) * 0.02)
        self.time_embed = FlowTimeEmbedding(dim)
        self.action_input = nn.Linear(action_input_dim, dim)
        # The architecture's own modules, registered on the network under the names checkpoints hold.
        self.mix = MIXERS[spec.architecture]
        self.image_steps = spec.n_obs_steps if spec.image_history is None else spec.image_history
        """How many of the latest observation steps have their images encoded (``spec.image_history``)."""
        num_obs_tokens = spec.n_obs_steps * (spec.tokens_per_step + int(spec.point_cloud))
        num_obs_tokens += self.image_steps * image_tokens
        for name, module in self.mix.build(spec, num_obs_tokens).items():
            self.add_module(name, module)
        self.head = nn.Linear(dim, velocity_dim)

    def encode_observation(
        self,
        features: Tensor,
        rot: Tensor,
        trans: Tensor,
        images: dict[str, Tensor] | None = None,
        points: Tensor | None = None,
        image_poses: dict[str, tuple[Tensor, Tensor]] | None = None,
    ) -> SceneTokens:
        """Encode the observation (and the constant part of the action tokens) once per chunk.

        features ``[B, T, N, F]``; rot ``[B, T, N, 3, 3]``, trans ``[B, T, N, 3]`` in the scaled EEF frame;
        images ``{key: [B, T, 3, H, W]}`` in [0, 1], each a token posed where its camera was
        (``image_poses[key]``: rot ``[B, T, 3, 3]``, trans ``[B, T, 3]`` in the scaled EEF frame) or, without
        an entry there, at the EEF token of its step (``image_placement="token"``), or added to that EEF
        token's feature (``"eef"``); points
        ``[B, T, P, 3]`` in the scaled EEF frame, posed at their centroid with the identity rotation
        (``"pointnet"``) or the Vector-Neuron encoder's frame (``"vn"``).
        """
        b, t_steps, n, _ = features.shape
        k = self.image_steps
        s = self.feature_encoder(features)  # [B, T, N, C]
        if self.spec.image_placement == "eef" and self.spec.image_keys:
            # The camera is the EEF token's sensor: its image becomes part of that token's feature.
            encoded = [self.image_encoders[_module_key(c)](images[c][:, -k:]) for c in self.spec.image_keys]
            img = torch.stack(encoded).sum(0)  # [B, k, C]
            eef = torch.cat([s[:, : t_steps - k, :1], s[:, t_steps - k :, :1] + img[:, :, None]], dim=1)
            s = torch.cat([eef, s[:, :, 1:]], dim=2)
        # Tokens of every step (the scene, the point cloud) and of the last k steps only (the cameras).
        every, last = ([s], [rot], [trans]), ([], [], [])
        extra = 0
        for key in self.spec.image_keys if self.spec.image_placement == "token" else ():
            img = self.image_encoders[_module_key(key)](images[key][:, -k:])  # [B, k, C]
            cam_rot, cam_trans = (image_poses or {}).get(key, (rot[:, :, 0], trans[:, :, 0]))
            _append(last, (img + self.extra_token_embed[extra])[:, :, None], cam_rot[:, -k:, None],
                    cam_trans[:, -k:, None])  # fmt: skip
            extra += 1
        if self.point_encoder is not None:
            centroid = points.mean(dim=-2)  # [B, T, 3]
            centred = points - centroid[:, :, None]
            if self.spec.point_encoder == "vn":
                pc, pc_rot = self.point_encoder(centred)  # [B, T, C] invariant, [B, T, 3, 3] equivariant
                pc_rot = pc_rot[:, :, None]
            else:
                pc = self.point_encoder(centred)  # [B, T, C]
                pc_rot = torch.eye(3, dtype=rot.dtype, device=rot.device).expand(b, t_steps, 1, 3, 3)
            _append(every, (pc + self.extra_token_embed[extra])[:, :, None], pc_rot, centroid[:, :, None])
        s, rot, trans = _step_tokens(every, last, k, self.step_embed)  # [B, M, ...]
        s = self.mix.observe(self, s, rot, trans)
        squashed = squash(trans, self.spec.squash_limit, self.spec.squash_mode)
        return SceneTokens(s, rot, trans, squashed, self.action_feature + self.action_index_embed)

    def forward(
        self, scene: SceneTokens, act_rot: Tensor, act_trans: Tensor, act_input: Tensor, t: Tensor
    ) -> Tensor:
        """Velocity ``[B, H, D_v]`` of action tokens at ``act_rot [B, H, 3, 3]``, ``act_trans [B, H, 3]``
        (scaled EEF frame), with per-step inputs ``act_input [B, H, a]`` at flow time ``t [B]``."""
        a = scene.action_embed + self.time_embed(t)[:, None] + self.action_input(act_input)  # [B, H, C]
        out = self.mix.mix(self, scene, a, act_rot, act_trans)
        return self.head(out[:, -a.shape[1] :])


def _append(tokens: tuple[list, list, list], feats: Tensor, rot: Tensor, trans: Tensor) -> None:
    """Add one kind of token ``[B, T', 1, ...]`` (features, rotations, translations) to a group."""
    for group, x in zip(tokens, (feats, rot, trans), strict=True):
        group.append(x)


def _step_tokens(
    every: tuple[list, list, list], last: tuple[list, list, list], k: int, step_embed: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """The observation tokens as one sequence ``[B, M, C]``, ``[B, M, 3, 3]``, ``[B, M, 3]``, step by step:
    each step's tokens of ``every`` step (``[B, T, n, ...]``: the scene and the point cloud, the last of
    them after the cameras), with the cameras' tokens (``last``, ``[B, k, 1, ...]``) in the last ``k`` steps,
    each with its step's embedding. With ``k = T`` a step holds the scene, the cameras, then the point
    cloud, the order checkpoints trained with every step's images hold."""
    t = every[0][0].shape[1]
    early = [torch.cat([x[:, : t - k] for x in group], dim=2) for group in every]  # [B, T - k, n, ...]
    late = [
        torch.cat([group[0][:, t - k :], *cams, *(x[:, t - k :] for x in group[1:])], dim=2)
        for group, cams in zip(every, last, strict=True)
    ]  # [B, k, n + cameras, ...]
    early[0] = early[0] + step_embed[None, : t - k, None]
    late[0] = late[0] + step_embed[None, t - k :, None]
    pairs = zip(early, late, strict=True)
    return tuple(torch.cat([e.flatten(1, 2), la.flatten(1, 2)], dim=1) for e, la in pairs)


def _module_key(feature_key: str) -> str:
    """ModuleDict keys may not contain dots: ``observation.images.wrist -> observation_images_wrist``."""
    return feature_key.replace(".", "_")
