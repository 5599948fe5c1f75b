"""``actionflow-generate``: many demonstrations from a few, by MimicGen's protocol, on any recording of a
gym_actionflow task.

    actionflow-generate outputs/stack_d0_10 --task Stack --variant D1 --episodes 200 --root outputs/stack_gen
    actionflow-generate outputs/mug_train_10 --task MugHanging --variant test --episodes 200 --workers 2

How (Mandlekar et al., MimicGen, 2023):

1. **Segment** every source episode into the task's object-centric subtasks
   (:attr:`gym_actionflow.registry.TaskSpec.subtasks`), cutting where the gripper command changes sign
   (closes on an object, opens to release it). Stack's episodes become *reach and grasp cube A*, *carry it
   onto cube B and open*, *leave*, each relative to one object, the subtask's reference. The cut comes once
   the hand has moved :data:`SETTLE_RADIUS` (10 cm) from where the gripper changed: the grasp's lift and the
   release's retreat stay with the object they were made at, as MimicGen's subtask-end offsets do. An
   episode whose gripper changes a different number of times (a regrasp) is left out, and the card says so.
2. **Transform** for a new layout: at the start of subtask i, one source episode is drawn (per subtask, by the
   generated episode's seed, among the :data:`NEAREST` whose moved segment the hand reaches by the shortest
   link, as MimicGen draws among nearest neighbours), and its segment's end-effector targets ``T`` move with
   the reference object, from where it was when that segment started (``O_src``) to where it is now
   (``O_new``): ``T' = O_new O_src^-1 T``. A carried object moves with the hand, so carrying cube A onto cube
   B follows cube B wherever it is. Beyond MimicGen, a subtask that carries an object also corrects for how
   that object sits in the hand now (``H_new``) against the source (``H_src``): ``T' = O_new O_src^-1 T H_src
   H_new^-1``, so the carried object, not the hand, retraces the source's path (a bulb grasped 2 mm higher
   still reaches the socket). Also beyond MimicGen, a symmetric object (``Subtask.symmetry``: a cube looks the
   same every quarter turn) is taken at whichever of its equivalent poses ``O_new Z_k`` keeps the segment's
   hand nearest where it is (:func:`least_turn`), as the experts grasp a cube by the faces nearest the wrist.
   MimicGen's plain transform turns the wrist with every random yaw of the cube, anywhere in the circle, which
   the experts never do (Stack Three D1 trained on such data: 0 % against 70 % from expert data).
3. **Link** the current target to the first transformed one as near the subtask's object as the hand already
   is (:func:`transit_end`: what comes before is the source's transit from elsewhere) by a straight, evenly
   timed motion (position along a line, rotation along the geodesic, at the scripted experts' speeds), the
   gripper held as it was.
4. **Execute** in the env and keep only the successes.

The output is an ordinary LeRobotDataset with the schema and observation settings of ``actionflow-record``
(``--obs-mode``, ``--cameras``, ``--env-kwarg`` as there), written by the same recorder: parallel
(``--workers``), durable and resumable (rerun the command), and a card saying where it came from: the source
dataset, the generation success rate, and (in ``meta/actionflow_generation.json``) the source episode of
every segment of every generated episode. The env's variant may be one the sources never showed (D1 or D2
from D0 sources, MugHanging ``test`` from ``train``): a segment follows its object wherever it is.

The source must hold the token observation (``observation.token_poses`` with the reference objects), and
only successful episodes: an ``actionflow-record`` dataset keeps only successes; another recording needs a
``next.success`` column (its episodes ending in success are used).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lerobot_actionflow import schema

GENERATION_FILE = "actionflow_generation.json"
"""``meta/<this>``: for each generated episode (by seed), the source episode of each of its segments."""
SUCCESS_KEY = "next.success"
"""A recording's per-frame success flag (LeRobot's name); its episodes that end in success are sources."""
SETTLE_RADIUS = 0.1
"""After a gripper change the hand holds still (within the experts' jitter) while the fingers move; the next
subtask starts once the target is this far (m) from where the change was commanded."""
HOLD_STEPS = 10
"""Steps the last target is held after the plan, for the success check to see the scene settle."""
NEAREST: int | None = 3
"""Each subtask's segment is drawn (uniformly, by the episode's seed) among the NEAREST source segments whose
link from the hand is shortest, MimicGen's nearest-neighbour selection measured by the motion it costs rather
than the object's pose; None draws among all."""
TRIM_TRANSIT = True
"""Link straight to the first target of a moved segment as near its object as the hand is
(:func:`transit_end`), skipping the source's transit; False replays the whole moved segment (MimicGen)."""
LINK_SPEED = 0.02
LINK_ROT_SPEED = 0.12
"""Speeds of the linking motion, metres and radians per control step (the scripted experts' defaults)."""


# ---------------------------------------------------------------------------- poses
def to_matrix(p9: np.ndarray) -> np.ndarray:
    """A (9,) ``[x, y, z, r00, r10, r20, r01, r11, r21]`` pose as a 4x4 transform."""
    from gym_actionflow.geometry import pose9_to_rt

    rot, pos = pose9_to_rt(p9)
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rot, pos
    return out


def to_pose9(m: np.ndarray) -> np.ndarray:
    from gym_actionflow.geometry import pose9

    return pose9(m[:3, 3], m[:3, :3])


def _matrix(pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rot, pos
    return out


def link_steps(start: np.ndarray, end: np.ndarray) -> int:
    """How many steps :func:`link` takes from ``start`` to ``end``: as many as the slower of the straight line
    and the rotation's geodesic needs at the link speeds (at least one)."""
    from gym_actionflow.geometry import rotation_log

    turn = float(np.linalg.norm(rotation_log(start[:3, :3].T @ end[:3, :3])))
    distance = float(np.linalg.norm(end[:3, 3] - start[:3, 3]))
    return max(1, math.ceil(max(distance / LINK_SPEED, turn / LINK_ROT_SPEED)))


def link(start: np.ndarray, end: np.ndarray) -> list[np.ndarray]:
    """4x4 targets from ``start`` (excluded) to ``end`` (included): a straight line and the rotation's
    geodesic, evenly timed, :func:`link_steps` of them."""
    from gym_actionflow.geometry import axis_angle_matrix, rotation_log

    delta = rotation_log(start[:3, :3].T @ end[:3, :3])
    steps = link_steps(start, end)
    out = []
    for k in range(1, steps + 1):
        s = k / steps
        m = np.eye(4)
        m[:3, :3] = start[:3, :3] @ axis_angle_matrix(s * delta)
        m[:3, 3] = (1 - s) * start[:3, 3] + s * end[:3, 3]
        out.append(m)
    return out


def turns(n: int) -> np.ndarray:
    """``[n, 4, 4]``: the rotations by 360/n degrees x k (k < n) about the z axis, the equivalent frames of an
    object with n-fold symmetry (``Subtask.symmetry``) when right-multiplied onto its pose."""
    from gym_actionflow.geometry import yaw_matrix

    out = np.tile(np.eye(4), (n, 1, 1))
    for k in range(n):
        out[k, :3, :3] = yaw_matrix(2 * np.pi * k / n)
    return out


def least_turn(
    hand: np.ndarray, moves: np.ndarray, targets: np.ndarray, regrips: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Of the equivalent transforms of a segment's ``targets`` ``[L, 4, 4]`` (``moves[k] @ T @ regrips[j]``,
    one per symmetric pose of the reference and of the carried object), the pair that keeps the segment
    nearest the hand as it is now: the least mean over its targets of the time a link from ``hand`` would
    take (distance over :data:`LINK_SPEED` plus turn over :data:`LINK_ROT_SPEED`). So a cube is grasped by
    the faces nearest the wrist's yaw and set down at the turn nearest the one it is held at, as the experts
    do; turning the reference and the carried object together can leave the hand's rotation as it was and
    move only where the path runs, hence the distance."""
    moved = np.einsum("kab,lbc,jcd->kjlad", moves, targets, regrips)
    cos = (np.einsum("ab,kjlab->kjl", hand[:3, :3], moved[..., :3, :3]) - 1.0) / 2.0
    angle = np.arccos(np.clip(cos, -1.0, 1.0))  # trace(hand^T target) = 1 + 2 cos(angle)
    distance = np.linalg.norm(moved[..., :3, 3] - hand[:3, 3], axis=-1)
    cost = (distance / LINK_SPEED + angle / LINK_ROT_SPEED).mean(axis=-1)
    k, j = np.unravel_index(int(np.argmin(cost)), cost.shape)
    return moves[k], regrips[j]


def transit_end(targets: list[np.ndarray], hand: np.ndarray, reference: np.ndarray) -> int:
    """The first of a moved segment's targets that is no farther from the reference object's origin than
    the hand is now, give or take one link step (0 when the first already is; the last when none is).
    What comes before is the source's transit from wherever its previous subtask ended, which, moved with
    this subtask's object, starts at a point that has nothing to do with where the hand is (carrying cube A
    onto cube B, it starts where the source's cube A lay relative to its cube B): the link goes straight
    here instead, without the detour."""
    reach = float(np.linalg.norm(hand[:3, 3] - reference)) + LINK_SPEED
    near = [i for i, m in enumerate(targets) if np.linalg.norm(m[:3, 3] - reference) <= reach]
    return near[0] if near else len(targets) - 1


# ---------------------------------------------------------------------------- sources
@dataclass
class Segment:
    """One subtask of one source episode: its actions and its reference object's pose when it started."""

    episode: int
    reference: str
    object_pose: np.ndarray
    """4x4 world pose of the reference object at the segment's first frame."""
    actions: np.ndarray
    """``[L, 10]``: absolute end-effector targets (pose9) and the gripper command."""
    carried: str | None = None
    in_hand: np.ndarray | None = None
    """The carried object's pose in the end-effector frame at the segment's first frame (4x4)."""
    symmetry: int = 1
    carried_symmetry: int = 1
    """n-fold symmetries about the reference's and the carried object's z axes (``Subtask``)."""


@dataclass
class Source:
    """A source dataset cut into subtasks: ``segments[i]`` holds subtask i of every usable episode."""

    root: str
    task: str
    segments: list[list[Segment]]
    skipped: dict[int, str] = field(default_factory=dict)
    """Source episodes left out, with why."""

    @property
    def episodes(self) -> list[int]:
        return [segment.episode for segment in self.segments[0]]


def split(actions: np.ndarray, n_subtasks: int) -> list[tuple[int, int]] | None:
    """``[start, end)`` of each subtask; None when the episode does not have ``n_subtasks - 1`` gripper
    changes. A subtask ends where the gripper command changes sign *and the hand has finished there*: the
    frames that hold the hand still while the fingers close (or open) belong to the subtask that brought it
    there, and the next one starts when the target has moved :data:`SETTLE_RADIUS` away, so a grasp completes
    where its object is, not where the next subtask's object would put it."""
    closed = actions[:, -1] > 0
    changes = [i for i in range(1, len(closed)) if closed[i] != closed[i - 1]]
    if len(changes) != n_subtasks - 1:
        return None
    cuts = []
    for change in changes:
        moved = np.linalg.norm(actions[change:, :3] - actions[change, :3], axis=1) > SETTLE_RADIUS
        cut = change + int(np.argmax(moved)) if moved.any() else len(actions) - 1
        cuts.append(max(cut, cuts[-1] + 1 if cuts else 1))
    bounds = [0, *cuts, len(actions)]
    if any(b >= e for b, e in zip(bounds[:-1], bounds[1:], strict=True)):
        return None
    return list(zip(bounds[:-1], bounds[1:], strict=True))


def _read_columns(root: Path, columns: list[str]) -> dict[str, np.ndarray]:
    """``columns`` of every data file of the dataset at ``root``, as numpy arrays (frame-major)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    files = sorted((root / "data").rglob("*.parquet"))
    if not files:
        raise ValueError(f"source {root}: no data files under data/; expected a LeRobotDataset")
    table = pa.concat_tables([pq.read_table(f, columns=columns) for f in files])
    return {name: np.asarray(table.column(name).to_pylist()) for name in columns}


def load_source(root: str | Path, task: str) -> Source:
    """Read and segment the source dataset at ``root`` for ``task``; every bad input is a ValueError saying
    what was found and what is expected."""
    from gym_actionflow import find_task

    from lerobot_actionflow.tools.record.log import RecordingLog

    root = Path(root)
    spec = find_task(task)
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise ValueError(f"source {root}: no meta/info.json; expected a LeRobotDataset folder (its --root)")
    if not spec.subtasks:
        raise ValueError(
            f"{spec.name} declares no subtasks (gym_actionflow.registry); generation needs them. Tasks with "
            f"subtasks: {[t.name for t in _generatable()]}"
        )
    info = json.loads(info_path.read_text())
    log = RecordingLog.load(root)
    if log is not None and find_task(log.recipe["task"]).name != spec.name:
        raise ValueError(
            f"source {root} is a recording of {find_task(log.recipe['task']).name}, not {spec.name}; pass "
            f"--task {find_task(log.recipe['task']).name} or a source of {spec.name}"
        )
    if int(info.get("total_episodes", 0)) == 0:
        raise ValueError(f"source {root} holds no episode; expected at least one successful demonstration")
    poses = info["features"].get(schema.TOKEN_POSES)
    names = (poses or {}).get("names")
    tokens = list(names["tokens"]) if isinstance(names, dict) and "tokens" in names else None
    if tokens is None:
        raise ValueError(
            f"source {root} has no named {schema.TOKEN_POSES}; generation moves segments with their objects "
            "and needs the token layout (actionflow-record's default, not --obs-layout lerobot)"
        )
    needed = [name for sub in spec.subtasks for name in (sub.object, sub.carried) if name]
    missing = sorted(set(needed) - set(tokens))
    if missing:
        raise ValueError(
            f"source {root}: tokens {tokens} lack {missing}, objects of {spec.name}'s subtasks "
            f"({[tuple(sub) for sub in spec.subtasks]}); record the source with those objects as tokens"
        )
    columns = ["episode_index", "frame_index", schema.ACTION, schema.TOKEN_POSES]
    has_success = SUCCESS_KEY in info["features"]
    if log is None and not has_success:
        raise ValueError(
            f"source {root} says neither which episodes succeeded (no {SUCCESS_KEY} column) nor that all did "
            "(no actionflow-record log); record successful episodes only, or add a next.success column"
        )
    frames = _read_columns(root, columns + ([SUCCESS_KEY] if has_success else []))
    order = np.lexsort((frames["frame_index"], frames["episode_index"]))
    frames = {name: values[order] for name, values in frames.items()}
    segments: list[list[Segment]] = [[] for _ in spec.subtasks]
    skipped: dict[int, str] = {}
    starts = np.flatnonzero(np.diff(frames["episode_index"], prepend=-1))
    for start, end in zip(starts, [*starts[1:], len(order)], strict=True):
        episode = int(frames["episode_index"][start])
        if has_success and not bool(np.asarray(frames[SUCCESS_KEY][end - 1]).reshape(-1)[0]):
            skipped[episode] = "did not end in success"
            continue
        actions = frames[schema.ACTION][start:end].astype(np.float64)
        token_poses = frames[schema.TOKEN_POSES][start:end].astype(np.float64)
        bounds = split(actions, len(spec.subtasks))
        if bounds is None:
            changes = int(np.count_nonzero(np.diff(actions[:, -1] > 0)))
            need = len(spec.subtasks) - 1
            skipped[episode] = f"{changes} gripper changes, {spec.name}'s subtasks need {need}"
            continue
        for i, ((first, last), sub) in enumerate(zip(bounds, spec.subtasks, strict=True)):
            pose = to_matrix(token_poses[first, tokens.index(sub.object)])
            in_hand = None
            if sub.carried:
                eef = to_matrix(token_poses[first, 0])  # token 0 is the end effector
                in_hand = np.linalg.inv(eef) @ to_matrix(token_poses[first, tokens.index(sub.carried)])
            segments[i].append(
                Segment(
                    episode, sub.object, pose, actions[first:last], sub.carried, in_hand,
                    sub.symmetry, sub.carried_symmetry,
                )
            )
    if not segments[0]:
        reasons = "; ".join(f"episode {e}: {why}" for e, why in list(skipped.items())[:5])
        raise ValueError(f"source {root} has no usable successful episode ({reasons})")
    return Source(str(root), spec.name, segments, skipped)


def _generatable():
    from gym_actionflow.registry import TASKS

    return [t for t in TASKS if t.subtasks]


# ---------------------------------------------------------------------------- generation
class SegmentPlayer:
    """Plays one generated episode: each subtask's source segment moved with its object, linked to the last
    target; then holds the last target for :data:`HOLD_STEPS` steps. ``act()`` returns None when done;
    ``played`` lists the source episode of each segment played so far."""

    def __init__(self, env, source: Source, seed: int, noise: float = 0.0):
        self.env = env.unwrapped
        self.source = source
        self.rng = np.random.default_rng([seed, 1])
        self.noise = noise
        self.target = _matrix(*self.env.tcp_pose())
        self.grip = float(source.segments[0][0].actions[0, -1])  # as the sources began (holding or not)
        self.subtask = 0
        self.queue: list[tuple[np.ndarray, float]] = []
        self.held = 0
        self.played: list[int] = []

    def plan(self, segment: Segment) -> tuple[list[np.ndarray], int]:
        """``segment``'s targets moved into the scene as it is now, and the index of the first one the link
        goes to (:func:`transit_end`)."""
        objects = self.env.object_poses()
        if segment.reference not in objects:
            raise ValueError(
                f"the env has no object {segment.reference!r} ({list(objects)}); its observation settings "
                "must keep the objects the subtasks act on"
            )
        reference = _matrix(*objects[segment.reference])
        moves = reference @ turns(segment.symmetry) @ np.linalg.inv(segment.object_pose)
        # A carried object sits in the hand as it does now, not as in the source: correct the hand's targets
        # so that the object, not the hand, follows the source's path relative to the reference.
        regrips = np.eye(4)[None]
        if segment.carried is not None:
            in_hand_now = np.linalg.inv(_matrix(*self.env.tcp_pose())) @ _matrix(*objects[segment.carried])
            regrips = segment.in_hand @ turns(segment.carried_symmetry) @ np.linalg.inv(in_hand_now)
        source = np.array([to_matrix(a[:9]) for a in segment.actions])
        move, regrip = least_turn(self.target, moves, source, regrips)
        targets = [move @ target @ regrip for target in source]
        first = transit_end(targets, self.target, reference[:3, 3]) if TRIM_TRANSIT else 0
        return targets, first

    def _plan_next(self) -> None:
        candidates = self.source.segments[self.subtask]
        plans = [self.plan(segment) for segment in candidates]
        # MimicGen's nearest-neighbour selection, by the link each candidate needs from where the hand is.
        steps = [link_steps(self.target, targets[first]) for targets, first in plans]
        nearest = np.argsort(steps, kind="stable")[: NEAREST or len(candidates)]
        pick = int(nearest[int(self.rng.integers(len(nearest)))])
        (targets, first), segment = plans[pick], candidates[pick]
        self.queue = [(m, self.grip) for m in link(self.target, targets[first])[:-1]]
        pairs = zip(targets[first:], segment.actions[first:], strict=True)
        self.queue += [(m, float(a[-1])) for m, a in pairs]
        self.played.append(segment.episode)
        self.subtask += 1

    def act(self) -> np.ndarray | None:
        from gym_actionflow.experts.base import JITTER_POS, JITTER_ROT
        from gym_actionflow.geometry import axis_angle_matrix

        while not self.queue and self.subtask < len(self.source.segments):
            self._plan_next()
        if self.queue:
            self.target, self.grip = self.queue.pop(0)
        elif self.held < HOLD_STEPS:
            self.held += 1
        else:
            return None
        target = self.target
        if self.noise > 0:
            target = target.copy()
            target[:3, 3] += self.rng.normal(0.0, JITTER_POS * self.noise, 3)
            turn = axis_angle_matrix(self.rng.normal(0.0, JITTER_ROT * self.noise, 3))
            target[:3, :3] = turn @ target[:3, :3]
        return np.concatenate([to_pose9(target), [self.grip]]).astype(np.float32)


def run_generated(
    env, source: Source, seed: int, noise: float = 0.0, on_step=None
) -> tuple[bool, list[int]]:
    """One generated episode from ``seed``: reset, play; whether it succeeded and the source episode of each
    segment played. ``on_step(obs, action)`` sees each observation and the action taken from it (the
    recorder's frames)."""
    obs, info = env.reset(seed=seed)
    player = SegmentPlayer(env, source, seed, noise)
    while True:
        action = player.act()
        if action is None:
            break
        if on_step is not None:
            on_step(obs, action)
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    return bool(info.get("is_success", False)), player.played


_sources: dict[tuple[str, str], Source] = {}


def remember_source(root: str, task: str, source: Source) -> None:
    """Make ``source`` the one :func:`cached_source` returns for ``(root, task)`` in this process (a Ray
    actor given the driver's source, where ``root`` may not exist)."""
    _sources[(str(root), task)] = source


def cached_source(root: str, task: str) -> Source:
    """The segmented source, read once per process (the recorder's workers each read it once)."""
    key = (str(root), task)
    if key not in _sources:
        _sources[key] = load_source(root, task)
    return _sources[key]


def write_generation_file(
    root: Path, source: Source, seeds: list[int], segments: dict[str, list[int]]
) -> dict:
    """``meta/actionflow_generation.json``: the source, its usable and skipped episodes, and for each kept
    episode (in dataset order) its seed and the source episode of each of its segments (``segments``, by
    seed, as the recording log keeps them)."""
    data = {
        "source": source.root, "task": source.task, "source_episodes": source.episodes,
        "skipped_source_episodes": {str(k): v for k, v in source.skipped.items()},
        "episodes": [{"seed": seed, "segments": segments.get(str(seed))} for seed in seeds],
    }  # fmt: skip
    path = root / "meta" / GENERATION_FILE
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    tmp.replace(path)
    return data


# ---------------------------------------------------------------------------- command line
def build_parser() -> argparse.ArgumentParser:
    from lerobot_actionflow.tools.record.cli import _workers, add_executor_arguments

    parser = argparse.ArgumentParser(
        prog="actionflow-generate", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("source", type=Path, help="the source dataset's folder (a LeRobotDataset)")
    parser.add_argument("--task", required=True, help="the task of the source and of the generated episodes")
    parser.add_argument("--variant", help="layouts to generate for (default: the task's first)")
    parser.add_argument("--episodes", type=int, required=True, help="successful episodes to generate (>= 1)")
    parser.add_argument("--seed", type=int, default=0, help="first layout seed (default 0)")
    parser.add_argument(
        "--noise", type=float, default=0.0,
        help="per-step jitter of the targets, scaled like the experts' (default 0: none)",
    )  # fmt: skip
    parser.add_argument("--obs-mode", choices=("state", "pixels"), default="state")
    parser.add_argument("--cameras", nargs="+", help="with --obs-mode pixels: cameras from front, wrist")
    parser.add_argument(
        "--env-kwarg", action="append", default=[], metavar="KEY=VALUE",
        help="a further gym.make keyword (repeatable), as actionflow-record takes it",
    )  # fmt: skip
    parser.add_argument("--repo-id", help="repo id (default: actionflow/<task>_<variant>_gen<episodes>)")
    parser.add_argument("--root", type=Path, help="output folder (default: $HF_LEROBOT_HOME/<repo id>)")
    parser.add_argument("--workers", type=_workers, default=1, help="simulation processes (default 1)")
    add_executor_arguments(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    from gym_actionflow import find_task

    from lerobot_actionflow.recipes import snake
    from lerobot_actionflow.tools.record.cli import INPUT_ERRORS, _parse_env_kwarg, executor_kwargs
    from lerobot_actionflow.tools.record.recipe import Recipe
    from lerobot_actionflow.tools.record.recorder import record

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        spec = find_task(args.task)
        variant = args.variant or spec.variants[0]
        env_kwargs = dict(_parse_env_kwarg(text) for text in args.env_kwarg)
        source = load_source(args.source, spec.name)  # every bad source is refused before anything is written
        recipe = Recipe(
            task=spec.name, variant=variant, episodes=args.episodes, seed=args.seed, noise=args.noise,
            repo_id=args.repo_id or f"actionflow/{snake(spec.name)}_{variant.lower()}_gen{args.episodes}",
            obs_mode=args.obs_mode, cameras=args.cameras, env_kwargs=env_kwargs,
            source=str(args.source),
        )  # fmt: skip
    except (ValueError, argparse.ArgumentTypeError) as err:
        parser.error(str(err))
    used = len(source.episodes)
    print(f"{spec.name}: {used} source episodes in {len(spec.subtasks)} subtasks ({describe(spec.subtasks)})"
          + (f"; left out {len(source.skipped)}: {source.skipped}" if source.skipped else ""))  # fmt: skip
    try:
        result = record(
            recipe, args.root, progress=not args.quiet, workers=args.workers, **executor_kwargs(args, parser)
        )
    except KeyboardInterrupt:
        print("\nInterrupted: every finished episode is saved; run the same command again to resume.")
        return 130
    except INPUT_ERRORS as err:  # another recording at --root, a bad keyword, generation failing throughout
        print(f"actionflow-generate: error: {err}", file=sys.stderr)
        return 2
    tried = len(result.log.kept_seeds) + len(result.log.failed_seeds)
    print(f"{result.root}: {result.episodes} episodes generated of {tried} tried "
          f"({result.log.success_rate:.0%}), {result.seconds:.0f} s this run")  # fmt: skip
    return 0


def describe(subtasks) -> str:
    """``cube_a, cube_b carrying cube_a, cube_b``."""
    return ", ".join(s.object + (f" carrying {s.carried}" if s.carried else "") for s in subtasks)


if __name__ == "__main__":
    sys.exit(main())
