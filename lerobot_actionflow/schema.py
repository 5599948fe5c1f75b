"""The token data contract, written once: env observation -> LeRobotDataset frame -> policy batch.

Every tool converts through this module (the recorder, the LeRobot env config, the rerun visualiser, the
benchmarks and the tests); a new observation modality is added here, in one place. It is a leaf: it imports
nothing else of ours (and LeRobot only inside the functions that build LeRobot's feature objects).

| env key | dataset / policy key | LeRobot type | shape |
|---|---|---|---|
| ``token_poses`` | ``observation.token_poses`` | STATE | (N, 9) pose vectors ``POSE_LAYOUT``, token 0 = EEF |
| ``token_features`` | ``observation.token_features`` | STATE | (N, F) one-hot token id + scalars |
| ``agent_pos`` | ``observation.state`` | STATE | (10,) EEF pose + gripper opening |
| ``environment_state`` | ``observation.environment_state`` | ENV | (9 (N - 1),) object poses, for baselines |
| ``point_cloud`` | ``observation.point_cloud`` | STATE | (P, 3) world points of a fixture |
| ``pixels/<cam>`` | ``observation.images.<cam>`` | VISUAL | (H, W, 3) uint8 (policy: (3, H, W) in [0, 1]) |
| (the action) | ``action`` | ACTION | (10,) target EEF pose + gripper command in [-1, 1] |

An env observation is a dict of arrays with the cameras nested under ``pixels``; "shapes" below are
``{flat env key: shape}`` with the cameras flattened to ``pixels/<cam>`` (:func:`observation_shapes`).

Two layouts of these keys (the env's ``obs_layout``): ``tokens``, the token keys and ``agent_pos`` (+ cameras,
+ point cloud), and ``lerobot``, a plain LeRobot dataset's ``observation.state`` and
``observation.images.<cam>`` only (none of :data:`TOKEN_KEYS`), which carries no object pose: a policy sees
the objects through the cameras, placed by each camera's pose (the env's ``camera_poses``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

if TYPE_CHECKING:
    from lerobot.configs.types import PolicyFeature

# ---------------------------------------------------------------------------- pose and action layout
POSE_NAMES = ("x", "y", "z", "r00", "r10", "r20", "r01", "r11", "r21")
"""Position, then the first and second columns of the rotation matrix (continuous 6D rotation)."""
POSE_DIM = len(POSE_NAMES)
POSE_LAYOUT = "[x, y, z, r00, r10, r20, r01, r11, r21]"
GRIPPER_DIM = 1
ACTION_DIM = POSE_DIM + GRIPPER_DIM
ACTION_NAMES = (*POSE_NAMES, "gripper")
"""Action: absolute target EEF pose (world frame) + gripper command in [-1 open, 1 close]."""
STATE_NAMES = (*POSE_NAMES, "gripper_opening")
"""``observation.state``: the EEF pose + the gripper opening in metres."""

# ---------------------------------------------------------------------------- dataset / policy keys
TOKEN_POSES = "observation.token_poses"
TOKEN_FEATURES = "observation.token_features"
STATE = "observation.state"
ENV_STATE = "observation.environment_state"
POINT_CLOUD = "observation.point_cloud"
IMAGES = "observation.images"
"""Prefix of the camera keys: ``observation.images.<cam>``."""
ACTION = "action"
PIXELS = "pixels"
"""The env key under which the cameras are nested: ``obs["pixels"]["<cam>"]``."""

_ENV_KEYS: dict[str, tuple[str, str]] = {  # env key: (dataset / policy key, LeRobot FeatureType name)
    "token_poses": (TOKEN_POSES, "STATE"),
    "token_features": (TOKEN_FEATURES, "STATE"),
    "agent_pos": (STATE, "STATE"),
    "environment_state": (ENV_STATE, "ENV"),
    "point_cloud": (POINT_CLOUD, "STATE"),
}
_NAMES = {"agent_pos": list(STATE_NAMES)}
CAMERAS = ("front", "wrist")
"""The cameras a gym_actionflow env can have (``obs_mode="pixels"``, chosen by its ``cameras``): ``front``,
static, and ``wrist``, on the hand (gym_actionflow's ``registry.CAMERAS``; this module imports nothing of
ours)."""
TOKEN_KEYS = ("token_poses", "token_features", "environment_state", "point_cloud")
"""The env keys of the token layout that the LeRobot layout leaves out: tokens and object poses."""

CAMERA_FRAMES = ("world", "eef")
"""Where a camera's pose is given: ``world``, a static camera's world pose; ``eef``, a hand camera's fixed
pose in the end-effector frame of ``observation.state`` (its world pose is the end-effector pose times it)."""
CAMERA_CONVENTION = "MuJoCo's camera frame: looking along its -z axis, x the image's right, y its up"

FEATURES_MAP: dict[str, str] = {
    ACTION: ACTION,
    **{env_key: key for env_key, (key, _) in _ENV_KEYS.items()},
    **{f"{PIXELS}/{cam}": f"{IMAGES}.{cam}" for cam in CAMERAS},
}
"""Env key -> dataset / policy key, as lerobot-eval's observation preprocessing maps them."""


def policy_key(env_key: str) -> str:
    """The dataset / policy key of a flat env key: ``token_poses -> observation.token_poses``,
    ``pixels/wrist -> observation.images.wrist``."""
    if env_key.startswith(f"{PIXELS}/"):
        return f"{IMAGES}.{env_key.removeprefix(f'{PIXELS}/')}"
    if env_key not in FEATURES_MAP:
        raise KeyError(
            f"{env_key!r} is not an observation key of the token schema; expected one of "
            f"{sorted(FEATURES_MAP)}"
        )
    return FEATURES_MAP[env_key]


def _is_camera(env_key: str) -> bool:
    return env_key.startswith(f"{PIXELS}/")


def obs_layout(shapes: Mapping[str, tuple[int, ...]]) -> str:
    """``lerobot`` when the observation holds ``agent_pos`` and cameras only (no token key, no object pose),
    else ``tokens``: which of the two layouts an env's or a dataset's shapes follow."""
    if any(key in shapes for key in TOKEN_KEYS):
        return "tokens"
    return "lerobot" if any(_is_camera(key) for key in shapes) else "tokens"


# ---------------------------------------------------------------------------- shapes and feature specs
def observation_shapes(space) -> dict[str, tuple[int, ...]]:
    """``{flat env key: shape}`` of an env's observation space (a gymnasium ``Dict``), in the schema's order
    (the table above; cameras last) whatever the order of the space."""
    flat = {}
    for key, sub in space.spaces.items():
        if key == PIXELS:
            flat.update({f"{PIXELS}/{cam}": tuple(s.shape) for cam, s in sub.spaces.items()})
        else:
            flat[key] = tuple(sub.shape)
    ordered = {k: flat[k] for k in _ENV_KEYS if k in flat}
    return ordered | {k: v for k, v in flat.items() if k not in ordered}


def token_shapes(n_tokens: int, feature_dim: int) -> dict[str, tuple[int, ...]]:
    """The shapes of an observation with ``n_tokens`` tokens of ``feature_dim`` features, as a gym_actionflow
    env gives them (for synthetic tasks, benchmarks and tests); add ``point_cloud`` / ``pixels/<cam>`` to it
    for those modalities."""
    return {
        "token_poses": (n_tokens, POSE_DIM),
        "token_features": (n_tokens, feature_dim),
        "agent_pos": (len(STATE_NAMES),),
        "environment_state": (POSE_DIM * (n_tokens - 1),),
    }


def _token_names(
    shapes: Mapping[str, tuple[int, ...]], token_names: Sequence[str], scalar_names: Sequence[str]
) -> dict[str, list | dict]:
    """LeRobot ``names`` of the token keys: a 2-D key names each axis (``{"tokens": [...], "pose": [...]}``,
    LeRobot's ``{axis: [names]}`` form), the flat ``environment_state`` each element (``cube_a.x``...), as
    a 1-D key's list of names, which LeRobot's viewers use to label the series."""
    tokens = list(token_names)
    columns = [f"is_{name}" for name in tokens] + ["gripper_opening", *scalar_names]
    expected = {
        "token_poses": (len(tokens), POSE_DIM),
        "token_features": (len(tokens), len(columns)),
        "environment_state": (POSE_DIM * (len(tokens) - 1),),
    }
    for env_key, shape in expected.items():
        if env_key in shapes and tuple(shapes[env_key]) != shape:
            raise ValueError(
                f"{env_key} has shape {tuple(shapes[env_key])} but token_names {tokens} and scalar_names "
                f"{list(scalar_names)} describe {shape}; expected one name per token (token 0 = EEF) and the "
                "feature columns one-hot id + gripper opening + task scalars"
            )
    return {
        "token_poses": {"tokens": tokens, "pose": list(POSE_NAMES)},
        "token_features": {"tokens": tokens, "features": columns},
        "environment_state": [f"{name}.{p}" for name in tokens[1:] for p in POSE_NAMES],
    }


IMAGE_STORAGES = ("image", "video")
"""How a dataset stores camera frames: ``image``, each frame a PNG in the parquet files (read by
LeRobot's streaming loader without FFmpeg); ``video``, AV1 video files (smaller; decoding needs PyAV or
torchcodec)."""


def dataset_features(
    shapes: Mapping[str, tuple[int, ...]],
    token_names: Sequence[str] | None = None,
    scalar_names: Sequence[str] = (),
    image_storage: str = "video",
) -> dict[str, dict]:
    """LeRobotDataset feature specs (``LeRobotDataset.create(features=...)``) of observations with these
    shapes, plus the action. Cameras are stored as ``image_storage`` (:data:`IMAGE_STORAGES`).

    ``token_names`` (the env's ``token_names``: ``eef``, then its entities) and ``scalar_names`` (its task
    scalars) name the rows and columns of the token keys, so a dataset says which row is which object;
    without them those keys have ``names: None``. The LeRobot layout has no token keys: it ignores them, and
    its features are ``observation.state``, ``observation.images.<cam>`` and ``action``."""
    if image_storage not in IMAGE_STORAGES:
        raise ValueError(f"image_storage={image_storage!r}; expected one of {IMAGE_STORAGES}")
    names = dict(_NAMES)
    if token_names is not None and obs_layout(shapes) == "tokens":
        names |= _token_names(shapes, token_names, scalar_names)
    features = {}
    for env_key, shape in shapes.items():
        if _is_camera(env_key):
            spec = {"dtype": image_storage, "shape": tuple(shape), "names": ["height", "width", "channels"]}
        else:
            spec = {"dtype": "float32", "shape": tuple(shape), "names": names.get(env_key)}
        features[policy_key(env_key)] = spec
    features[ACTION] = {"dtype": "float32", "shape": (ACTION_DIM,), "names": list(ACTION_NAMES)}
    return features


def camera_info(
    frame: str, pose: Sequence[float], quaternion: Sequence[float], fovy: float
) -> dict[str, Any]:
    """Where a camera was, as its dataset feature's ``info`` entries (``meta/info.json``; LeRobot keeps them
    beside its own ``video.*`` entries): ``camera.frame`` (:data:`CAMERA_FRAMES`), ``camera.pose`` (the pose
    vector ``POSE_LAYOUT`` of :data:`CAMERA_CONVENTION`'s frame), the same rotation as
    ``camera.quaternion_wxyz`` (w, x, y, z), ``camera.fovy_degrees`` (vertical field of view: square pixels,
    focal length (H / 2) / tan(fovy / 2) pixels, principal point at the centre) and ``camera.convention``.
    Numbers are rounded to 1e-6 (a micrometre), which drops float32 digits and 1e-17 remainders of zeros."""
    if frame not in CAMERA_FRAMES:
        raise ValueError(f"camera frame {frame!r}; expected one of {CAMERA_FRAMES}")

    def rounded(values: Sequence[float]) -> list[float]:
        return [round(float(v), 6) + 0.0 for v in values]  # + 0.0: no negative zero

    return {
        "camera.frame": frame,
        "camera.pose": rounded(pose),
        "camera.quaternion_wxyz": rounded(quaternion),
        "camera.fovy_degrees": float(fovy),
        "camera.convention": CAMERA_CONVENTION,
    }


def env_features(shapes: Mapping[str, tuple[int, ...]]) -> dict[str, PolicyFeature]:
    """LeRobot ``EnvConfig.features``: ``{flat env key: PolicyFeature}`` with the env's own shapes (cameras
    (H, W, 3)), plus the action; LeRobot maps them to policy keys with :data:`FEATURES_MAP`."""
    from lerobot.configs.types import FeatureType, PolicyFeature

    features = {ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))}
    for env_key, shape in shapes.items():
        kind = FeatureType.VISUAL if _is_camera(env_key) else FeatureType[_ENV_KEYS[env_key][1]]
        features[env_key] = PolicyFeature(type=kind, shape=tuple(shape))
    return features


def policy_features(
    shapes: Mapping[str, tuple[int, ...]],
) -> tuple[dict[str, PolicyFeature], dict[str, PolicyFeature]]:
    """``(input_features, output_features)`` of a policy config for observations with these shapes: what
    LeRobot derives from a dataset or an env (cameras become channel-first (3, H, W))."""
    from lerobot.configs.types import FeatureType, PolicyFeature

    features = env_features(shapes)
    inputs = {}
    for env_key, feature in features.items():
        if env_key == ACTION:
            continue
        if feature.type is FeatureType.VISUAL:
            h, w, c = feature.shape
            feature = PolicyFeature(type=FeatureType.VISUAL, shape=(c, h, w))
        inputs[policy_key(env_key)] = feature
    return inputs, {ACTION: features[ACTION]}


# ---------------------------------------------------------------------------- conversions
def flatten_observation(obs: Mapping) -> dict[str, np.ndarray]:
    """An env observation as ``{flat env key: array}``: the cameras un-nested to ``pixels/<cam>``."""
    flat = {k: v for k, v in obs.items() if k != PIXELS}
    flat.update({f"{PIXELS}/{cam}": image for cam, image in obs.get(PIXELS, {}).items()})
    return flat


def dataset_frame(obs: Mapping, action: np.ndarray, task: str) -> dict:
    """One ``LeRobotDataset.add_frame`` frame: the observation under dataset keys, the action, the task."""
    frame = {policy_key(k): v for k, v in flatten_observation(obs).items()}
    frame[ACTION] = np.asarray(action, dtype=np.float32)
    frame["task"] = task
    return frame


def policy_batch(obs: Mapping) -> dict[str, torch.Tensor]:
    """A single env observation as the batch of one that LeRobot's env preprocessing gives a policy:
    float32 tensors ``[1, ...]``, camera images ``[1, 3, H, W]`` in [0, 1]."""
    batch = {}
    for env_key, value in flatten_observation(obs).items():
        if _is_camera(env_key):
            tensor = torch.from_numpy(np.asarray(value)).permute(2, 0, 1).float() / 255
        else:
            tensor = torch.from_numpy(np.asarray(value, dtype=np.float32))
        batch[policy_key(env_key)] = tensor.unsqueeze(0)
    return batch
