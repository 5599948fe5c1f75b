"""How much the Lightbulb socket forgives, per socket fit: the paper's replay baseline on expert
demonstrations recorded on that fit.

    python -m eval.diagnostics.lightbulb_fit --socket-fit strict 2 2.25 2.5 2.75 3 \\
        --socket-pose fixed any --episodes 50

The paper's real robot replayed its light-bulb demonstrations with 8/10 success, and with 5/10 when they were
shifted 1.5 mm sideways. For every ``--socket-fit`` (a name of ``SOCKET_FITS``, or a candidate total
clearance in millimetres) and ``--socket-pose``, this simulates the scripted expert from seeds 0, 1, ... at
the recording noise, keeping the first ``--episodes`` successful episodes as ``actionflow-record`` would (the
same recipe, the same ``simulate``), and replays their actions open loop with the replay baseline's own code
(:func:`eval.paper.replay.replay_shifted`): unshifted, then ``--offset-mm`` off along world y, alternating
the side. It prints one Markdown row per cell. An unshifted replay repeats the recorded episode exactly (the
same seed, the same actions, a deterministic simulator), so it checks the protocol rather than the fit.

A recorded dataset gives the same figures through the baseline itself: record a recipe with
``socket_fit`` in its ``[env_kwargs]`` and run ``python -m eval.paper.replay --root <dataset> --offset-mm 1.5
--out replay.json``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from gym_actionflow.tasks.lightbulb import SOCKET_FITS, SOCKET_POSES, SocketFit

from eval.paper.replay import replay_shifted
from lerobot_actionflow.tools.record.recipe import Recipe
from lerobot_actionflow.tools.record.simulate import episodes, make_env

MAX_SEEDS_PER_EPISODE = 3
"""Give up on a cell when the expert fails so often that it needs more than three seeds per kept episode."""


@dataclass(frozen=True)
class Cell:
    """One measured fit and layout: the replays' success rates and what it took to record them."""

    fit: str
    clearance_mm: float
    socket_pose: str
    episodes: int
    seeds_tried: int
    replay: float
    replay_off: float
    seconds: float


def parse_fit(text: str) -> tuple[str, SocketFit]:
    """A ``--socket-fit`` value: a name of ``SOCKET_FITS`` or a total clearance in millimetres (``2.5``)."""
    if text in SOCKET_FITS:
        return text, SOCKET_FITS[text]
    try:
        clearance_mm = float(text)
    except ValueError:
        raise ValueError(
            f"--socket-fit={text!r}; expected one of {tuple(SOCKET_FITS)} or a total clearance in mm "
            "(e.g. 2.5)"
        ) from None
    try:
        return f"{clearance_mm:g} mm", SocketFit(clearance_mm / 1000)
    except ValueError as err:
        raise ValueError(f"--socket-fit={text!r}: {err}") from None


def expert_demonstrations(recipe: Recipe) -> tuple[list[int], list[np.ndarray], int]:
    """The recipe's first ``episodes`` successful expert episodes, as ``actionflow-record`` keeps them: their
    seeds, their actions ``[T, 10]`` (float32, as stored) and how many seeds were tried."""
    env = make_env(recipe)
    seeds, actions, tried = [], [], 0
    for episode in episodes(recipe, recipe.seed, workers=1, env=env):
        tried += 1
        if episode.success:
            seeds.append(episode.seed)
            actions.append(episode.columns["action"])
        if len(seeds) == recipe.episodes:
            break
        if tried >= MAX_SEEDS_PER_EPISODE * recipe.episodes:
            raise RuntimeError(
                f"the expert kept {len(seeds)} of {tried} episodes with env_kwargs={recipe.env_kwargs}; "
                "this fit is not one it can record"
            )
    env.close()
    return seeds, actions, tried


def measure(name: str, fit: SocketFit, socket_pose: str, n: int, offset_mm: float, noise: float) -> Cell:
    """Record ``n`` expert episodes on this fit and layout, then replay them unshifted and ``offset_mm``
    off."""
    start = time.perf_counter()
    env_kwargs = {"socket_pose": socket_pose, "socket_fit": fit}
    recipe = Recipe(
        task="Lightbulb",
        variant="D0",
        episodes=n,
        repo_id="local/lightbulb_fit",
        noise=noise,
        env_kwargs=env_kwargs,
    )
    seeds, actions, tried = expert_demonstrations(recipe)
    env = make_env(recipe)
    exact = replay_shifted(env, seeds, actions, 0.0)
    off = replay_shifted(env, seeds, actions, offset_mm)
    env.close()
    seconds = time.perf_counter() - start
    return Cell(name, fit.clearance * 1000, socket_pose, n, tried, np.mean(exact), np.mean(off), seconds)


def table(cells: Sequence[Cell], offset_mm: float) -> str:
    """The cells as a Markdown table."""
    lines = [
        f"| socket_fit | total clearance | socket_pose | episodes | expert seeds tried | replay | "
        f"replay {offset_mm:g} mm off | seconds |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in cells:
        lines.append(
            f"| {c.fit} | {c.clearance_mm:g} mm | {c.socket_pose} | {c.episodes} | {c.seeds_tried} | "
            f"{c.replay:.0%} | {c.replay_off:.0%} | {c.seconds:.0f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    fits_help = f"fits to measure: names of {tuple(SOCKET_FITS)} or total clearances in mm"
    parser.add_argument("--socket-fit", nargs="+", default=list(SOCKET_FITS), help=fits_help)
    parser.add_argument("--socket-pose", nargs="+", default=["fixed"], choices=tuple(SOCKET_POSES))
    parser.add_argument("--episodes", type=int, default=50, help="expert episodes kept per cell")
    parser.add_argument("--offset-mm", type=float, default=1.5)
    parser.add_argument("--noise", type=float, default=1.0, help="the expert's noise (1: the recipes')")
    args = parser.parse_args(argv)
    try:
        fits = [parse_fit(text) for text in args.socket_fit]
    except ValueError as err:
        parser.error(str(err))
    cells = []
    for pose in args.socket_pose:
        for name, fit in fits:
            cells.append(measure(name, fit, pose, args.episodes, args.offset_mm, args.noise))
            print(table(cells[-1:], args.offset_mm).splitlines()[-1], flush=True)  # progress, row by row
    print()
    print(table(cells, args.offset_mm))


if __name__ == "__main__":
    main()
