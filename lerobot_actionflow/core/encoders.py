"""Per-modality token encoders: each maps one kind of observation to features of the common width ``dim``.

Encoders see only quantities that are already invariant (features, images, points expressed in the
end-effector frame), so they never break the policy's SE(3) equivariance.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


class VectorEncoder(nn.Module):
    """Token feature vectors ``[*, F] -> [*, dim]`` (one-hot entity id, gripper opening, lid angle...)."""

    def __init__(self, in_dim: int, dim: int):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(in_dim, dim), nn.GELU(), nn.Linear(dim, dim))

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x)


def _conv_block(c_in: int, c_out: int, stride: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1, bias=False),
        nn.GroupNorm(min(8, c_out), c_out),
        nn.ReLU(inplace=True),
    )


class ImageEncoder(nn.Module):
    """RGB images ``[*, 3, H, W]`` in [0, 1] -> ``[*, dim]``.

    A small residual-free CNN (4 stride-2 stages, GroupNorm so batch size does not matter) followed by
    spatial softmax keypoints, the standard choice of visuomotor policies. It is trained from scratch:
    no weights are downloaded.
    """

    def __init__(self, dim: int, channels: tuple[int, ...] = (32, 64, 128, 128), keypoints: int = 32):
        super().__init__()
        layers, c_in = [], 3
        for c_out in channels:
            layers.append(_conv_block(c_in, c_out, stride=2))
            c_in = c_out
        self.backbone = nn.Sequential(*layers)
        self.to_keypoints = nn.Conv2d(c_in, keypoints, 1)
        self.out = nn.Sequential(nn.Linear(2 * keypoints, dim), nn.GELU(), nn.Linear(dim, dim))

    def forward(self, images: Tensor) -> Tensor:
        lead = images.shape[:-3]
        x = images.reshape(-1, *images.shape[-3:]) * 2.0 - 1.0
        heat = self.to_keypoints(self.backbone(x))  # [B', K, h, w]
        b, k, h, w = heat.shape
        attn = torch.softmax(heat.flatten(2), dim=-1).view(b, k, h, w)
        ys = torch.linspace(-1.0, 1.0, h, device=x.device, dtype=x.dtype)
        xs = torch.linspace(-1.0, 1.0, w, device=x.device, dtype=x.dtype)
        kp = torch.stack([(attn.sum(-2) * xs).sum(-1), (attn.sum(-1) * ys).sum(-1)], dim=-1)  # [B', K, 2]
        return self.out(kp.flatten(1)).reshape(*lead, -1)


class PointCloudEncoder(nn.Module):
    """PointNet over points ``[*, P, 3]`` (already centred and scaled by the caller) -> ``[*, dim]``.

    Shared per-point MLP then max pooling, so the result does not depend on the order of the points.
    """

    def __init__(self, dim: int, hidden: int = 64):
        super().__init__()
        self.point_mlp = nn.Sequential(
            nn.Linear(3, hidden),
            nn.GELU(),
            nn.Linear(hidden, 2 * hidden),
            nn.GELU(),
            nn.Linear(2 * hidden, dim),
        )
        self.out = nn.Sequential(nn.GELU(), nn.Linear(dim, dim))

    def forward(self, points: Tensor) -> Tensor:
        return self.out(self.point_mlp(points).amax(dim=-2))
