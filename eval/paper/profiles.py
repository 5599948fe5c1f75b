"""The models and the profiles of the paper benchmark (``python -m eval.paper``): which policies, how much
data, how long to train and how many evaluation episodes, for this 2-core CPU (``cpu``), a lent GPU (``gpu``)
and a minutes-long check of the harness itself (``smoke``, whose numbers mean nothing).

A profile says what runs; :mod:`eval.paper.plan` turns it into cells. Every knob a table or a plot depends on
lives here, so a result's JSON names its profile and the profile names everything else.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Model:
    """One policy as ``lerobot-train`` builds it: ``--policy.type`` plus the flags that make it this model."""

    name: str
    """What ``--models`` and the tables call it (``A.1``, ``DP``...)."""
    policy_type: str
    flags: tuple[str, ...] = ()
    flow: bool = True
    """A flow policy (ActionFlow) takes ``--policy.time_schedule``; diffusion takes DDIM steps instead."""


# ActionFlow trains with ActionFlowConfig's defaults (the measured recipe: lr 1e-3, 100 warm-up steps, cosine
# decay over the run) plus its task recipe's settings (lerobot_actionflow/recipes); a model adds only what
# makes it that model. Cells trained before those were the defaults passed them as flags (their commands say
# so); the training is the same.
# LeRobot's Diffusion Policy normalises STATE, VISUAL and ACTION features but has no entry for ENV, so it
# would read ``observation.environment_state`` (the object poses, in metres) raw: objects that move by a few
# centimetres barely move its input. The baseline min-max normalises them like the robot state.
DIFFUSION_NORMALISATION = (
    '--policy.normalization_mapping={"VISUAL": "MEAN_STD", "STATE": "MIN_MAX", "ENV": "MIN_MAX", '
    '"ACTION": "MIN_MAX"}'
)
# Diffusion Policy's chunk as ActionFlow's (16 actions, 8 executed, 2 observations; LeRobot's own defaults,
# 64 / 32, are its PushT setting); everything else is LeRobot's default unless a profile shrinks the UNet.
DIFFUSION_FLAGS = ("--policy.horizon=16", "--policy.n_action_steps=8", DIFFUSION_NORMALISATION)

MODELS: dict[str, Model] = {
    m.name: m
    for m in (
        Model("A.1", "actionflow", ("--policy.architecture=ipa",)),
        Model("A.2", "actionflow", ("--policy.architecture=multi_token",)),
        Model("A.3", "actionflow", ("--policy.architecture=single_token",)),
        # The Euclidean flow with its velocity in each action's frame, as the SE(3) flow's (EuclideanFlow);
        # cells before the flag were trained with the EEF-frame velocity and are kept as superseded.
        Model("A.1-euclidean", "actionflow",
              ("--policy.action_space=euclidean", "--policy.euclidean_frame=action")),
        Model("DP", "diffusion", DIFFUSION_FLAGS, flow=False),
    )
}


@dataclass(frozen=True)
class Group:
    """Cells that share a task and variant: one dataset per demonstration count, one training per model."""

    task: str
    variant: str
    demos: tuple[int, ...]
    models: tuple[str, ...]
    env_kwargs: tuple[tuple[str, str], ...] = ()
    eval_variants: tuple[str, ...] = ()
    """Layouts evaluated (default: the training variant)."""
    title: str = ""
    """How tables and plots name the group (default ``task variant``)."""
    replay_offsets_mm: tuple[float, ...] = ()
    """Replay baselines on the recorded demonstrations, shifted sideways by each offset (generalisation)."""
    steps: int | str | None = None
    """Training steps for this group instead of the profile's: a number, or ``"recipe"`` for the task
    recipe's steps (a task with much longer demonstrations, or one that needs more epochs)."""


@dataclass(frozen=True)
class Profile:
    name: str
    device: str
    batch_size: int
    steps: dict[str, int]
    """Training steps per experiment."""
    seeds: tuple[int, ...]
    eval_episodes: int
    eval_batch_size: int
    checkpoints: int
    """Checkpoints saved per training and evaluated; above 1, tables add the best of them (labelled)."""
    policy_flags: dict[str, tuple[str, ...]]
    """Extra ``lerobot-train`` flags per ``--policy.type`` (the CPU's smaller UNet)."""
    notes: dict[str, str]
    """Said next to every number of a model of that ``--policy.type``."""
    sample_efficiency: tuple[Group, ...]
    inference_steps: tuple[Group, ...]
    generalisation: tuple[Group, ...]
    min_steps: dict[str, int] = field(default_factory=dict)
    """At least this many training steps per ``--policy.type``, whatever the experiment or group sets."""
    inference_ks: tuple[int, ...] = (1, 2, 4, 10, 100)
    schedules: tuple[str, ...] = ("uniform", "exponential")
    record_workers: int = 1


MIMICGEN_D0 = ("StackThree", "ThreePieceAssembly", "Coffee", "Threading")
# The published protocol (Equivariant Diffusion Policy, Table 1): each task on its hardest variant.
PUBLISHED = (
    ("Stack", "D1"),
    ("StackThree", "D1"),
    ("ThreePieceAssembly", "D2"),
    ("Coffee", "D2"),
    ("Threading", "D2"),
)
ROBOMIMIC = ("RobosuiteLift", "RobosuiteCan", "RobosuiteSquare", "RobosuiteToolHang")
"""The paper's inference-steps tasks, on robosuite itself."""
MUG = (("mug_yaw", "slight"),)  # the paper's protocol: slight variations of the mug pose
MUG_PC = (*MUG, ("hanger_obs", "point_cloud"))
INFERENCE_MODELS = ("A.1", "A.1-euclidean", "DP")
CPU_UNET = ("--policy.down_dims=[64,128,256]",)
# LeRobot's Diffusion Policy scored 0 % at 2000-6000 steps with its 1e-4 learning rate on every cpu-profile
# task and 25 % on Stack at 8000 (eval/results/diffusion_baseline.md); on this CPU it trains at least 8000
# steps, with ActionFlow's optimiser settings (1e-3, 100 warm-up steps), which halved its loss at 2000 steps.
CPU_DIFFUSION = (*CPU_UNET, "--policy.optimizer_lr=1e-3", "--policy.scheduler_warmup_steps=100")
CPU_DIFFUSION_STEPS = 8000


def _generalisation(
    mug_demos: int, bulb_demos: int, models: tuple[str, ...], mug_steps: int | str | None = None,
    bulb_steps: int | str | None = None,
) -> tuple[Group, ...]:
    return (
        Group("MugHanging", "train", (mug_demos,), models, MUG, ("train", "test"),
              "MugHanging (hanger pose)", steps=mug_steps),
        Group("MugHanging", "train", (mug_demos,), ("A.1",), MUG_PC, ("train", "test"),
              "MugHanging (hanger point cloud)", steps=mug_steps),
        Group("Lightbulb", "D0", (bulb_demos,), models, (), ("D0",), "Lightbulb", (0.0, 1.5),
              steps=bulb_steps),
    )  # fmt: skip


CPU = Profile(
    name="cpu",
    device="cpu",
    batch_size=32,
    steps={"sample-efficiency": 2000, "inference-steps": 3000, "generalisation": 3000},
    seeds=(1,),
    eval_episodes=50,
    eval_batch_size=10,
    checkpoints=1,
    policy_flags={"diffusion": CPU_DIFFUSION},
    notes={"diffusion": "UNet down_dims 64-128-256, lr 1e-3 (cpu profile)"},
    min_steps={"diffusion": CPU_DIFFUSION_STEPS},
    sample_efficiency=(
        *(Group(t, "D0", (20, 50, 200), ("A.1", "A.2", "A.3", "DP")) for t in MIMICGEN_D0),
        Group("StackThree", "D1", (100, 200), ("A.1", "DP")),
        Group("Threading", "D2", (100, 200), ("A.1", "DP")),
    ),
    inference_steps=(
        *(Group(t, "D0", (100,), INFERENCE_MODELS) for t in ("Threading", "Coffee", "RobosuiteSquare")),
        # Tool Hang's 100 demonstrations hold 39k frames (Square's 11k): its recipe's 11000 steps give it
        # Square's epochs.
        Group("RobosuiteToolHang", "D0", (100,), INFERENCE_MODELS, steps="recipe"),
    ),
    # The recipes' steps: MugHanging's moved hanger needs 6000 (16 epochs of its 50 demonstrations) on a
    # CPU; Lightbulb's millimetre insertion gets the same 6000 (23 epochs of its 100 demonstrations).
    generalisation=_generalisation(50, 100, ("A.1", "DP"), mug_steps="recipe", bulb_steps="recipe"),
)

GPU = Profile(
    name="gpu",
    device="cuda",
    batch_size=64,
    steps={"sample-efficiency": 50_000, "inference-steps": 50_000, "generalisation": 30_000},
    seeds=(1, 2, 3),
    eval_episodes=50,
    eval_batch_size=50,
    checkpoints=10,
    policy_flags={},
    notes={"diffusion": "LeRobot's default UNet"},
    sample_efficiency=(
        *(Group(t, "D0", (20, 50, 200, 1000), ("A.1", "A.2", "A.3", "DP")) for t in MIMICGEN_D0),
        *(Group(t, v, (100, 200, 1000), ("A.1", "A.2", "A.3", "DP")) for t, v in PUBLISHED),
    ),
    inference_steps=tuple(
        Group(t, "D0", (1000,), ("A.1", "A.1-euclidean", "DP")) for t in ("Threading", "Coffee", *ROBOMIMIC)
    ),
    generalisation=_generalisation(50, 100, ("A.1", "DP")),
    record_workers=4,
)

SMOKE = Profile(
    name="smoke",
    device="cpu",
    batch_size=4,
    steps={"sample-efficiency": 2, "inference-steps": 2, "generalisation": 2},
    seeds=(1,),
    eval_episodes=1,
    eval_batch_size=1,
    checkpoints=1,
    policy_flags={
        "actionflow": ("--policy.dim=32", "--policy.ipa_layers=1", "--policy.transformer_layers=1")
    },
    notes={"actionflow": "smoke profile: 2 training steps, numbers mean nothing"},
    sample_efficiency=(Group("Stack", "D0", (2,), ("A.1",)),),
    inference_steps=(Group("Stack", "D0", (2,), ("A.1",)),),
    # The replay baseline on the MugHanging demonstrations: its code path without recording a third dataset.
    generalisation=(
        Group(
            "MugHanging", "train", (2,), ("A.1",), MUG, ("train", "test"), "MugHanging (hanger pose)", (1.5,)
        ),
    ),
    inference_ks=(1,),
    schedules=("exponential",),
)

PROFILES = {p.name: p for p in (CPU, GPU, SMOKE)}
