"""Training throughput of the real ``lerobot-train --policy.type=actionflow`` under data-loading settings.

    python -m eval.bench.train [--steps 300] [--rounds 2] [--settings before stream1 ...] [--shuffle]
                               [--out eval/results]

Each setting is the main job's ``lerobot-train`` command (``lerobot_actionflow/tools/demo.py``: batch 32,
default model, CPU) plus its own loader flags and torch threads, run for ``--steps`` steps on a recorded
Stack D0 token dataset (recorded once with ``actionflow-record`` and cached under ``outputs/bench_train/``).
Settings run interleaved, round after round, so that load from other jobs on a shared machine falls on all of
them alike. The script reads LeRobot's own log lines (``updt_s``, ``data_s`` per step, averaged over each
``--log-freq`` window; the first window, which holds worker start-up and the first batch, is dropped) and
reports per setting:

* ``data_s`` / ``updt_s``: LeRobot's mean seconds per step waiting for the next batch / in forward, backward
  and optimiser step;
* data wait: ``data_s / (data_s + updt_s)``, the share of each step spent waiting for data;
* samples/s: the batch size over the wall-clock time between the first and last kept log lines (everything
  the training loop does), and LeRobot's own ``smp/s`` (batch / (data_s + updt_s)).

``--shuffle`` adds how well each loader shuffles: the episode of every sample in the first
``--shuffle-batches`` batches, as LeRobot's map-style sampler (a permutation per epoch) and its streaming
dataset (a 1000-frame shuffle buffer over the parquet files, in order) deliver them.
Results go to ``<out>/train_cpu.md`` (default out: ``outputs/bench``).
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from eval.bench.output import add_out_argument, write_result
from eval.provenance import describe, portable_command
from lerobot_actionflow.tools.run import resolve as cli

LOG_LINE = re.compile(r"step:(\S+) .*updt_s:([\d.]+) data_s:([\d.]+)")


@dataclass(frozen=True)
class Setting:
    name: str
    flags: tuple[str, ...]
    threads: int
    """OMP_NUM_THREADS of the lerobot-train process (and so of its loader workers)."""
    note: str
    dataset: str = "tokens"
    """Which benchmark dataset it trains on (``DATASETS``): Stack D0's pose tokens, or its wrist camera's
    frames stored as video or as PNG images in the parquet files."""


SETTINGS = {
    s.name: s
    for s in [
        Setting(
            "before", ("--num_workers=2",), 1, "the main job before: map-style dataset, 2 loader workers"
        ),
        Setting("map0", ("--num_workers=0",), 1, "map-style dataset, loaded in the training process"),
        Setting("map1", ("--num_workers=1",), 1, "map-style dataset, 1 loader worker"),
        Setting(
            "stream1",
            ("--dataset.streaming=true", "--num_workers=1"),
            1,
            "LeRobot's streaming dataset, 1 loader worker",
        ),
        Setting(
            "stream2",
            ("--dataset.streaming=true", "--num_workers=2"),
            1,
            "LeRobot's streaming dataset, 2 loader workers",
        ),
        Setting(
            "stream1_t2",
            ("--dataset.streaming=true", "--num_workers=1"),
            2,
            "streaming, 1 loader worker, 2 torch threads",
        ),
    ]
}

DATASETS = {
    "tokens": (),
    "video": ("--obs-mode", "pixels", "--image-storage", "video"),
    "image": ("--obs-mode", "pixels", "--image-storage", "image"),
}
"""The ``actionflow-record`` flags of each benchmark dataset beyond the Stack D0 recording: pose tokens; the
wrist camera (80 px) as AV1/H.264 video (LeRobot's default, before) or as PNG frames in the parquet files."""


def _camera_settings() -> list[Setting]:
    """Image training before and after the lean image path, per encoder. Before: the frames as video, the
    map-style dataset with 2 loader workers, the images of both observation steps encoded
    (``image_history=null``, the old behaviour). After: PNG frames in the parquet files, LeRobot's streaming
    dataset with 1 loader worker, only the current step's image encoded (``image_history=1``, the default).
    The middle settings change one thing at a time."""
    out = []
    stream, every = ("--dataset.streaming=true", "--num_workers=1"), "--policy.image_history=null"
    for enc in ("cnn", "resnet18"):
        policy = (f"--policy.image_encoder={enc}",)
        out += [
            Setting(f"cam_before_{enc}", ("--num_workers=2", *policy, "--policy.image_history=null"), 1,
                    f"{enc}, video frames, map-style, 2 workers, every step's image encoded", "video"),
            Setting(f"cam_png_map_{enc}", ("--num_workers=2", *policy, "--policy.image_history=null"), 1,
                    f"{enc}, PNG frames, map-style, 2 workers, every step's image encoded", "image"),
            Setting(f"cam_png_stream_{enc}",
                    (*stream, *policy, every), 1,
                    f"{enc}, PNG frames, streaming, 1 worker, every step's image encoded", "image"),
            Setting(f"cam_after_{enc}", (*stream, *policy), 1,
                    f"{enc}, PNG frames, streaming, 1 worker, the current image only (defaults)", "image"),
        ]  # fmt: skip
    return out


SETTINGS.update({s.name: s for s in _camera_settings()})


@dataclass
class Run:
    setting: Setting
    command: str
    windows: list[tuple[float, float, float]] = field(default_factory=list)
    """(arrival time, updt_s, data_s) of each kept log window."""
    wall_s: float = 0.0
    returncode: int = 0

    def mean(self, i: int) -> float:
        return statistics.fmean(w[i] for w in self.windows)


def dataset_of(args: argparse.Namespace, kind: str) -> tuple[str, Path]:
    """The repo id and root of the benchmark dataset ``kind`` (a key of ``DATASETS``)."""
    if kind == "tokens":
        name = f"stack_d0_{args.episodes}"
    else:
        name = f"stack_d0_wrist_{kind}_{args.camera_episodes}"
    return f"local/{name}", args.work / name


def ensure_dataset(root: Path, repo_id: str, episodes: int, kind: str = "tokens") -> None:
    """Record the benchmark dataset once (the main job's recording command, with the flags of ``kind``)
    unless it is already there."""
    if (root / "meta" / "info.json").exists():
        return
    cmd = [cli("actionflow-record"), "--task", "Stack", "--variant", "D0", "--episodes", str(episodes),
           "--seed", "0", "--noise", "1", *DATASETS[kind], "--repo-id", repo_id, "--root", str(root),
           "--quiet"]  # fmt: skip
    print("$ " + " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, env={**os.environ, "HF_HUB_OFFLINE": "1"})


def train_command(setting: Setting, args: argparse.Namespace, out: Path) -> list[str]:
    """The main job's lerobot-train command (the config's defaults) with the setting's loader flags."""
    repo_id, root = dataset_of(args, setting.dataset)
    return [
        cli("lerobot-train"), "--policy.type=actionflow", "--policy.device=cpu", "--policy.push_to_hub=false",
        f"--dataset.repo_id={repo_id}", f"--dataset.root={root}",
        f"--steps={args.steps}", f"--batch_size={args.batch_size}", *setting.flags,
        "--save_checkpoint=false", f"--log_freq={args.log_freq}", "--seed=1", f"--output_dir={out}",
    ]  # fmt: skip


def run_setting(setting: Setting, args: argparse.Namespace) -> Run:
    out = args.work / "runs" / setting.name
    shutil.rmtree(out, ignore_errors=True)
    cmd = train_command(setting, args, out)
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "PYTHONUNBUFFERED": "1",
           "OMP_NUM_THREADS": str(setting.threads)}  # fmt: skip
    shown = f"OMP_NUM_THREADS={setting.threads} " + portable_command(cmd)
    run = Run(setting, shown)
    log = (args.work / "logs" / f"{setting.name}.log").open("a")
    start = time.perf_counter()
    # Text mode reads tqdm's carriage returns as line ends, so the log lines arrive as they are written.
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seen = 0
    for line in proc.stdout:
        log.write(line)
        if m := LOG_LINE.search(line):
            seen += 1
            if seen > 1:  # the first window holds worker start-up and the first batch
                run.windows.append((time.perf_counter(), float(m[2]), float(m[3])))
    run.returncode = proc.wait()
    run.wall_s = time.perf_counter() - start
    log.close()
    return run


def summarise(runs: list[Run], args: argparse.Namespace) -> dict[str, dict[str, float]]:
    """Per setting, over all its rounds: mean data_s, updt_s, data wait, wall and LeRobot samples/s."""
    table = {}
    for name in dict.fromkeys(r.setting.name for r in runs):
        mine = [r for r in runs if r.setting.name == name and len(r.windows) >= 2 and r.returncode == 0]
        if not mine:
            continue
        data = statistics.fmean(r.mean(2) for r in mine)
        updt = statistics.fmean(r.mean(1) for r in mine)
        wall = [
            (len(r.windows) - 1) * args.log_freq * args.batch_size / (r.windows[-1][0] - r.windows[0][0])
            for r in mine
        ]
        table[name] = {
            "data_s": data,
            "updt_s": updt,
            "wait": data / (data + updt),
            "samples_s": statistics.fmean(wall),
            "samples_s_min": min(wall),
            "samples_s_max": max(wall),
            "lerobot_samples_s": args.batch_size / (data + updt),
            "run_s": statistics.fmean(r.wall_s for r in mine),
            "rounds": len(mine),
        }
    return table


def shuffle_quality(args: argparse.Namespace, batches: int) -> list[str]:
    """Episode mix of the first ``batches`` batches from LeRobot's map-style sampler and its streaming
    dataset, built with the arguments ``lerobot-train`` gives them (``lerobot/datasets/factory.py``,
    ``lerobot/scripts/lerobot_train.py``)."""
    import logging

    import numpy as np
    from lerobot.datasets import EpisodeAwareSampler
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    from eval.diagnostics.loader_order import streaming_order

    logging.disable(logging.WARNING)
    meta = LeRobotDatasetMetadata(args.repo_id, root=args.dataset)
    starts = np.asarray(meta.episodes["dataset_from_index"])
    ends = np.asarray(meta.episodes["dataset_to_index"])
    episode_of = np.repeat(np.arange(len(starts)), ends - starts)

    sampler = EpisodeAwareSampler(list(starts), list(ends), shuffle=True, seed=1)
    order = np.fromiter(sampler, dtype=np.int64)[: batches * args.batch_size]
    sources = {"map-style (EpisodeAwareSampler)": episode_of[order].reshape(batches, args.batch_size)}
    for workers in (1, 2):
        frames = batches * args.batch_size
        order = streaming_order(args.dataset, args.repo_id, workers, frames, args.batch_size, seed=42)
        sources[f"streaming, {workers} worker{'s' * (workers > 1)}"] = order.reshape(batches, args.batch_size)

    lines = [
        f"Episode mix of the first {batches} batches of {args.batch_size} ({batches * args.batch_size} of "
        f"{meta.total_frames} frames, {meta.total_episodes} episodes):",
        "",
        "| loader | distinct episodes per batch | episodes shared by consecutive batches | "
        "episodes seen in 10 consecutive batches | episode index: lag-1 correlation of batch means |",
        "|---|---|---|---|---|",
    ]
    for name, eps in sources.items():
        sets = [set(b.tolist()) for b in eps]
        shared = [len(a & b) / len(a | b) for a, b in zip(sets, sets[1:], strict=False)]
        window = [len(set(eps[i : i + 10].ravel().tolist())) for i in range(0, len(eps) - 9)]
        means = eps.mean(1)
        corr = float(np.corrcoef(means[:-1], means[1:])[0, 1])
        lines.append(
            f"| {name} | {statistics.fmean(len(s) for s in sets):.1f} | "
            f"{100 * statistics.fmean(shared):.0f} % (Jaccard) | {statistics.fmean(window):.1f} | "
            f"{corr:+.2f} |"
        )
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    token_settings = [name for name, s in SETTINGS.items() if s.dataset == "tokens"]
    parser.add_argument("--settings", nargs="+", default=token_settings, choices=list(SETTINGS),
                        help="default: the pose-token ones; cam_* train from the wrist camera")  # fmt: skip
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--log-freq", type=int, default=50)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--rounds", type=int, default=1, help="runs per setting, interleaved")
    parser.add_argument("--episodes", type=int, default=100, help="episodes of the pose-token dataset")
    parser.add_argument("--camera-episodes", type=int, default=30, help="episodes of the camera datasets")
    parser.add_argument("--work", type=Path, default=Path("outputs/bench_train"))
    parser.add_argument("--shuffle", action="store_true", help="also measure each loader's episode mix")
    parser.add_argument("--shuffle-batches", type=int, default=100)
    add_out_argument(parser)
    args = parser.parse_args(argv)
    if args.steps < 3 * args.log_freq:
        parser.error(f"--steps {args.steps} < 3 x --log-freq {args.log_freq}: too few windows to time")
    args.repo_id, args.dataset = dataset_of(args, "tokens")
    (args.work / "logs").mkdir(parents=True, exist_ok=True)
    for kind in dict.fromkeys(SETTINGS[name].dataset for name in args.settings):
        repo_id, root = dataset_of(args, kind)
        ensure_dataset(root, repo_id, args.episodes if kind == "tokens" else args.camera_episodes, kind)

    runs = []
    for r in range(args.rounds):
        for name in args.settings:
            run = run_setting(SETTINGS[name], args)
            runs.append(run)
            status = "" if run.returncode == 0 else f"  FAILED (exit {run.returncode})"
            if run.windows:
                status = (
                    f"data_s {run.mean(2):.3f}  updt_s {run.mean(1):.3f}  "
                    f"wait {run.mean(2) / (run.mean(1) + run.mean(2)):.0%}" + status
                )
            print(f"round {r + 1} {name:>10}: {status}  ({run.wall_s:.0f} s)", flush=True)

    table = summarise(runs, args)
    given = sys.argv[1:] if argv is None else argv

    def base_of(name: str) -> float | None:
        """samples/s of the row this one is compared to: its encoder's cam_before, or before."""
        before = f"cam_before_{name.rsplit('_', 1)[1]}" if name.startswith("cam_") else "before"
        return table.get(before, {}).get("samples_s")

    cameras = any(SETTINGS[name].dataset != "tokens" for name in table)
    tokens_text = (
        f"Stack D0, {args.episodes} episodes (`actionflow-record --task Stack --variant D0 --episodes "
        f"{args.episodes} --seed 0 --noise 1`), "
        if any(SETTINGS[name].dataset == "tokens" for name in table)
        else ""
    )
    camera_text = (
        f" The cam_* rows train on Stack D0's wrist camera, {args.camera_episodes} episodes recorded with "
        "`--obs-mode pixels` and `--image-storage video` or `image` (80 px, pose tokens beside the image), "
        "and compare with their encoder's cam_before row."
        if cameras
        else ""
    )
    lines = [
        f"# lerobot-train throughput, ActionFlow on CPU ({platform.processor() or 'CPU'}, "
        f"{os.cpu_count()} cores)",
        "",
        f"`{portable_command(['python', '-m', 'eval.bench.train', *given])}`",
        "",
        tokens_text + f"batch {args.batch_size}, default model, "
        f"{args.steps} steps per run, {args.rounds} interleaved round(s); LeRobot's `data_s` / `updt_s` "
        "averaged over its "
        f"{args.log_freq}-step log windows after the first. samples/s is wall clock over the kept windows "
        "(mean, min-max over rounds). The machine's cores were shared with other jobs: compare rows, not "
        "absolute figures." + camera_text,
        "",
        "| setting | data_s | updt_s | data wait | samples/s | vs before | LeRobot smp/s | run s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, row in table.items():
        base = base_of(name)
        speedup = f"{row['samples_s'] / base:.2f}x" if base else "-"
        lines.append(
            f"| `{name}`: {SETTINGS[name].note} | {row['data_s']:.3f} | {row['updt_s']:.3f} | "
            f"{row['wait']:.0%} | {row['samples_s']:.0f} ({row['samples_s_min']:.0f}-"
            f"{row['samples_s_max']:.0f}) | {speedup} | {row['lerobot_samples_s']:.0f} | {row['run_s']:.0f} |"
        )
    lines += ["", "Commands (`<out>` a fresh output directory):", "", "```bash"]
    for name in table:
        shown = next(r.command for r in runs if r.setting.name == name)
        lines.append(re.sub(r"--output_dir=\S+", "--output_dir=<out>", shown))
    lines.append("```")
    if args.shuffle:
        lines += ["", *shuffle_quality(args, args.shuffle_batches)]
    lines += ["", describe()]
    text = "\n".join(lines) + "\n"
    print("\n" + text)
    write_result(args.out, "train_cpu.md", text)


if __name__ == "__main__":
    main()
