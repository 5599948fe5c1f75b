"""ActionFlowConfig: the LeRobot policy configuration registered as ``--policy.type=actionflow``."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import NormalizationMode, PreTrainedConfig
from lerobot.configs.types import FeatureType
from lerobot.optim import AdamWConfig, CosineDecayWithWarmupSchedulerConfig
from lerobot.optim.schedulers import LRSchedulerConfig
from torch.optim import Optimizer
from torch.optim.lr_scheduler import LambdaLR

from lerobot_actionflow.core.adaptation import SQUASH_MODES
from lerobot_actionflow.core.flow import EUCLIDEAN_FRAMES
from lerobot_actionflow.core.mixers import MIXERS
from lerobot_actionflow.core.model import Sampler
from lerobot_actionflow.core.pose_layouts import POSE_LAYOUTS, CameraPose, StateLayout
from lerobot_actionflow.core.spec import ModelSpec
from lerobot_actionflow.schema import (
    ACTION,
    ACTION_DIM,
    ACTION_NAMES,
    CAMERA_FRAMES,
    IMAGES,
    POINT_CLOUD,
    POSE_DIM,
    POSE_LAYOUT,
    STATE,
    STATE_NAMES,
    TOKEN_FEATURES,
    TOKEN_POSES,
)

ARCHITECTURES = tuple(MIXERS)
ACTION_SPACES = ("se3", "euclidean")
TIME_SCHEDULES = ("uniform", "exponential")
POINT_ENCODERS = ("pointnet", "vn")
IMAGE_ENCODERS = ("cnn", "resnet18")
IMAGE_PLACEMENTS = ("token", "eef")
MIN_IMAGE_SIDE = {"cnn": 17, "resnet18": 33}
"""Smallest image side each encoder can see: the CNN's feature map is 1/16 of the image and the ResNet18's
1/32; below these sides the map is 1x1, its spatial-softmax keypoints are constant and the image is
ignored."""


@LRSchedulerConfig.register_subclass("actionflow_cosine")
@dataclass
class RunLengthCosineSchedulerConfig(CosineDecayWithWarmupSchedulerConfig):
    """LeRobot's cosine decay with warm-up, its decay spanning the training run when ``num_decay_steps`` is
    None. (LeRobot's own, given more decay steps than the run has, shrinks the warm-up by the same factor: a
    2000-step run of a 100000-step schedule would warm up for 2 steps instead of 100.)"""

    num_warmup_steps: int = 100
    num_decay_steps: int | None = None
    peak_lr: float = 1e-3
    decay_lr: float = 1e-5

    def build(self, optimizer: Optimizer, num_training_steps: int) -> LambdaLR:
        decay = self.num_decay_steps or num_training_steps
        fixed = CosineDecayWithWarmupSchedulerConfig(
            self.num_warmup_steps, decay, self.peak_lr, self.decay_lr
        )
        return fixed.build(optimizer, num_training_steps)


@PreTrainedConfig.register_subclass("actionflow")
@dataclass
class ActionFlowConfig(PreTrainedConfig):
    """ActionFlow: SE(3) flow matching over action pose sequences with an SE(3) Invariant Transformer.

    Inputs, either the token schema (lerobot_actionflow/schema.py):
        ``observation.token_poses`` (N, 9) world poses, token 0 = end effector; ``observation.token_features``
        (N, F); optionally ``observation.images.*`` (3, H, W) posed at the end effector or where
        ``camera_poses`` puts them, and ``observation.point_cloud`` (P, 3) world points;
    or a plain LeRobot dataset (no token keys):
        ``observation.state`` (D,) with the end-effector pose in it (``state_pose_*``), which becomes token 0,
        and ``observation.images.*`` (3, H, W), each posed by its ``camera_poses`` entry.
    Output:
        ``action``: absolute target EEF pose (world frame) + gripper command: (10,) = pose9 + gripper in
        [-1, 1], or another pose layout + gripper (``action_layout``), converted to and from ours.
    """

    # Inputs / output structure.
    n_obs_steps: int = 2
    horizon: int = 16
    n_action_steps: int = 8

    # Poses must never be mean/std normalised (that breaks the geometry); every mode here is identity.
    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.IDENTITY,
            "ENV": NormalizationMode.IDENTITY,
            "ACTION": NormalizationMode.IDENTITY,
        }
    )

    # Adaptation module: poses in the current EEF frame, translations x scale, tanh before the network.
    translation_scale: float = 10.0
    # The network sees translations as squash_limit * tanh(t / squash_limit). 1 is the paper's tanh, which at
    # scale 10 flattens everything beyond ~0.2 m; 3 keeps far entities and far actions apart (measured:
    # eval/results/ablate.md). Checkpoints saved before this field existed load with 1.
    squash_limit: float = 3.0
    # "axis": the tanh per coordinate (the paper's); "radial": the tanh of the distance from the EEF with the
    # direction kept, so entities at the same distance look equally far whatever their bearing.
    squash_mode: str = "axis"

    # Flow matching.
    action_space: str = "se3"  # "se3" (paper) or "euclidean" (flat [p, rot6d, gripper] vector)
    # Frame of the Euclidean flow's velocity (unused by "se3"). "action": each action's own frame, as the
    # SE(3) flow's, which an invariant network gives directly; "eef": the flat vector in the EEF frame, which
    # IPA must learn to turn its output into. Checkpoints saved before this field existed load with "eef".
    euclidean_frame: str = "action"
    num_inference_steps: int = 4
    time_schedule: str = "uniform"  # "uniform" or "exponential" (shorter steps near the data)
    time_schedule_rate: float = 2.0
    # Rotation noise of the SE(3) flow: Exp(std * N(0, I)) around the gripper's current orientation (radians),
    # or None for the paper's uniform noise on SO(3). 0.5 turns the hand by the right amount far more often
    # (MugHanging: 100 % / 90 % vs 76 % / 80 % on two seeds each; eval/results/ablate.md). Checkpoints saved
    # before this field existed load with None.
    rotation_noise_std: float | None = 0.5

    # Loss weights of the velocity terms.
    translation_loss_weight: float = 1.0
    rotation_loss_weight: float = 1.0
    gripper_loss_weight: float = 1.0
    mask_padded_actions: bool = True  # actions past the episode end are copies: leave them out of the loss

    # Architecture.
    architecture: str = "ipa"  # "ipa" (A.1), "multi_token" (A.2) or "single_token" (A.3)
    dim: int = 128
    num_heads: int = 4
    ipa_layers: int = 2
    transformer_layers: int = 2
    ipa_head_dim: int = 16
    ipa_query_points: int = 4
    ipa_value_points: int = 4
    dropout: float = 0.0
    # Encoder of observation.point_cloud (unused without one). "pointnet" (paper): a plain PointNet, its token
    # posed at the centroid with the gripper's orientation, so it must learn every turn of the cloud relative
    # to the gripper. "vn": a Vector-Neuron PointNet, whose feature does not change when the cloud turns and
    # whose token is posed at the centroid with a rotation that turns with the cloud.
    point_encoder: str = "pointnet"
    # Encoder of each observation.images.* (trained from scratch, both ending in spatial-softmax keypoints).
    # "cnn": a small 4-stage CNN. "resnet18" (paper): torchvision's ResNet18 with GroupNorm (at least 33 px).
    image_encoder: str = "cnn"
    # Where an image enters the scene. "token": a token of its own, posed at the EEF token of its step.
    # "eef" (paper): its feature is added to that EEF token's feature (the camera's pose); no extra token.
    image_placement: str = "token"
    # Training augmentation of the images: each sample's frames shifted by up to this many pixels each way
    # (edge-padded random crop, one offset per sample); 0 = off. Evaluation always sees the image unshifted.
    image_random_shift: int = 0
    # How many of the latest observation steps have their images encoded (a token each, or added to the EEF
    # token): 1 = the current image only, half the image work of 2 at n_obs_steps=2 while the pose tokens
    # keep the whole history; None = every step. Checkpoints saved before this field existed load with None.
    image_history: int | None = 1

    # Plain LeRobot datasets (docs/training.md "Training on your own LeRobot camera dataset").
    # Without observation.token_poses the end effector is the only scene token, built from observation.state:
    # its pose is the `state_pose_layout` slice (core/pose_layouts.py POSE_LAYOUTS, e.g. "xyz_quat_wxyz")
    # starting at index `state_pose_start`; its feature is the gripper opening at `state_gripper_index` (None:
    # no gripper) and, with `state_extra_features`, every other state element (these must not change when the
    # whole scene moves: joint angles yes, world-frame velocities no). None: from the dataset's state names,
    # our schema.STATE_NAMES giving "pose9" at 0 with the gripper at 9; otherwise set them.
    state_pose_layout: str | None = None
    state_pose_start: int = 0
    state_gripper_index: int | None = None
    state_extra_features: bool = False
    # Where each camera observation.images.<cam> was, by <cam>: [frame, x, y, z, qw, qx, qy, qz] (metres,
    # scalar-first quaternion) with frame "eef" (on the gripper: the pose is its fixed offset in the EEF
    # frame, its pose at each step the EEF's times it) or "world" (static: the pose is its extrinsics). Its
    # image token is posed there. CLI: --policy.camera_poses='{wrist: [eef, 0, 0, 0.05, 1, 0, 0, 0]}'.
    # Without token keys every camera needs one (a dataset whose image features' `info` holds `camera.frame`,
    # `camera.pose` and `camera.quaternion_wxyz`, as actionflow-record writes them, gives its own); with
    # token keys a camera without one is posed at the EEF token. Unused by image_placement="eef".
    camera_poses: dict[str, list] = field(default_factory=dict)
    # The dataset's action: a pose in one of POSE_LAYOUTS, then one gripper value (in [-1, 1]: the sampled
    # command is clamped there). Training converts it to ours (pose9 + gripper), `select_action` back. None:
    # "pose9" when the action's names are schema.ACTION_NAMES or its shape is (10,) with no names.
    action_layout: str | None = None

    # Runtime (real-robot options of the paper's appendix).
    # Exponential smoothing of consecutive actions: a_out = alpha * a_prev + (1 - alpha) * a_new (0 = off).
    action_smoothing: float = 0.0
    # Latency compensation: drop the actions of a new chunk whose time (at control_fps) passed while it was
    # being generated, as on the real robot. Off in simulation, where the world waits for the policy.
    latency_compensation: bool = False
    control_fps: float = 20.0

    # What the policy was trained on, recorded from the dataset by lerobot-train (saved with the checkpoint):
    # the dataset's task descriptions, and the names of the scene tokens where the dataset names them.
    # `lerobot-eval` refuses an environment whose task is not among `trained_tasks` (the token shapes of two
    # tasks can match, and such a run would score 0 % without a word); `check_task=false` allows it.
    trained_tasks: list[str] = field(default_factory=list)
    token_names: list[str] = field(default_factory=list)
    check_task: bool = True

    # Training presets: the settings every published figure trained with (AdamW at 1e-3 after 100 warm-up
    # steps, cosine decay to 1e-5 over the run: `lerobot-train --steps` sets the decay's length, see
    # `get_scheduler_preset`). Checkpoints saved before these were the defaults keep their saved values.
    optimizer_lr: float = 1e-3
    optimizer_betas: tuple[float, float] = (0.9, 0.999)
    optimizer_eps: float = 1e-8
    optimizer_weight_decay: float = 1e-4
    optimizer_grad_clip_norm: float = 1.0
    scheduler_warmup_steps: int = 100
    # None: the decay spans the training run (`lerobot-train --steps`); an int fixes its length.
    scheduler_decay_steps: int | None = None
    scheduler_decay_lr: float = 1e-5
    # Exponential moving average of the weights, updated after every optimiser step (LeRobot's training loop
    # calls the policy's `update()`), sampled from at inference: ema = d * ema + (1 - d) * weights, with
    # d = min(ema_decay, (1 + n) / (10 + n)) after n updates. 0 = off (no second copy of the weights).
    ema_decay: float = 0.0

    def __post_init__(self):
        super().__post_init__()
        self._dataset_names: dict[str, list[str] | None] = {}
        """The state's and the action's names in the dataset (``set_dataset_feature_metadata``), not saved."""
        for name in ("state_pose_layout", "action_layout"):
            if getattr(self, name) not in (None, *POSE_LAYOUTS):
                raise ValueError(
                    f"{name}={getattr(self, name)!r}; expected None (from the dataset's names) or one of "
                    f"{tuple(POSE_LAYOUTS)}"
                )
        gripper = self.state_gripper_index
        if self.state_pose_start < 0 or (gripper is not None and gripper < 0):
            raise ValueError(
                f"state_pose_start={self.state_pose_start}, state_gripper_index={self.state_gripper_index}; "
                "expected indices >= 0 into observation.state (the gripper's may be None: no gripper)"
            )
        self.camera_poses = {cam: _camera_entry(cam, entry) for cam, entry in self.camera_poses.items()}
        if self.camera_poses and self.image_placement != "token":
            raise ValueError(
                f"camera_poses={sorted(self.camera_poses)} with image_placement={self.image_placement!r}; "
                "camera poses place each image as a token of its own: use image_placement='token'"
            )
        if self.architecture not in ARCHITECTURES:
            raise ValueError(f"architecture={self.architecture!r}; expected one of {ARCHITECTURES}")
        if self.action_space not in ACTION_SPACES:
            raise ValueError(f"action_space={self.action_space!r}; expected one of {ACTION_SPACES}")
        if self.euclidean_frame not in EUCLIDEAN_FRAMES:
            raise ValueError(f"euclidean_frame={self.euclidean_frame!r}; expected one of {EUCLIDEAN_FRAMES}")
        if self.time_schedule not in TIME_SCHEDULES:
            raise ValueError(f"time_schedule={self.time_schedule!r}; expected one of {TIME_SCHEDULES}")
        if self.point_encoder not in POINT_ENCODERS:
            raise ValueError(f"point_encoder={self.point_encoder!r}; expected one of {POINT_ENCODERS}")
        if self.image_encoder not in IMAGE_ENCODERS:
            raise ValueError(f"image_encoder={self.image_encoder!r}; expected one of {IMAGE_ENCODERS}")
        if self.image_placement not in IMAGE_PLACEMENTS:
            raise ValueError(f"image_placement={self.image_placement!r}; expected one of {IMAGE_PLACEMENTS}")
        if self.image_history is not None and not 1 <= self.image_history <= self.n_obs_steps:
            raise ValueError(
                f"image_history={self.image_history!r}, n_obs_steps={self.n_obs_steps}; expected None (every "
                "observation step) or 1 <= image_history <= n_obs_steps"
            )
        if not isinstance(self.image_random_shift, int) or self.image_random_shift < 0:
            raise ValueError(f"image_random_shift={self.image_random_shift!r}; expected an int >= 0 (pixels)")
        if not 1 <= self.n_action_steps <= self.horizon:
            raise ValueError(
                f"n_action_steps={self.n_action_steps}, horizon={self.horizon}; expected "
                "1 <= n_action_steps <= horizon (actions are taken from the predicted chunk)"
            )
        for name in ("n_obs_steps", "num_inference_steps", "dim", "num_heads"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)}; expected an integer >= 1")
        if self.dim % self.num_heads != 0:
            raise ValueError(
                f"dim={self.dim}, num_heads={self.num_heads}; dim must be divisible by num_heads"
            )
        if self.squash_mode not in SQUASH_MODES:
            raise ValueError(
                f"squash_mode={self.squash_mode!r}; expected one of {SQUASH_MODES} (per coordinate, the "
                "paper's, or of the distance)"
            )
        if self.squash_limit <= 0:
            raise ValueError(f"squash_limit={self.squash_limit}; expected > 0 (1 is the paper's tanh)")
        if self.rotation_noise_std is not None and not self.rotation_noise_std > 0:
            raise ValueError(
                f"rotation_noise_std={self.rotation_noise_std}; expected None (uniform on SO(3), the "
                "paper's) or a standard deviation > 0 in radians"
            )
        if self.scheduler_decay_steps is not None and self.scheduler_decay_steps < 1:
            raise ValueError(
                f"scheduler_decay_steps={self.scheduler_decay_steps}; expected None (the decay spans the "
                "training run) or an integer >= 1"
            )
        if self.scheduler_warmup_steps < 0 or not self.optimizer_lr > 0:
            raise ValueError(
                f"scheduler_warmup_steps={self.scheduler_warmup_steps}, optimizer_lr={self.optimizer_lr}; "
                "expected warm-up steps >= 0 and a learning rate > 0"
            )
        if self.translation_scale <= 0:
            raise ValueError(f"translation_scale={self.translation_scale}; expected > 0")
        if self.control_fps <= 0:
            raise ValueError(f"control_fps={self.control_fps}; expected > 0 (Hz)")
        if not 0.0 <= self.ema_decay < 1.0:
            raise ValueError(f"ema_decay={self.ema_decay}; expected 0 <= decay < 1 (0 = off, 0.999 typical)")
        if not 0.0 <= self.action_smoothing < 1.0:
            raise ValueError(f"action_smoothing={self.action_smoothing}; expected 0 <= alpha < 1")
        for ftype in ("STATE", "ACTION"):
            mode = self.normalization_mapping.get(ftype, NormalizationMode.IDENTITY)
            if mode != NormalizationMode.IDENTITY:
                raise ValueError(
                    f"normalization_mapping[{ftype!r}]={mode}; ActionFlow's {ftype.lower()} features hold "
                    "poses, "
                    "which must stay unnormalised (IDENTITY): scaling them would break the SE(3) geometry"
                )

    def get_optimizer_preset(self) -> AdamWConfig:
        return AdamWConfig(
            lr=self.optimizer_lr,
            betas=self.optimizer_betas,
            eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
            grad_clip_norm=self.optimizer_grad_clip_norm,
        )

    def get_scheduler_preset(self) -> RunLengthCosineSchedulerConfig:
        return RunLengthCosineSchedulerConfig(
            peak_lr=self.optimizer_lr,
            decay_lr=self.scheduler_decay_lr,
            num_warmup_steps=self.scheduler_warmup_steps,
            num_decay_steps=self.scheduler_decay_steps,
        )

    def validate_features(self) -> None:
        """Check the inputs (token keys, or ``observation.state`` and camera poses), the images and the
        action; say what is missing or wrong and what was expected. Resolves ``action_layout`` when the
        action's shape alone says it is ours."""
        inputs = self.input_features or {}
        if TOKEN_POSES in inputs or TOKEN_FEATURES in inputs:
            self._validate_tokens(inputs)
        else:
            self._validate_state(inputs)
        if POINT_CLOUD in inputs and (
            len(inputs[POINT_CLOUD].shape) != 2 or inputs[POINT_CLOUD].shape[1] != 3
        ):
            raise ValueError(f"{POINT_CLOUD} has shape {tuple(inputs[POINT_CLOUD].shape)}; expected (P, 3)")
        for key, ft in self.image_features.items():
            if len(ft.shape) != 3 or ft.shape[0] != 3:
                raise ValueError(f"{key} has shape {tuple(ft.shape)}; expected a (3, H, W) RGB image")
            min_side = MIN_IMAGE_SIDE[self.image_encoder]
            if min(ft.shape[1:]) < min_side:
                raise ValueError(
                    f"{key} has shape {tuple(ft.shape)}; image_encoder={self.image_encoder!r} needs H, W >= "
                    f"{min_side} (smaller images give a 1x1 feature map and would be ignored): resize them"
                )
        cameras = [_camera_name(key) for key in self.image_features]
        unknown = sorted(set(self.camera_poses) - set(cameras))
        if unknown:
            raise ValueError(
                f"camera_poses names the cameras {unknown}, which are not inputs; expected the <cam> of "
                f"{IMAGES}.<cam>, one of {cameras}"
            )
        self._validate_action()

    def _validate_tokens(self, inputs: dict) -> None:
        missing = [k for k in (TOKEN_POSES, TOKEN_FEATURES) if k not in inputs]
        if missing:
            raise ValueError(
                f"ActionFlow needs the input features {missing}, which are missing (got {sorted(inputs)}). "
                f"Expected {TOKEN_POSES} with shape (N, 9) pose vectors {POSE_LAYOUT} "
                "(token 0 = end effector) "
                f"and {TOKEN_FEATURES} with shape (N, F)."
            )
        poses, feats = inputs[TOKEN_POSES].shape, inputs[TOKEN_FEATURES].shape
        if len(poses) != 2 or poses[1] != POSE_DIM:
            raise ValueError(
                f"{TOKEN_POSES} has shape {tuple(poses)}; expected (N, 9) pose vectors {POSE_LAYOUT}"
            )
        if len(feats) != 2 or feats[0] != poses[0]:
            raise ValueError(
                f"{TOKEN_FEATURES} has shape {tuple(feats)} and {TOKEN_POSES} has shape {tuple(poses)}; "
                "expected (N, F) with the same token count N as the poses"
            )

    def _validate_state(self, inputs: dict) -> None:
        """No token keys: ``observation.state`` must say where the end effector is, and every camera must
        have a pose."""
        if STATE not in inputs:
            raise ValueError(
                f"ActionFlow needs either the token keys {TOKEN_POSES} (N, 9) and {TOKEN_FEATURES} (N, F), "
                f"or {STATE} with the end-effector pose in it; got {sorted(inputs)}"
            )
        shape, names = tuple(inputs[STATE].shape), self._dataset_names.get(STATE)
        if self.state_pose_layout is None:
            raise ValueError(
                f"{STATE} has shape {shape}{_named(names)}; without {TOKEN_POSES} ActionFlow builds the "
                "end-effector token from it, but nothing says where the pose is. Set "
                f"--policy.state_pose_layout (one of {tuple(POSE_LAYOUTS)}), --policy.state_pose_start (the "
                "index of its first element) and --policy.state_gripper_index (the gripper opening's index; "
                "leave it unset for none), e.g. --policy.state_pose_layout=xyz_quat_wxyz "
                "--policy.state_pose_start=0 --policy.state_gripper_index=7"
            )
        layout = self.state_layout()
        used = [*layout.pose_indices, *([] if layout.gripper_index is None else [layout.gripper_index])]
        if len(shape) != 1 or max(used) >= shape[0] or layout.gripper_index in layout.pose_indices:
            raise ValueError(
                f"{STATE} has shape {shape}{_named(names)}; state_pose_layout={layout.pose!r} at "
                f"state_pose_start={layout.start} reads the indices {list(layout.pose_indices)} and "
                f"state_gripper_index={layout.gripper_index}: expected a flat (D,) state holding both, apart"
            )
        posed = self.image_placement == "token"  # "eef": the images join the EEF token's feature, unposed
        missing = [key for key in self.image_features if posed and _camera_name(key) not in self.camera_poses]
        if missing:
            raise ValueError(
                f"{missing} have no entry in camera_poses; without {TOKEN_POSES} each image token is posed "
                "where its camera was. Set it for every camera, e.g. --policy.camera_poses="
                f"'{{{_camera_name(missing[0])}: [world, 0.5, 0, 0.4, 0, 0, 1, 0]}}' for a static camera "
                "([world, x, y, z, qw, qx, qy, qz]: its extrinsics) or [eef, 0, 0, 0.05, 1, 0, 0, 0] for a "
                "camera on the gripper (its fixed offset in the end effector's frame)"
            )

    def _validate_action(self) -> None:
        action = (self.output_features or {}).get(ACTION)
        if action is None or action.type != FeatureType.ACTION:
            raise ValueError(
                f"ActionFlow needs an 'action' output feature (got {sorted(self.output_features or {})}); "
                "expected shape (10,): target EEF pose (9) + gripper command"
            )
        shape, names = tuple(action.shape), self._dataset_names.get(ACTION)
        if self.action_layout is None and shape == (ACTION_DIM,) and names is None:
            self.action_layout = "pose9"
        if self.action_layout is None:
            sizes = {name: size + 1 for name, size in POSE_LAYOUTS.items()}
            raise ValueError(
                f"action has shape {shape}{_named(names)}; expected (10,): target EEF pose {POSE_LAYOUT} "
                f"+ gripper command in [-1, 1] (names {list(ACTION_NAMES)}), or an end-effector pose in "
                "another layout followed by one gripper value: set --policy.action_layout to the layout "
                f"(sizes with the gripper: {sizes}). Joint-space actions (joint angles or velocities) cannot "
                "be converted to end-effector poses: record the target end-effector pose as the action"
            )
        expected = (POSE_LAYOUTS[self.action_layout] + 1,)
        if shape != expected:
            raise ValueError(
                f"action has shape {shape}; action_layout={self.action_layout!r} expects {expected}: the "
                f"pose ({expected[0] - 1} values) + one gripper value; for the default pose9 that is target "
                f"EEF pose {POSE_LAYOUT} + gripper command in [-1, 1]"
            )

    def set_dataset_feature_metadata(self, features: dict) -> None:
        """Called by LeRobot's ``make_policy`` with the dataset's features: keep the scene tokens' names, and
        read the state's and the action's layout from their names where those are ours."""
        names = (features.get(TOKEN_POSES) or {}).get("names")
        if isinstance(names, dict):  # {"token": [...], "pose": [...]}: the first axis names the tokens
            names = next(iter(names.values()), None)
        if isinstance(names, list) and all(isinstance(n, str) for n in names):
            self.token_names = list(names)
        self._dataset_names = {key: _flat_names(features.get(key)) for key in (STATE, ACTION)}
        uses_state = TOKEN_POSES not in (self.input_features or {})
        if uses_state and self.state_pose_layout is None and self._dataset_names[STATE] == list(STATE_NAMES):
            self.state_pose_layout, self.state_pose_start = "pose9", 0
            self.state_gripper_index = STATE_NAMES.index("gripper_opening")
        if self.action_layout is None and self._dataset_names[ACTION] == list(ACTION_NAMES):
            self.action_layout = "pose9"
        for key, feature in features.items() if uses_state and self.image_placement == "token" else ():
            info = (feature or {}).get("info") or {}
            cam = _camera_name(key)
            if key.startswith(f"{IMAGES}.") and cam not in self.camera_poses and "camera.frame" in info:
                pose = [*info["camera.pose"][:3], *info["camera.quaternion_wxyz"]]
                self.camera_poses[cam] = _camera_entry(cam, [info["camera.frame"], *pose])

    def state_layout(self) -> StateLayout | None:
        """Where the end effector is in ``observation.state``; None when the inputs have token keys."""
        inputs = self.input_features or {}
        if TOKEN_POSES in inputs or self.state_pose_layout is None:
            return None
        return StateLayout(
            self.state_pose_layout,
            self.state_pose_start,
            self.state_gripper_index,
            self.state_extra_features,
            inputs[STATE].shape[0],
        )

    def model_spec(self) -> ModelSpec:
        """The plain-data spec :class:`~lerobot_actionflow.core.model.ActionFlowModel` is built from: this
        config's settings and the token layout of its input features."""
        inputs = self.input_features or {}
        state = self.state_layout()
        n_tokens, feature_dim = inputs[TOKEN_FEATURES].shape if state is None else (1, state.feature_dim)
        cameras = {
            f"{IMAGES}.{cam}": CameraPose(frame, tuple(pose))
            for cam, (frame, *pose) in self.camera_poses.items()
        }
        settings = {name: getattr(self, name) for name in ModelSpec.settings()}
        return ModelSpec(**{
            **settings, "tokens_per_step": n_tokens, "token_feature_dim": feature_dim,
            "image_keys": tuple(self.image_features), "camera_poses": cameras,
            "point_cloud": POINT_CLOUD in inputs,
        })  # fmt: skip

    def sampler(self) -> Sampler:
        """How chunks are sampled now (read at every call: an evaluation may change these fields)."""
        return Sampler(self.num_inference_steps, self.time_schedule, self.time_schedule_rate)

    @property
    def observation_delta_indices(self) -> list[int]:
        return list(range(1 - self.n_obs_steps, 1))

    @property
    def action_delta_indices(self) -> list[int]:
        # The chunk starts at the current step: every predicted action lies in the future.
        return list(range(self.horizon))

    @property
    def reward_delta_indices(self) -> None:
        return None


def _camera_name(image_key: str) -> str:
    """``observation.images.wrist -> wrist``."""
    return image_key.removeprefix(f"{IMAGES}.")


def _named(names: list[str] | None) -> str:
    """`` (names [...])`` for an error message, or nothing when the dataset gave none."""
    return f" (names {names})" if names else ""


def _flat_names(feature: dict | None) -> list[str] | None:
    """A dataset feature's element names as one list (LeRobot also writes ``{axis: [names]}``), or None."""
    names = (feature or {}).get("names")
    if isinstance(names, dict):
        names = next(iter(names.values()), None)
    return list(names) if isinstance(names, (list, tuple)) else None


def _camera_entry(cam: str, entry: list) -> list:
    """A ``camera_poses`` entry checked: ``[frame, x, y, z, qw, qx, qy, qz]`` with the numbers as floats
    (YAML reads ``-1e-3`` as a string)."""
    frame, *numbers = entry if isinstance(entry, (list, tuple)) and entry else [None]
    try:
        pose = [float(v) for v in numbers]
    except (TypeError, ValueError):
        pose = []
    if frame not in CAMERA_FRAMES or len(pose) != 7 or sum(v * v for v in pose[3:]) < 1e-12:
        raise ValueError(
            f"camera_poses[{cam!r}]={entry!r}; expected [frame, x, y, z, qw, qx, qy, qz]: frame in "
            f"{CAMERA_FRAMES}, the position in metres and a non-zero scalar-first quaternion, e.g. "
            "[eef, 0, 0, 0.05, 1, 0, 0, 0]"
        )
    return [frame, *pose]
