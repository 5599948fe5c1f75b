"""LeRobot environment config for the gym_actionflow tasks, registered as ``--env.type=actionflow``.

    lerobot-eval --policy.path=outputs/train/.../pretrained_model --env.type=actionflow \\
        --env.task=StackThree-v0 --env.variant=D1 --eval.n_episodes=50 --eval.batch_size=10

``--env.task`` is the task's id without the ``gym_actionflow/`` prefix (``StackThree-v0``, ...); LeRobot makes
``gym_actionflow/<task>``. Features follow the token schema (:mod:`lerobot_actionflow.schema`): env key ->
policy key.

A plain LeRobot camera layout (``observation.state`` and ``observation.images.<cam>``, no token keys, no
object poses), as a policy trained on such a dataset expects it:

    lerobot-eval ... --env.type=actionflow --env.task=Stack-v0 --env.obs_mode=pixels \
        --env.obs_layout=lerobot --env.cameras='[front,wrist]' --env.image_size=80
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import PolicyFeature
from lerobot.envs.configs import EnvConfig

from lerobot_actionflow import schema

TASK_OPTIONS: dict[str, tuple[str, ...]] = {
    "Lightbulb": ("socket_obs", "socket_pose", "socket_fit"),
    "MugHanging": ("hanger_obs", "mug_yaw", "mask_after_grasp"),
}
"""Env-config fields passed to ``gym.make`` for one task only (task name -> fields); None = the env's
default."""


def _task_spec(task: str):
    from gym_actionflow import find_task

    try:
        return find_task(task)
    except ValueError as err:
        raise ValueError(f"--env.task={task!r} is not a gym_actionflow task ({err})") from None


@EnvConfig.register_subclass("actionflow")
@dataclass
class ActionFlowEnvConfig(EnvConfig):
    """A gym_actionflow task: token observations (+ cameras, + point cloud), or the plain LeRobot layout
    (state + cameras), and a 10-d pose action."""

    task: str | None = "StackThree-v0"
    fps: int = 20
    variant: str | None = None
    """Initial-state distribution: D0 / D1 (/ D2 for ThreePieceAssembly, Coffee, Threading), or train / test /
    scene_moved for MugHanging; None = the task's first (the registry's ``variants`` lists them)."""
    obs_mode: str = "state"
    """``state`` (no image) or ``pixels`` (adds the cameras: ``cameras``, default the wrist camera)."""
    obs_layout: str | None = None
    """``tokens`` (the env's default: token keys, ``agent_pos``, object poses) or ``lerobot`` (``agent_pos``
    and the cameras only; needs ``obs_mode=pixels``)."""
    cameras: list[str] | None = None
    """With ``obs_mode=pixels``: the cameras, from ``front`` (static) and ``wrist``, e.g.
    ``--env.cameras='[front,wrist]'``; None = the env's default, the wrist camera."""
    image_size: int | None = None
    """Side of the square camera images in pixels; None = the task's default (84, or 80 for Lightbulb and
    MugHanging)."""
    hanger_obs: str | None = None
    """MugHanging only: ``pose`` or ``point_cloud``."""
    mug_yaw: str | None = None
    """MugHanging only: ``any`` (the env's default) or ``slight`` (the paper's protocol)."""
    mask_after_grasp: bool | None = None
    """MugHanging only, with ``obs_mode=pixels``: black out the wrist image but the mug while it is held."""
    socket_obs: str | None = None
    """Lightbulb only: ``pose`` (the env's default) or ``none`` (no socket token; needs obs_mode=pixels)."""
    socket_pose: str | None = None
    """Lightbulb only: ``any`` (the env's default), ``fixed`` (one socket pose, the paper's) or ``slight``."""
    socket_fit: str | None = None
    """Lightbulb only: ``strict`` (the env's default, 1.5 mm of clearance) or ``paper`` (2.5 mm, calibrated on
    the paper's replay baseline: eval/results/lightbulb_fit.md)."""
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=lambda: dict(schema.FEATURES_MAP))

    def __post_init__(self) -> None:
        spec = _task_spec(self.task)
        self.task = f"{spec.name}-v0"
        try:
            self.variant = spec.kwargs(self.variant, self.obs_mode, self.obs_layout, self.cameras)["variant"]
        except ValueError as err:
            raise ValueError(f"--env.{err}") from None
        if self.image_size is not None and (isinstance(self.image_size, bool) or self.image_size < 1):
            raise ValueError(f"--env.image_size={self.image_size!r}; expected a positive number of pixels")
        for owner, names in TASK_OPTIONS.items():
            for name in names:
                if getattr(self, name) is not None and spec.name != owner:
                    raise ValueError(f"--env.{name} is a {owner} option; the task is {spec.name}")
        if not self.features:
            self.features = self._features_from_env(spec)

    def _features_from_env(self, spec) -> dict[str, PolicyFeature]:
        """Shapes read from the env itself (token and point counts depend on the task and its options)."""
        import gymnasium as gym

        env = gym.make(spec.env_id, **self.gym_kwargs)
        shapes = schema.observation_shapes(env.observation_space)
        env.close()
        return schema.env_features(shapes)

    @property
    def gym_kwargs(self) -> dict:
        spec = _task_spec(self.task)
        kwargs = spec.kwargs(self.variant, self.obs_mode, self.obs_layout, self.cameras)
        if self.image_size is not None:
            kwargs["image_size"] = self.image_size
        for name in TASK_OPTIONS.get(spec.name, ()):
            if getattr(self, name) is not None:
                kwargs[name] = getattr(self, name)
        return kwargs
