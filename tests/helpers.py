"""Shared test helpers (imported by the test modules; pytest puts this folder on sys.path)."""

from __future__ import annotations

import torch

from lerobot_actionflow import ActionFlowConfig, schema
from lerobot_actionflow.core import geometry as g

N_TOKENS, N_FEATURES = 3, 4


def make_config(extra_inputs: dict[str, tuple[int, ...]] | None = None, **overrides) -> ActionFlowConfig:
    """A CPU ActionFlowConfig for the synthetic 3-token task; keyword arguments override fields.

    ``extra_inputs`` adds modalities by env key and shape, e.g. ``{"pixels/wrist": (32, 32, 3)}``."""
    cfg = ActionFlowConfig(device="cpu", **overrides)
    shapes = schema.token_shapes(N_TOKENS, N_FEATURES) | (extra_inputs or {})
    cfg.input_features, cfg.output_features = schema.policy_features(shapes)
    return cfg


def random_se3(seed: int, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """One random rigid transform: a Haar rotation and a translation of up to ~1 m."""
    gen = torch.Generator().manual_seed(seed)
    rot = g.random_rotation((), generator=gen, dtype=torch.float64)
    trans = torch.randn(3, generator=gen, dtype=torch.float64) * 0.5
    return rot.to(dtype), trans.to(dtype)


def transform_pose9(rot: torch.Tensor, trans: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
    """Apply a world transform to pose vectors ``[*, 9]``."""
    r, p = g.pose9_to_rt(pose)
    return g.rt_to_pose9(*g.compose(rot.expand_as(r), trans.expand_as(p), r, p))


def chunks_before_and_after(policy, obs: dict, rot: torch.Tensor, trans: torch.Tensor):
    """Sample a chunk from ``obs`` and from ``obs`` moved by the world transform ``(rot, trans)`` (token poses
    and, if present, the point cloud), with the same noise; returns ``(actions, actions_moved, trans_err,
    rot_err)``, the errors between ``actions_moved`` and the transformed ``actions`` (exactly 0 for an
    SE(3)-equivariant policy)."""
    moved = dict(obs)
    moved[schema.TOKEN_POSES] = transform_pose9(rot, trans, obs[schema.TOKEN_POSES])
    if schema.POINT_CLOUD in obs:
        moved[schema.POINT_CLOUD] = g.apply(rot, trans, obs[schema.POINT_CLOUD])
    torch.manual_seed(9)
    actions = policy.predict_action_chunk(obs)
    torch.manual_seed(9)
    actions_moved = policy.predict_action_chunk(moved)
    trans_err, rot_err = g.pose9_errors(actions_moved[..., :9], transform_pose9(rot, trans, actions[..., :9]))
    return actions, actions_moved, trans_err, rot_err
