"""How far from its demonstrations a MugHanging policy generalises: success by where the mug starts relative
to the hanger, for cells of the ablation results (``eval/results/ablate_MugHanging.jsonl``, written by the
retired ``eval/ablate.py``, or any JSON-lines file of rows ``{"name", "env_kwargs", "eval": {variant: {"n",
"failed_seeds"}}}``).

    python -m eval.diagnostics.mug_layouts --cells panda_physics via_slight --variants test scene_moved
    python -m eval.diagnostics.mug_layouts --by bearing --cells via_slight_6000 via_slight_6000_seed1

Every layout is rebuilt from its evaluation seed (``env.reset(seed)`` places mug and hanger; no policy is
run), and the cell's ``failed_seeds`` say which ones failed. The mug's start is expressed in the hanger
frame (x along the peg's heading, y sideways): the ``train`` demonstrations all start with the mug 0.22-0.34 m
out along the peg's line and at most 4.5 cm to its side. An SE(3)-equivariant policy sees only these relative
poses (plus the gripper's), so ``test`` layouts are new to it exactly by how far the mug sits off that line.
``--by bearing`` bins by the angle between the peg's heading and the mug's direction from the hanger instead
(the demonstrations: at most 12 degrees).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from gym_actionflow.registry import make_env

from lerobot_actionflow.recipes import EVAL_SEED

RESULTS = Path(__file__).resolve().parents[1] / "results" / "ablate_MugHanging.jsonl"
"""The MugHanging ablation cells (read only)."""
SIDE_BINS = (0.0, 0.1, 0.2, 0.25, 0.4)
"""Bins of the mug's sideways distance from the peg's line (m)."""
BEARING_BINS = (0.0, 35.0, 50.0, 90.0)
"""Bins of the mug's bearing from the hanger, off the peg's heading (degrees)."""


def mug_in_hanger_frame(variant: str, seeds: range, env_kwargs: dict) -> np.ndarray:
    """(len(seeds), 2) the mug's start in the hanger frame (x along the peg's heading, y sideways)."""
    env = make_env("MugHanging", variant, **env_kwargs)
    sim = env.unwrapped
    out = []
    for seed in seeds:
        env.reset(seed=seed)
        h_pos, h_rot = sim.body_pose(sim.hanger_id)
        m_pos, _ = sim.body_pose(sim.mug_id)
        out.append((h_rot.T @ (m_pos - h_pos))[:2])
    env.close()
    return np.array(out)


def rows_by(cell: dict, variant: str, by: str = "side") -> list[tuple[str, int, int]]:
    """(bin label, successes, episodes) per bin of the mug's sideways distance from the peg's line
    (``by="side"``) or of its bearing off the peg's heading (``by="bearing"``), in a cell's ``variant``
    evaluation."""
    result = cell["eval"][variant]
    seeds = range(EVAL_SEED, EVAL_SEED + result["n"])
    failed = set(result["failed_seeds"])
    rel = mug_in_hanger_frame(variant, seeds, cell.get("env_kwargs", {}))
    if by == "bearing":
        value, bins, unit = np.degrees(np.arctan2(np.abs(rel[:, 1]), rel[:, 0])), BEARING_BINS, "deg"
    else:
        value, bins, unit = np.abs(rel[:, 1]), SIDE_BINS, "m"
    rows = []
    for low, high in zip(bins[:-1], bins[1:], strict=True):
        members = [s for s, d in zip(seeds, value, strict=True) if low <= d < high]
        if members:
            rows.append((f"{low:g}-{high:g} {unit}", sum(s not in failed for s in members), len(members)))
    return rows


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--results", type=Path, default=RESULTS)
    p.add_argument("--cells", nargs="+", required=True, help="cell names in the results file")
    p.add_argument("--variants", nargs="+", default=["test"])
    p.add_argument("--by", choices=("side", "bearing"), default="side",
                   help="bin by the mug's distance from the peg's line or its bearing off the peg's heading")
    args = p.parse_args(argv)
    cells = {}
    for line in args.results.read_text().splitlines():
        row = json.loads(line)
        cells[row["name"]] = row  # a later row of the same name wins
    missing = [name for name in args.cells if name not in cells]
    if missing:
        raise SystemExit(f"cells {missing} are not in {args.results}; it has {sorted(cells)}")
    what = (
        "mug's bearing off the peg's heading"
        if args.by == "bearing" else "mug's distance from the peg's line"
    )
    print(f"| cell | layouts | {what} | success |")
    print("|---|---|---|---|")
    for name in args.cells:
        for variant in args.variants:
            if variant not in cells[name]["eval"]:
                continue
            for label, ok, n in rows_by(cells[name], variant, args.by):
                print(f"| {name} | {variant} | {label} | {ok} of {n} ({100 * ok / n:.0f} %) |")


if __name__ == "__main__":
    main()
