"""How demonstrations move the hand: per dataset, the episode length, the hand's path length and how far the
wrist turns from the experts' home yaw, to compare generated demonstrations with recorded ones.

    python -m eval.diagnostics.demo_stats outputs/gen/s3_expert200/dataset outputs/gen/s3_gen200/dataset

Reads the ``action`` column (absolute end-effector targets, pose9 + gripper) of every data file of each
LeRobotDataset folder. The wrist yaw is the target's rotation about the vertical against the scripted experts'
top-down home grasp (``top_down(0)``), folded to [0, 180] degrees and taken every 5th frame; a generator that
turns the wrist with every random yaw of a cube shows up as a wide spread here.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def stats(root: Path) -> dict[str, float]:
    """``episodes``, mean ``frames`` and hand ``path_m`` per episode, and wrist yaw percentiles (degrees)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from gym_actionflow.experts.base import top_down
    from gym_actionflow.geometry import pose9_to_rt, yaw_of

    files = sorted((root / "data").rglob("*.parquet"))
    if not files:
        raise SystemExit(f"{root}: no data files under data/; expected a LeRobotDataset folder")
    table = pa.concat_tables([pq.read_table(f, columns=["action", "episode_index"]) for f in files])
    actions = np.asarray(table.column("action").to_pylist(), dtype=np.float64)
    episode = np.asarray(table.column("episode_index"))
    home = top_down(0.0)
    yaw = np.abs([np.degrees(yaw_of(pose9_to_rt(a[:9])[0] @ home.T)) for a in actions[::5]])
    ids = np.unique(episode)
    paths = [np.linalg.norm(np.diff(actions[episode == e, :3], axis=0), axis=1).sum() for e in ids]
    p50, p90, p99 = np.percentile(yaw, [50, 90, 99])
    return {"episodes": len(ids), "frames": len(actions) / len(ids), "path_m": float(np.mean(paths)),
            "yaw_p50": p50, "yaw_p90": p90, "yaw_p99": p99}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("roots", type=Path, nargs="+", help="LeRobotDataset folders")
    args = parser.parse_args(argv)
    print("| dataset | episodes | frames / episode | hand path (m) | wrist yaw from home, p50 / p90 / p99 |")
    print("|---|---|---|---|---|")
    for root in args.roots:
        s = stats(root)
        print(f"| `{root}` | {s['episodes']} | {s['frames']:.1f} | {s['path_m']:.2f} | "
              f"{s['yaw_p50']:.0f} / {s['yaw_p90']:.0f} / {s['yaw_p99']:.0f} deg |")  # fmt: skip


if __name__ == "__main__":
    main()
