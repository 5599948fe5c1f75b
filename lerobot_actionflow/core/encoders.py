"""Per-modality token encoders: each maps one kind of observation to features of the common width ``dim``.

Encoders see only quantities that are already invariant (features, images, points expressed in the
end-effector frame), so they never break the policy's SE(3) equivariance. Images have two encoders
(``ActionFlowConfig.image_encoder``): a small CNN and the paper's ResNet18, both trained from scratch and
both ending in spatial-softmax keypoints. The point cloud has two encoders
(``ActionFlowConfig.point_encoder``): the plain PointNet, whose feature changes when the cloud turns relative
to the gripper, and the Vector-Neuron PointNet, whose feature does not and which also gives the cloud a
rotation that turns with it.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torchvision.models import resnet18

from lerobot_actionflow.core import geometry as g


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


def random_shift(images: Tensor, pad: int, generator: torch.Generator | None = None) -> Tensor:
    """Training augmentation of camera images ``[B, T, C, H, W]``: each sample's frames, padded by ``pad``
    pixels (edge pixels repeated), cropped back to ``H x W`` at one random offset in ``[0, 2 pad]`` per sample
    (the same for every step of its history), as DrQ's and Diffusion Policy's random crops. The content moves
    by up to ``pad`` pixels each way, so a policy cannot key its actions to exact pixel positions of 100
    demonstrations. ``pad=0`` returns ``images`` itself."""
    if pad <= 0:
        return images
    b, t, c, h, w = images.shape
    padded = nn.functional.pad(images.reshape(b, t * c, h, w), (pad, pad, pad, pad), mode="replicate")
    offsets = torch.randint(0, 2 * pad + 1, (b, 2), generator=generator, device="cpu").tolist()
    crops = [padded[i, :, dy : dy + h, dx : dx + w] for i, (dy, dx) in enumerate(offsets)]
    return torch.stack(crops).reshape(b, t, c, h, w)


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
        return encode_keypoints(images, self.backbone, self.to_keypoints, self.out)


def spatial_softmax(heat: Tensor) -> Tensor:
    """Keypoints ``[B, K, 2]`` (x, y in [-1, 1]) of heat maps ``[B, K, h, w]``: the expected pixel position
    under each map's softmax. A map of width (height) 1 gives a constant x (y): it carries no position."""
    b, k, h, w = heat.shape
    attn = torch.softmax(heat.flatten(2), dim=-1).view(b, k, h, w)
    ys = torch.linspace(-1.0, 1.0, h, device=heat.device, dtype=heat.dtype)
    xs = torch.linspace(-1.0, 1.0, w, device=heat.device, dtype=heat.dtype)
    return torch.stack([(attn.sum(-2) * xs).sum(-1), (attn.sum(-1) * ys).sum(-1)], dim=-1)


def encode_keypoints(images: Tensor, backbone: nn.Module, to_keypoints: nn.Module, out: nn.Module) -> Tensor:
    """The image encoders' shared path ``[*, 3, H, W]`` in [0, 1] -> ``[*, dim]``: pixels to [-1, 1], the
    convolutional ``backbone``, a 1x1 convolution ``to_keypoints`` to K heat maps, :func:`spatial_softmax`,
    and the MLP ``out`` of the 2K keypoint coordinates."""
    lead = images.shape[:-3]
    x = images.reshape(-1, *images.shape[-3:]) * 2.0 - 1.0
    kp = spatial_softmax(to_keypoints(backbone(x)))  # [B', K, 2]
    return out(kp.flatten(1)).reshape(*lead, -1)


class ResNet18ImageEncoder(nn.Module):
    """The paper's image encoder: RGB images ``[*, 3, H, W]`` in [0, 1] -> ``[*, dim]`` through torchvision's
    ResNet18, built with ``weights=None`` (trained from scratch, nothing is downloaded).

    Changes to the ImageNet network, for small wrist images (the paper's 80x80) and any batch size:

    * BatchNorm becomes GroupNorm with groups of 16 channels (as Diffusion Policy's ResNet18), so a
      prediction does not depend on the other samples of a batch or on running statistics, like the CNN.
    * The classifier (global average pooling + ``fc``) is replaced by the head of :class:`ImageEncoder`: a
      1x1 convolution to K heat maps, spatial-softmax keypoints and an MLP to ``dim``. Average pooling would
      discard where things are in the image, which is what a wrist view tells the gripper.
    * The 7x7 stride-2 stem and the max pooling are kept: the feature map is 1/32 of the image, 3x3 at 80x80
      (as Diffusion Policy and robomimic use ResNet18 on 76-84 px crops; the soft-argmax of the spatial
      softmax still places a keypoint between the cells). Without the max pooling (a 5x5 map at 80x80) the
      backbone's forward + backward pass over 64 80x80 images took about 5x as long (7.4 s against 1.4 s,
      one thread of this project's shared 2-core CPU); a 3x3 stride-1 stem without max pooling would
      quadruple the area of every stage again. Images need at least 33 px a side (a 2x2 map;
      ``ActionFlowConfig.validate_features`` checks it): below that the map is 1x1 and its keypoints are
      constant.
    """

    def __init__(self, dim: int, keypoints: int = 32, group_size: int = 16):
        super().__init__()
        net = resnet18(weights=None, norm_layer=lambda c: nn.GroupNorm(c // group_size, c))
        self.backbone = nn.Sequential(
            net.conv1, net.bn1, net.relu, net.maxpool, net.layer1, net.layer2, net.layer3, net.layer4
        )
        self.to_keypoints = nn.Conv2d(net.fc.in_features, keypoints, 1)
        self.out = nn.Sequential(nn.Linear(2 * keypoints, dim), nn.GELU(), nn.Linear(dim, dim))

    def forward(self, images: Tensor) -> Tensor:
        return encode_keypoints(images, self.backbone, self.to_keypoints, self.out)


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


class VNLinear(nn.Module):
    """Vector-Neuron linear layer ``[*, 3, C_in] -> [*, 3, C_out]``: ``V' = W V`` (Deng et al. 2021, eq. 2).

    VN features are lists of C 3-vectors, stored here as the columns of ``[*, 3, C]`` (channels last, so that
    mixing channels is one matrix product over the last axis). The layer mixes the channels, never the xyz
    axis, and has no bias (a bias vector would not rotate), so ``f(R V) = R f(V)`` for every rotation R: it
    is SO(3)-equivariant.
    """

    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.map = nn.Linear(c_in, c_out, bias=False)

    def forward(self, v: Tensor) -> Tensor:
        return self.map(v)


class VNLinearLeakyReLU(nn.Module):
    """VN linear layer followed by the VN leaky ReLU ``[*, 3, C_in] -> [*, 3, C_out]`` (Deng et al. 2021,
    eqs. 3-4).

    Each output channel has a feature ``q = W V`` and a learned direction ``k = U V``. Where ``<q, k> >= 0``
    the ReLU keeps ``q``; elsewhere it removes the component of ``q`` along ``k``. The leaky version returns
    ``slope * q + (1 - slope) * relu(q)``. Both ``q`` and ``k`` rotate with the input and the case is chosen
    by an inner product, which does not, so the layer is SO(3)-equivariant.
    """

    def __init__(self, c_in: int, c_out: int, negative_slope: float = 0.2, eps: float = 1e-6):
        super().__init__()
        self.feature = VNLinear(c_in, c_out)
        self.direction = VNLinear(c_in, c_out)
        self.negative_slope, self.eps = negative_slope, eps

    def forward(self, v: Tensor) -> Tensor:
        q, k = self.feature(v), self.direction(v)  # [*, 3, C_out] each
        dot = torch.linalg.vecdot(q, k, dim=-2)[..., None, :]  # [*, 1, C_out]
        k_sq = torch.linalg.vecdot(k, k, dim=-2)[..., None, :]
        # slope * q + (1 - slope) * relu(q), written as one correction of q where <q, k> < 0.
        along_k = torch.where(dot < 0, dot / (k_sq + self.eps), 0.0)
        return torch.addcmul(q, along_k, k, value=self.negative_slope - 1.0)


def knn_edge_features(points: Tensor, neighbours: int) -> Tensor:
    """VN features of each point's edges to its nearest neighbours: ``[N, P, 3] -> [N, P, k, 3, 3]`` with the
    three vector channels (columns) ``(x_j - x_i, x_i, x_j x x_i)`` for the ``k = min(neighbours, P)``
    nearest points ``x_j`` (the point itself included).

    Distances do not change under rotation and the cross product rotates with its arguments, so the result
    is SO(3)-equivariant and permutation-equivariant (up to exact ties in the k-th distance). Without such
    pairs a VN network over single points only sees one direction per point and reduces to a linear map of
    the centroid.
    """
    k = min(neighbours, points.shape[-2])
    with torch.no_grad():
        idx = torch.cdist(points, points).topk(k, dim=-1, largest=False).indices  # [N, P, k]
    batch = torch.arange(points.shape[0], device=points.device)[:, None, None]
    x_j = points[batch, idx]  # [N, P, k, 3]
    x_i = points[:, :, None].expand_as(x_j)
    return torch.stack([x_j - x_i, x_i, torch.linalg.cross(x_j, x_i, dim=-1)], dim=-1)


def vn_rotation_frame(u: Tensor, v: Tensor, eps: float = 1e-6, parallel_tol: float = 1e-3) -> Tensor:
    """A proper rotation ``[*, 3, 3]`` from two equivariant vectors ``u, v [*, 3]`` by Gram-Schmidt: the first
    column is ``u`` normalised, the second the part of ``v`` orthogonal to it, the third their cross product.

    Equivariant (``frame(R u, R v) = R frame(u, v)``) wherever ``|u| > eps`` and the part of ``v`` orthogonal
    to ``u`` exceeds ``parallel_tol * |v|`` (nearer than that, float32 rounding would leave the second column
    visibly non-orthogonal) and ``eps``. Degenerate inputs (a cloud of equal or collinear points has no
    second direction) fall back to fixed axes, so the result is always a rotation and never NaN.
    """
    ex = torch.tensor([1.0, 0.0, 0.0], dtype=u.dtype, device=u.device).expand_as(u)
    u = torch.where((u * u).sum(-1, keepdim=True) > eps**2, u, ex)
    with torch.no_grad():
        e1 = u / u.norm(dim=-1, keepdim=True)
        v_perp = v - (v * e1).sum(-1, keepdim=True) * e1
        v_sq, perp_sq = (v * v).sum(-1, keepdim=True), (v_perp * v_perp).sum(-1, keepdim=True)
        parallel = perp_sq <= parallel_tol**2 * v_sq + eps**2
        # Any vector orthogonal to u: its cross product with the axis it is least aligned with.
        axis = nn.functional.one_hot(e1.abs().argmin(-1), 3).to(u.dtype)
        fallback = torch.linalg.cross(e1, axis, dim=-1)
    return g.rot6d_to_matrix(torch.cat([u, torch.where(parallel, fallback, v)], dim=-1))


def vn_rms_normalise(v: Tensor, eps: float = 1e-6) -> Tensor:
    """Scale VN features ``[*, 3, C]`` so that their channels' root-mean-square norm is 1.

    Norms do not change under rotation, so this stays equivariant. It matters after mean pooling over the
    points: features that point outwards from the centroid mostly cancel there, and without it the pooled
    vectors (and the invariants built from their inner products) start orders of magnitude below 1.
    """
    return v / ((v * v).sum(-2, keepdim=True).mean(-1, keepdim=True) + eps**2).sqrt()


class VNPointNetEncoder(nn.Module):
    """Vector-Neuron PointNet (Deng et al. 2021) over points ``[*, P, 3]`` -> an SO(3)-invariant feature
    ``[*, dim]`` and an SO(3)-equivariant rotation frame ``[*, 3, 3]``.

    For a rotation R, ``encoder(points @ R^T) == (feature, R @ frame)``: the feature does not depend on how
    the cloud is turned, and the frame turns with it. The points are centred at their centroid first, so
    both are also unchanged by a translation; both ignore the order of the points. A cloud with no
    orientation of its own (all points equal, or on one line) still gives a finite feature and a proper
    rotation, from fixed fallback axes, which cannot be equivariant there.

    Layers (``h`` = ``hidden`` vector channels): kNN edge features (:func:`knn_edge_features`) -> VN linear +
    leaky ReLU, mean over the neighbours -> per-point VN layer -> concatenation with the mean over the points
    -> VN layer -> VN linear -> mean over the points -> :func:`vn_rms_normalise`: ``V [*, 3, 4h]``,
    equivariant. A VN head turns ``V`` into three equivariant vectors ``Z [*, 3, 3]``; the inner products
    ``V^T Z`` are invariant (the VN paper's invariant layer) and an MLP maps them to ``dim``. The frame is
    Gram-Schmidt of the first two vectors of ``Z`` (:func:`vn_rotation_frame`).
    """

    def __init__(self, dim: int, hidden: int = 21, neighbours: int = 16):
        super().__init__()
        self.neighbours = neighbours
        self.edge = VNLinearLeakyReLU(3, hidden)
        self.point = VNLinearLeakyReLU(hidden, hidden)
        self.fuse = VNLinearLeakyReLU(2 * hidden, 2 * hidden)
        self.lift = VNLinear(2 * hidden, 4 * hidden)
        self.frame_head = nn.Sequential(VNLinearLeakyReLU(4 * hidden, 2 * hidden), VNLinear(2 * hidden, 3))
        self.out = nn.Sequential(nn.Linear(4 * hidden * 3, dim), nn.GELU(), nn.Linear(dim, dim))

    def forward(self, points: Tensor) -> tuple[Tensor, Tensor]:
        lead = points.shape[:-2]
        x = points.reshape(-1, *points.shape[-2:])  # [N, P, 3]
        x = x - x.mean(dim=-2, keepdim=True)
        h = self.edge(knn_edge_features(x, self.neighbours)).mean(dim=-3)  # [N, P, 3, h]
        h = self.point(h)
        h = self.fuse(torch.cat([h, h.mean(dim=-3, keepdim=True).expand_as(h)], dim=-1))  # [N, P, 3, 2h]
        v = vn_rms_normalise(self.lift(h).mean(dim=-3))  # [N, 3, 4h]
        z = self.frame_head(v)  # [N, 3, 3]: three equivariant vectors (columns)
        invariant = torch.einsum("ndc,ndk->nck", v, z).flatten(1)  # [N, 4h * 3]
        frame = vn_rotation_frame(z[..., 0], z[..., 1])  # [N, 3, 3]
        return self.out(invariant).reshape(*lead, -1), frame.reshape(*lead, 3, 3)
