"""Invariant Point Attention (IPA) and the SE(3) Invariant Transformer (paper Sec. "SE(3) Invariant
Transformer" and appendix "Invariant Point Attention").

Each token carries a feature ``s_i`` and a pose ``T_i = (R_i, p_i)``. IPA adds to ordinary dot-product
attention a term that compares 3D points generated from the features *in each token's local frame* and
placed in the common frame by ``T_i``; attended value points are brought back into the query's frame by
``T_i^{-1}``. Distances between placed points and points expressed in a token's own frame do not change
when one SE(3) transform is applied to every pose, so the layer's output is invariant to it.

There is no pair representation (unlike AlphaFold), and the poses are not updated by the layers: they are
the observed entity poses and the current action samples of the flow.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lerobot_actionflow.core import geometry as g


class InvariantPointAttention(nn.Module):
    """One IPA layer: ``(s [B, N, C], R [B, N, 3, 3], p [B, N, 3]) -> [B, N, C]``, invariant in (R, p)."""

    def __init__(self, dim: int, num_heads: int, head_dim: int, query_points: int, value_points: int):
        super().__init__()
        self.num_heads, self.head_dim = num_heads, head_dim
        self.query_points, self.value_points = query_points, value_points
        self.to_qkv = nn.Linear(dim, 3 * num_heads * head_dim, bias=False)
        self.to_qk_points = nn.Linear(dim, 2 * num_heads * query_points * 3)
        self.to_v_points = nn.Linear(dim, num_heads * value_points * 3)
        # Learnable per-head weight of the point term; softplus(0.5413) = 1.
        self.point_weight = nn.Parameter(torch.full((num_heads,), 0.5413))
        # Scalar and point terms weighted as in AlphaFold's IPA without the pair bias: equal variance at init.
        self.scalar_scale = math.sqrt(1.0 / 2.0) / math.sqrt(head_dim)
        self.point_scale = math.sqrt(1.0 / 2.0) * math.sqrt(2.0 / (9.0 * query_points)) / 2.0
        out_in = num_heads * (head_dim + value_points * 4)
        self.to_out = nn.Linear(out_in, dim)

    def forward(self, s: Tensor, rot: Tensor, trans: Tensor) -> Tensor:
        b, n, _ = s.shape
        h, c, pq, pv = self.num_heads, self.head_dim, self.query_points, self.value_points

        q, k, v = self.to_qkv(s).view(b, n, 3, h, c).unbind(2)  # each [B, N, H, C]

        # Points are produced in each token's local frame and placed in the common frame.
        qk_pts = self.to_qk_points(s).view(b, n, 2 * h * pq, 3)
        qk_pts = g.apply(rot[:, :, None], trans[:, :, None], qk_pts)  # [B, N, 2*H*Pq, 3]
        q_pts, k_pts = qk_pts.view(b, n, 2, h, pq * 3).unbind(2)  # each [B, N, H, Pq*3]
        v_pts = self.to_v_points(s).view(b, n, h * pv, 3)
        v_pts = g.apply(rot[:, :, None], trans[:, :, None], v_pts).view(b, n, h, pv * 3)

        scalar_logits = torch.einsum("bihc,bjhc->bhij", q, k) * self.scalar_scale  # [B, H, N, N]
        # sum_p |q_ip - k_jp|^2 = |q_i|^2 + |k_j|^2 - 2 q_i . k_j over the flattened points.
        q_sq = (q_pts * q_pts).sum(-1).transpose(1, 2)[..., :, None]  # [B, H, N, 1]
        k_sq = (k_pts * k_pts).sum(-1).transpose(1, 2)[..., None, :]  # [B, H, 1, N]
        cross = torch.einsum("bihx,bjhx->bhij", q_pts, k_pts)
        sq_dist = (q_sq + k_sq - 2.0 * cross).clamp_min(0.0)
        gamma = F.softplus(self.point_weight)[None, :, None, None]
        attn = torch.softmax(scalar_logits - gamma * self.point_scale * sq_dist, dim=-1)  # [B, H, N, N]

        out_scalar = torch.einsum("bhij,bjhc->bihc", attn, v).reshape(b, n, h * c)
        out_pts = torch.einsum("bhij,bjhx->bihx", attn, v_pts).reshape(b, n, h * pv, 3)
        out_pts = g.apply_inverse(rot[:, :, None], trans[:, :, None], out_pts)  # back to the query frame
        out_norm = torch.sqrt((out_pts * out_pts).sum(-1) + 1e-8)  # [B, N, H*Pv]
        return self.to_out(torch.cat([out_scalar, out_pts.reshape(b, n, h * pv * 3), out_norm], dim=-1))


class IPABlock(nn.Module):
    """IPA with a residual connection and LayerNorm, then a two-layer transition MLP (as in FrameDiff)."""

    def __init__(
        self, dim: int, num_heads: int, head_dim: int, query_points: int, value_points: int, dropout: float
    ):
        super().__init__()
        self.ipa = InvariantPointAttention(dim, num_heads, head_dim, query_points, value_points)
        self.norm1 = nn.LayerNorm(dim)
        self.transition = nn.Sequential(nn.Linear(dim, 2 * dim), nn.GELU(), nn.Linear(2 * dim, dim))
        self.norm2 = nn.LayerNorm(dim)
        self.dropout = nn.Dropout(dropout)

    def forward(self, s: Tensor, rot: Tensor, trans: Tensor) -> Tensor:
        s = self.norm1(s + self.dropout(self.ipa(s, rot, trans)))
        return self.norm2(s + self.dropout(self.transition(s)))


def transformer_encoder(dim: int, num_heads: int, num_layers: int, dropout: float) -> nn.TransformerEncoder:
    """Standard pre-norm transformer encoder over ``[B, N, C]`` tokens (no positional encoding: token
    identity, history step and action index are already in the features)."""
    layer = nn.TransformerEncoderLayer(
        dim,
        num_heads,
        dim_feedforward=4 * dim,
        dropout=dropout,
        activation="gelu",
        batch_first=True,
        norm_first=True,
    )
    return nn.TransformerEncoder(layer, num_layers, enable_nested_tensor=False)


class SE3InvariantTransformer(nn.Module):
    """IPA blocks to reason over relative poses, then a transformer encoder for higher-order interactions.

    ``(s [B, N, C], R [B, N, 3, 3], p [B, N, 3]) -> [B, N, C]``, invariant to one SE(3) transform of all
    poses.
    """

    def __init__(
        self,
        dim: int,
        num_heads: int,
        ipa_layers: int,
        transformer_layers: int,
        head_dim: int,
        query_points: int,
        value_points: int,
        dropout: float,
    ):
        super().__init__()
        self.ipa_blocks = nn.ModuleList(
            IPABlock(dim, num_heads, head_dim, query_points, value_points, dropout) for _ in range(ipa_layers)
        )
        self.encoder = transformer_encoder(dim, num_heads, transformer_layers, dropout)
        self.norm = nn.LayerNorm(dim)

    def forward(self, s: Tensor, rot: Tensor, trans: Tensor) -> Tensor:
        for block in self.ipa_blocks:
            s = block(s, rot, trans)
        return self.norm(self.encoder(s))
