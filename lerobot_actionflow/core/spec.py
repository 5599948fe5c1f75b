"""``ModelSpec``: the plain data an ActionFlow model is built from (no LeRobot): the observation layout it
reads and the settings of the adaptation module, the flow, the loss and the network.
``ActionFlowConfig.model_spec()`` fills one from a LeRobot config; a user without LeRobot fills it
directly."""

from __future__ import annotations

from dataclasses import dataclass, field, fields

from lerobot_actionflow.core.pose_layouts import CameraPose


@dataclass(frozen=True)
class ModelSpec:
    """Everything ``ActionFlowModel`` and its network are built from. The defaults are ``ActionFlowConfig``'s
    (tests/test_core_alone.py checks they agree); the fields' meaning is documented there."""

    tokens_per_step: int
    """N, the scene tokens per observation step (token 0 = end effector)."""
    token_feature_dim: int
    """F, the feature width of each scene token."""
    image_keys: tuple[str, ...] = ()
    camera_poses: dict[str, CameraPose] = field(default_factory=dict)
    """Image key -> where that camera is; its image token is posed there. An image key without an entry is
    posed at the EEF token of its step (``image_placement="token"``)."""
    point_cloud: bool = False
    n_obs_steps: int = 2
    horizon: int = 16
    translation_scale: float = 10.0
    squash_limit: float = 3.0
    squash_mode: str = "axis"
    action_space: str = "se3"
    euclidean_frame: str = "action"
    rotation_noise_std: float | None = 0.5
    translation_loss_weight: float = 1.0
    rotation_loss_weight: float = 1.0
    gripper_loss_weight: float = 1.0
    image_random_shift: int = 0
    image_history: int | None = 1
    architecture: str = "ipa"
    dim: int = 128
    num_heads: int = 4
    ipa_layers: int = 2
    transformer_layers: int = 2
    ipa_head_dim: int = 16
    ipa_query_points: int = 4
    ipa_value_points: int = 4
    dropout: float = 0.0
    point_encoder: str = "pointnet"
    image_encoder: str = "cnn"
    image_placement: str = "token"

    @classmethod
    def settings(cls) -> tuple[str, ...]:
        """The fields a config supplies by name (the layout fields come from its input features)."""
        layout = {"tokens_per_step", "token_feature_dim", "image_keys", "camera_poses", "point_cloud"}
        return tuple(f.name for f in fields(cls) if f.name not in layout)
