"""Adversarial action sequences and the contact penetration they cause: the physics' robustness check.

A new user's policy (or an untrained one) sends targets below the table, absurd values and presses the hand
down onto objects. A real Panda cannot push a cube into a table, so neither may the simulation: the
robustness test (``tests/test_physics.py``) and the benchmark (``eval/bench_envs.py``) both drive every task
with :func:`adversarial_action` and read :func:`object_penetration` from MuJoCo's contacts.

Penetration is measured between scene geoms only (object vs table, object vs object, object vs fixture):
the finger pads are deliberately soft, and a finger touching the table is not an object sinking. The floor is
left out too: an object knocked off the table hits it at ~4 m/s and overlaps it by about speed x time step
for one physics step, which no contact parameter at 500 Hz prevents and which says nothing about sinking.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from gym_actionflow.base import HOME_ROT, WORKSPACE_HIGH, WORKSPACE_LOW, ManipulationEnv
from gym_actionflow.geometry import axis_angle_matrix, pose9

RANDOM_STEPS = 40
HUGE_STEPS = 10
PRESS_STEPS = 25
LIFT_STEPS = 8
"""One round of the sequence: random targets, huge values, then for every entity token a press-down (the
target 1 m below the entity, clipped to the workspace floor) and a lift."""
HUGE = 1e4
"""Magnitude of the 'huge' actions: finite, so the env must clip them rather than refuse them."""


def ignored_geoms(model: mujoco.MjModel) -> np.ndarray:
    """(ngeom,) bool: geoms left out of the penetration measure: the arm and gripper (bodies under
    ``panda_link0``) and the floor."""
    root = model.body("panda_link0").id
    in_robot = np.zeros(model.nbody, dtype=bool)
    for b in range(1, model.nbody):  # parents come before children in a compiled model
        in_robot[b] = b == root or in_robot[model.body_parentid[b]]
    ignored = in_robot[model.geom_bodyid]
    ignored[model.geom("floor").id] = True
    return ignored


def object_penetration(env: ManipulationEnv, ignored: np.ndarray | None = None) -> float:
    """Deepest penetration (m, >= 0) among the current contacts between two scene geoms (table, objects,
    fixtures).

    ``ignored`` is :func:`ignored_geoms` of ``env.model``, passed in to avoid recomputing it every step."""
    if ignored is None:
        ignored = ignored_geoms(env.model)
    d = env.data
    if d.ncon == 0:
        return 0.0
    geom = d.contact.geom[: d.ncon]  # (ncon, 2)
    scene = ~ignored[geom[:, 0]] & ~ignored[geom[:, 1]]
    if not scene.any():
        return 0.0
    return float(max(0.0, -d.contact.dist[: d.ncon][scene].min()))


def adversarial_action(obs: dict, step: int, rng: np.random.Generator) -> np.ndarray:
    """The ``step``-th action (10,) of the adversarial sequence, given the current observation.

    The sequence cycles through random poses anywhere in the workspace (random rotation and gripper), huge
    values, and pressing the closed or open hand straight down onto each entity token in turn."""
    poses = obs["token_poses"]
    n_entities = len(poses) - 1
    cycle = RANDOM_STEPS + HUGE_STEPS + n_entities * (PRESS_STEPS + LIFT_STEPS)
    t = step % cycle
    if t < RANDOM_STEPS:
        pos = rng.uniform(WORKSPACE_LOW - 0.1, WORKSPACE_HIGH + 0.1)
        rot = axis_angle_matrix(rng.normal(size=3) * 2.0)
        return np.concatenate([pose9(pos, rot), [rng.uniform(-1, 1)]]).astype(np.float32)
    t -= RANDOM_STEPS
    if t < HUGE_STEPS:
        return (rng.choice([-1.0, 1.0], size=10) * HUGE * rng.uniform(0.1, 1.0, size=10)).astype(np.float32)
    t -= HUGE_STEPS
    entity, phase = divmod(t, PRESS_STEPS + LIFT_STEPS)
    pos = poses[1 + entity, :3].astype(np.float64)
    grip = 1.0 if entity % 2 == 0 else -1.0
    if phase < PRESS_STEPS:
        target = np.array([pos[0], pos[1], pos[2] - 1.0])
    else:
        target = np.array([pos[0], pos[1], pos[2] + 0.15])
    return np.concatenate([pose9(target, HOME_ROT), [grip]]).astype(np.float32)


@dataclass
class AdversarialReport:
    worst_penetration: float
    """Deepest scene-contact penetration seen after any control step (m)."""
    finite: bool
    """qpos, qvel and every observation array stayed finite."""
    warnings: dict[str, int]
    """MuJoCo warnings raised (name -> count); empty when none."""


def run_adversarial(env: ManipulationEnv, seed: int = 0, steps: int = 300) -> AdversarialReport:
    """Reset ``env`` (the unwrapped env) with ``seed`` and apply ``steps`` adversarial actions."""
    ignored = ignored_geoms(env.model)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    worst, finite = object_penetration(env, ignored), True
    for step in range(steps):
        obs, *_ = env.step(adversarial_action(obs, step, rng))
        worst = max(worst, object_penetration(env, ignored))
        finite = finite and bool(np.isfinite(env.data.qpos).all() and np.isfinite(env.data.qvel).all())
        finite = finite and all(np.isfinite(v).all() for v in obs.values() if isinstance(v, np.ndarray))
        if not finite:
            break
    warnings = {
        mujoco.mjtWarning(i).name: int(w.number) for i, w in enumerate(env.data.warning) if w.number > 0
    }
    return AdversarialReport(worst, finite, warnings)


def resting_penetration(env: ManipulationEnv, seed: int = 0, steps: int = 10) -> float:
    """Deepest scene-contact penetration (m) after a reset and ``steps`` steps holding the home pose."""
    ignored = ignored_geoms(env.model)
    obs, _ = env.reset(seed=seed)
    grip = 1.0 if obs["agent_pos"][9] < 0.075 else -1.0  # keep a held object (Lightbulb) held
    hold = np.concatenate([obs["token_poses"][0], [grip]]).astype(np.float32)
    worst = 0.0
    for _ in range(steps):
        env.step(hold)
        worst = max(worst, object_penetration(env, ignored))
    return worst
