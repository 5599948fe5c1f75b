"""LeRobot environment config for the gym_actionflow tasks, registered as ``--env.type=actionflow``.

    lerobot-eval --policy.path=outputs/train/.../pretrained_model --env.type=actionflow \\
        --env.task=StackThree-v0 --env.variant=D1 --eval.n_episodes=50 --eval.batch_size=10

``--env.task`` is the task's id without the ``gym_actionflow/`` prefix (``StackThree-v0``, ...); LeRobot makes
``gym_actionflow/<task>``. Features follow the token schema: env key -> policy key.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

# Env observation key -> LeRobot key (the mapping lerobot-eval's observation preprocessing applies).
FEATURES_MAP = {
    "action": "action",
    "agent_pos": "observation.state",
    "environment_state": "observation.environment_state",
    "token_poses": "observation.token_poses",
    "token_features": "observation.token_features",
    "point_cloud": "observation.point_cloud",
    "pixels/wrist": "observation.images.wrist",
}


def _task_spec(task: str):
    from gym_actionflow import TASKS

    for spec in TASKS:
        if task in (spec.name, f"{spec.name}-v0", spec.env_id):
            return spec
    known = ", ".join(f"{spec.name}-v0" for spec in TASKS)
    raise ValueError(f"--env.task={task!r} is not a gym_actionflow task; expected one of: {known}")


@EnvConfig.register_subclass("actionflow")
@dataclass
class ActionFlowEnvConfig(EnvConfig):
    """A gym_actionflow task: token observations (+ wrist camera, + point cloud) and a 10-d pose action."""

    task: str | None = "StackThree-v0"
    fps: int = 20
    variant: str | None = None
    """Initial-state distribution: D0 / D1, or train / test for MugHanging; None = the task's first."""
    obs_mode: str = "state"
    """``state`` (tokens) or ``pixels`` (tokens + wrist RGB)."""
    hanger_obs: str | None = None
    """MugHanging only: ``pose`` or ``point_cloud``."""
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=lambda: dict(FEATURES_MAP))

    def __post_init__(self) -> None:
        spec = _task_spec(self.task)
        self.task = f"{spec.name}-v0"
        if self.variant is None:
            self.variant = spec.variants[0]
        elif self.variant not in spec.variants:
            raise ValueError(f"--env.variant={self.variant!r}; {spec.name} has variants {spec.variants}")
        if self.obs_mode not in ("state", "pixels"):
            raise ValueError(f"--env.obs_mode={self.obs_mode!r}; expected 'state' or 'pixels'")
        if self.hanger_obs is not None and spec.name != "MugHanging":
            raise ValueError(f"--env.hanger_obs is a MugHanging option; the task is {spec.name}")
        if not self.features:
            self.features = self._features_from_env(spec)

    def _features_from_env(self, spec) -> dict[str, PolicyFeature]:
        """Shapes read from the env itself (token and point counts depend on the task and its options)."""
        import gymnasium as gym

        env = gym.make(spec.env_id, **self.gym_kwargs)
        space = env.observation_space
        env.close()
        features = {
            "action": PolicyFeature(type=FeatureType.ACTION, shape=(10,)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=space["agent_pos"].shape),
            "environment_state": PolicyFeature(type=FeatureType.ENV, shape=space["environment_state"].shape),
            "token_poses": PolicyFeature(type=FeatureType.STATE, shape=space["token_poses"].shape),
            "token_features": PolicyFeature(type=FeatureType.STATE, shape=space["token_features"].shape),
        }
        if "point_cloud" in space.spaces:
            features["point_cloud"] = PolicyFeature(type=FeatureType.STATE, shape=space["point_cloud"].shape)
        if "pixels" in space.spaces:
            shape = space["pixels"]["wrist"].shape
            features["pixels/wrist"] = PolicyFeature(type=FeatureType.VISUAL, shape=shape)
        return features

    @property
    def gym_kwargs(self) -> dict:
        spec = _task_spec(self.task)
        kwargs = {"obs_mode": self.obs_mode, **spec.kwargs(self.variant)}
        if self.hanger_obs is not None:
            kwargs["hanger_obs"] = self.hanger_obs
        return kwargs
