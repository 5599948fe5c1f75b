"""The adaptation module (paper appendix "Policy Representation").

All poses are expressed in the frame of the current end-effector (EEF) pose, translations are scaled
(default x10, so 0.1 m becomes 1) and, for the network's input only, squashed with a tanh into
(-limit, limit) (``ActionFlowConfig.squash_limit``; the paper's tanh is limit 1).
The flow itself runs in the scaled EEF frame, so the initial noise (standard normal translation) is centred
on the gripper with a 0.1 m spread.

Because every quantity the network sees is relative to the EEF, transforming the whole scene (EEF
included) by any g in SE(3) leaves the network's input unchanged; mapping the generated actions back
with the transformed EEF pose then transforms them by g. This makes every architecture variant exactly
SE(3)-equivariant, with IPA adding invariance inside the network on top.
"""

from __future__ import annotations

import torch
from torch import Tensor

from lerobot_actionflow.core import geometry as g


class EEFFrame:
    """A reference pose (the current EEF) with its translation scale: ``rot [B, 3, 3]``, ``trans [B, 3]``."""

    def __init__(self, rot: Tensor, trans: Tensor, scale: float):
        self.rot, self.trans, self.scale = rot, trans, scale

    def _expand(self, ndim: int) -> tuple[Tensor, Tensor]:
        """Reference pose broadcast against poses with ``ndim`` leading dims (batch first)."""
        shape = (self.rot.shape[0],) + (1,) * (ndim - 1)
        return self.rot.view(*shape, 3, 3), self.trans.view(*shape, 3)

    def to_local(self, rot: Tensor, trans: Tensor) -> tuple[Tensor, Tensor]:
        """World poses ``[B, *, 3, 3], [B, *, 3]`` -> EEF-frame poses with translations scaled."""
        ref_rot, ref_trans = self._expand(trans.dim() - 1)
        rot_l, trans_l = g.relative(ref_rot, ref_trans, rot, trans)
        return rot_l, trans_l * self.scale

    def to_world(self, rot: Tensor, trans: Tensor) -> tuple[Tensor, Tensor]:
        """Inverse of :meth:`to_local`."""
        ref_rot, ref_trans = self._expand(trans.dim() - 1)
        return g.compose(ref_rot, ref_trans, rot, trans / self.scale)

    def points_to_local(self, points: Tensor) -> Tensor:
        """World points ``[B, *, 3]`` -> scaled EEF-frame points."""
        ref_rot, ref_trans = self._expand(points.dim() - 1)
        return g.apply_inverse(ref_rot, ref_trans, points) * self.scale


SQUASH_MODES = ("axis", "radial")
"""``axis``: each coordinate squashed alone (the paper's elementwise tanh); ``radial``: the distance squashed
and the direction kept."""


def squash(trans: Tensor, limit: float = 1.0, mode: str = "axis") -> Tensor:
    """Bound scaled translations ``[..., 3]`` for the network, so far-away entities do not dominate.

    ``mode="axis"``: ``limit * tanh(trans / limit)`` per coordinate, close to the identity up to about
    ``limit / 2``. ``limit = 1`` is the paper's plain ``tanh``, which at the default scale x10 leaves 1 cm of
    motion 0.4 % of the input's range at 0.2 m and ties everything beyond ~0.25 m together. It bends
    directions: a point 0.3 m off along a diagonal lands further out than one 0.3 m straight ahead.

    ``mode="radial"``: ``trans * limit * tanh(|trans| / limit) / |trans|``, the same curve applied to the
    distance from the EEF, so the direction is kept and the squash commutes with every rotation about the
    EEF: two entities at the same distance stay at the same distance whatever their bearing.
    """
    if mode == "axis":
        return limit * torch.tanh(trans / limit)
    if mode == "radial":
        r = trans.norm(dim=-1, keepdim=True)
        # tanh(r / l) * l / r -> 1 as r -> 0; the clamp keeps the gradient finite at the EEF itself.
        r_safe = r.clamp_min(1e-6)
        return trans * (limit * torch.tanh(r_safe / limit) / r_safe)
    raise ValueError(f"squash mode={mode!r}; expected one of {SQUASH_MODES}")
