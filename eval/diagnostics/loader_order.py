"""How well a LeRobot data loader mixes a dataset: the distinct episodes in each batch and in each run of 10
batches, for LeRobot's streaming loader (``--dataset.streaming=true``) with 1..N workers beside the map-style
loader's shuffled order, on one LeRobotDataset folder.

    python -m eval.diagnostics.loader_order --root outputs/cam/lb_rgb_100 --workers 1 2 4 --batches 200

Drawn without replacement (the map-style loader), a batch of 32 from 100 similar episodes holds about 28 of
them and 10 batches nearly all; the streaming loader reads the data files in order through a 1000-frame
shuffle buffer, so a batch holds only the episodes near the reader's position in the files. Only the
``episode_index`` of each frame is looked at (the streaming rows read the real loader, images decoded as in
training); no observation windows are built, so the seconds are not training speeds.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def mixing(episodes: np.ndarray, batch_size: int) -> tuple[float, float]:
    """Mean distinct episodes per batch and per run of 10 batches, for frames drawn in the order given
    (whole batches only)."""
    n = len(episodes) // batch_size * batch_size
    if n == 0:
        raise ValueError(f"{len(episodes)} frames; expected at least one batch of {batch_size}")
    per_batch = [len(set(episodes[k : k + batch_size].tolist())) for k in range(0, n, batch_size)]
    span = 10 * batch_size
    per_ten = [len(set(episodes[k : k + span].tolist())) for k in range(0, n - span + 1, span)]
    return float(np.mean(per_batch)), float(np.mean(per_ten)) if per_ten else float("nan")


def shuffled_order(root: Path, frames: int, seed: int = 0) -> np.ndarray:
    """``episode_index`` of ``frames`` frames in a shuffled order without replacement (the map-style
    loader's sampler), read from the dataset's data files."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    files = sorted((root / "data").rglob("*.parquet"))
    if not files:
        raise SystemExit(f"{root}: no data files under data/; expected a LeRobotDataset folder")
    episodes = np.asarray(pa.concat_tables([pq.read_table(f, columns=["episode_index"]) for f in files])[0])
    rng = np.random.default_rng(seed)
    order = np.concatenate([rng.permutation(episodes) for _ in range(-(-frames // len(episodes)))])
    return order[:frames]


def streaming_order(
    root: Path, repo_id: str, workers: int, frames: int, batch_size: int, seed: int | None = None
) -> np.ndarray:
    """``episode_index`` of the first ``frames`` frames LeRobot's streaming loader yields with ``workers``
    DataLoader workers (it shards the data files into ``workers`` shards, as ``lerobot-train`` does);
    ``seed`` its shuffle buffer's (None: LeRobot's default)."""
    import torch
    from lerobot.datasets.streaming_dataset import StreamingLeRobotDataset

    seeded = {} if seed is None else {"seed": seed}
    dataset = StreamingLeRobotDataset(repo_id, root=root, max_num_shards=workers, return_uint8=True, **seeded)
    loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, num_workers=workers)
    seen: list[np.ndarray] = []
    for batch in loader:
        seen.append(batch["episode_index"].numpy().reshape(-1))
        if sum(len(s) for s in seen) >= frames:
            break
    return np.concatenate(seen)[:frames]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--root", type=Path, required=True, help="a LeRobotDataset folder")
    parser.add_argument(
        "--repo-id", default=None, help="its repo id (default local/<folder name>)"
    )
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4], help="streaming loader workers")
    parser.add_argument("--batches", type=int, default=200, help="batches read per row")
    parser.add_argument("--batch-size", type=int, default=32)
    args = parser.parse_args(argv)
    if not (args.root / "meta" / "info.json").is_file():
        raise SystemExit(f"--root {args.root}: no meta/info.json; expected a LeRobotDataset folder")
    repo_id = args.repo_id or f"local/{args.root.name}"
    frames = args.batches * args.batch_size
    print(f"{args.root}: {args.batches} batches of {args.batch_size}\n")
    print("| loader | distinct episodes per batch | per 10 batches | s |")
    print("|---|---|---|---|")
    start = time.perf_counter()
    per_batch, per_ten = mixing(shuffled_order(args.root, frames), args.batch_size)
    print(f"| map-style, shuffled | {per_batch:.1f} | {per_ten:.1f} | {time.perf_counter() - start:.0f} |")
    for workers in args.workers:
        start = time.perf_counter()
        order = streaming_order(args.root, repo_id, workers, frames, args.batch_size)
        per_batch, per_ten = mixing(order, args.batch_size)
        print(f"| streaming, {workers} worker{'s' * (workers > 1)} | {per_batch:.1f} | {per_ten:.1f} | "
              f"{time.perf_counter() - start:.0f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
