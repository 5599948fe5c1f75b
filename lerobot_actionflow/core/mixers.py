"""How observation and action tokens are mixed: one class per architecture (the paper's ablations), in
the table :data:`MIXERS` that ``ActionFlowConfig.architecture`` indexes.

* ``"ipa"`` (A.1): every entity is a token with a pose; IPA blocks then a transformer encoder
  (:class:`~lerobot_actionflow.core.ipa.SE3InvariantTransformer`).
* ``"multi_token"`` (A.2): the same tokens, their poses embedded into the features by a linear layer,
  a plain transformer encoder (no IPA).
* ``"single_token"`` (A.3): all observation tokens concatenated into one conditioning token, plus the
  action tokens, through a plain transformer encoder.

A mixer holds no weights itself: :meth:`Mixer.build` returns the modules it needs, which the network
registers under those names (the names saved checkpoints hold), and :meth:`Mixer.observe` /
:meth:`Mixer.mix` read them from the network. Adding an architecture is a class and a row of the table.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import torch
from torch import Tensor, nn

from lerobot_actionflow.core import geometry as g
from lerobot_actionflow.core.adaptation import squash
from lerobot_actionflow.core.ipa import SE3InvariantTransformer, transformer_encoder

if TYPE_CHECKING:
    from lerobot_actionflow.core.network import ActionFlowNetwork, SceneTokens
    from lerobot_actionflow.core.spec import ModelSpec


class Mixer(Protocol):
    def build(self, spec: ModelSpec, num_obs_tokens: int) -> dict[str, nn.Module]:
        """The modules this architecture adds to the network, by attribute name (created in this order)."""

    def observe(self, net: ActionFlowNetwork, s: Tensor, rot: Tensor, trans: Tensor) -> Tensor:
        """Observation token features ``[B, M, C]`` (poses ``rot [B, M, 3, 3]``, ``trans [B, M, 3]``, scaled
        EEF frame) as the mixer keeps them for the whole chunk."""

    def mix(
        self, net: ActionFlowNetwork, scene: SceneTokens, a: Tensor, rot: Tensor, trans: Tensor
    ) -> Tensor:
        """Mixed features ``[B, M', C]`` whose last ``H`` rows are the action tokens, from the scene and the
        action tokens ``a [B, H, C]`` at poses ``rot [B, H, 3, 3]``, ``trans [B, H, 3]``."""


def pose_features(rot: Tensor, trans: Tensor, squash_limit: float, squash_mode: str = "axis") -> Tensor:
    """Pose as a 9-vector for the non-IPA variants: squashed translation and the 6D rotation."""
    return torch.cat([squash(trans, squash_limit, squash_mode), g.matrix_to_rot6d(rot)], dim=-1)


class IPAMixer:
    """A.1: tokens keep their poses; IPA sees the squashed translations."""

    def build(self, spec: ModelSpec, num_obs_tokens: int) -> dict[str, nn.Module]:
        return {
            "mixer": SE3InvariantTransformer(
                spec.dim, spec.num_heads, spec.ipa_layers, spec.transformer_layers, spec.ipa_head_dim,
                spec.ipa_query_points, spec.ipa_value_points, spec.dropout,
            )
        }  # fmt: skip

    def observe(self, net: ActionFlowNetwork, s: Tensor, rot: Tensor, trans: Tensor) -> Tensor:
        return s

    def mix(
        self, net: ActionFlowNetwork, scene: SceneTokens, a: Tensor, rot: Tensor, trans: Tensor
    ) -> Tensor:
        s = torch.cat([scene.features, a], dim=1)
        act_squashed = squash(trans, net.spec.squash_limit, net.spec.squash_mode)
        rots = torch.cat([scene.rot, rot], dim=1)
        return net.mixer(s, rots, torch.cat([scene.squashed_trans, act_squashed], dim=1))


class PoseEmbeddingMixer:
    """A.2: each token's pose is embedded into its feature; a plain transformer encoder mixes them."""

    def build(self, spec: ModelSpec, num_obs_tokens: int) -> dict[str, nn.Module]:
        encoder = transformer_encoder(spec.dim, spec.num_heads, spec.transformer_layers, spec.dropout)
        return {"pose_embed": nn.Linear(9, spec.dim), "mixer": nn.Sequential(encoder, nn.LayerNorm(spec.dim))}

    def embed(self, net: ActionFlowNetwork, s: Tensor, rot: Tensor, trans: Tensor) -> Tensor:
        return s + net.pose_embed(pose_features(rot, trans, net.spec.squash_limit, net.spec.squash_mode))

    def observe(self, net: ActionFlowNetwork, s: Tensor, rot: Tensor, trans: Tensor) -> Tensor:
        return self.embed(net, s, rot, trans)

    def mix(
        self, net: ActionFlowNetwork, scene: SceneTokens, a: Tensor, rot: Tensor, trans: Tensor
    ) -> Tensor:
        return net.mixer(torch.cat([scene.features, self.embed(net, a, rot, trans)], dim=1))


class PooledMixer(PoseEmbeddingMixer):
    """A.3: as A.2, with every observation token pooled into one conditioning token (its pose unused)."""

    def build(self, spec: ModelSpec, num_obs_tokens: int) -> dict[str, nn.Module]:
        pool = nn.Sequential(
            nn.Linear(num_obs_tokens * spec.dim, spec.dim), nn.GELU(), nn.Linear(spec.dim, spec.dim)
        )
        return {**super().build(spec, num_obs_tokens), "obs_pool": pool}

    def observe(self, net: ActionFlowNetwork, s: Tensor, rot: Tensor, trans: Tensor) -> Tensor:
        return net.obs_pool(super().observe(net, s, rot, trans).flatten(1))[:, None]  # [B, 1, C]


MIXERS: dict[str, Mixer] = {
    "ipa": IPAMixer(),
    "multi_token": PoseEmbeddingMixer(),
    "single_token": PooledMixer(),
}
"""Architecture name (``ActionFlowConfig.architecture``) -> its mixer."""
