"""The main job: record expert demonstrations of a gym_actionflow task, train ActionFlow on them with
``lerobot-train``, evaluate it with ``lerobot-eval``, and save a 3D rerun recording of one evaluation rollout.

    python -m lerobot_actionflow.tools.demo [--task Stack] [--episodes 100] [--steps 2000] [--output-dir DIR]

Every step is a standard tool a LeRobot user already knows, run as a command (printed before it runs):
``actionflow-record`` writes a LeRobotDataset, ``lerobot-train --policy.type=actionflow`` trains,
``lerobot-eval --env.type=actionflow`` evaluates on new seeds (and writes videos). Only the rerun recording
is made in-process, from the same checkpoint and the first evaluation seed.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

STREAMING_LOADER_FLAGS = ("--dataset.streaming=true", "--num_workers=1")
"""How lerobot-train reads the dataset by default here. Map-style LeRobotDataset spends 10-18 ms per sample on
the history and action windows (Hugging Face `datasets` queries every column once per windowed key), so two
loader workers kept a batch-32 step waiting for data more than half the time; LeRobot's streaming dataset
builds the same windows (tests/test_streaming_loader.py) from files read in order, about 2.5 ms per sample,
and one worker keeps up with the model step on the other core: 4.2x the samples/s (eval/bench_train.py,
eval/results/train_cpu_main_job.md; README, "Training flags")."""

MAP_LOADER_FLAGS = ("--num_workers=2",)
"""LeRobot's map-style loader (its default): every frame drawn from a fresh permutation each epoch, at about
4x the streaming loader's data cost on a CPU."""

MAP_LOADER_TASKS = frozenset({"MugHanging", "Lightbulb"})
"""Tasks that ``--loader auto`` trains with the map-style loader. The streaming loader reads the one data file
in order through a 1000-frame shuffle buffer, so a batch mixes a few neighbouring episodes. On MugHanging's
moved hanger the map-style loader scored 42-46 % on `test` against 24 % streamed at 3000 steps, and 44 %
against 36-38 % at 6000 (eval/results/ablate.md, where the seed spread is also measured). On Lightbulb
(100 demonstrations, 3000 steps) frames drawn uniformly reached 44 % against 14 % in the streaming loader's
order (32 % for ``lerobot-train`` streamed; eval/results/ablate.md). Stack and Stack Three do well
streamed."""

LOADERS = ("auto", "stream", "map")

TASK_POLICY_FLAGS: dict[str, tuple[str, ...]] = {"MugHanging": ("--policy.action_smoothing=0.5",)}
"""ActionFlow settings that ``lerobot-train`` gets for a task here and in the paper harness (the checkpoint's
config keeps them, so ``lerobot-eval`` runs with them). MugHanging: consecutive actions smoothed on SE(3)
(``a = 0.5 a_prev + 0.5 a_new``), which steadies the carry where a moved hanger puts the mug: a mean of
78 % on the moved hanger against 69.6 % unsmoothed over five training seeds, at 98-100 % on the training
layout (eval/results/ablate.md)."""


def loader_flags(task: str, loader: str = "auto") -> tuple[str, ...]:
    """``lerobot-train``'s loader flags for ``task``: ``stream`` (LeRobot's streaming dataset, one worker),
    ``map`` (its map-style dataset, two workers) or ``auto`` (map-style for :data:`MAP_LOADER_TASKS`,
    streaming otherwise)."""
    if loader not in LOADERS:
        raise ValueError(f"loader={loader!r}: expected one of {', '.join(LOADERS)}")
    if loader == "auto":
        loader = "map" if task in MAP_LOADER_TASKS else "stream"
    return MAP_LOADER_FLAGS if loader == "map" else STREAMING_LOADER_FLAGS


EVAL_SEED = 100_000
"""First evaluation seed: far from the recording seeds (0, 1, ...), so every evaluated layout is new."""


def task_policy_flags(task: str) -> tuple[str, ...]:
    """``lerobot-train``'s ``--policy.*`` flags for ``task`` (:data:`TASK_POLICY_FLAGS`; none for most)."""
    return TASK_POLICY_FLAGS.get(task, ())


def cli(name: str) -> str:
    """The path of a console script of this environment (``lerobot-train``...), so that a command runs with
    the interpreter running this one, whatever the ``PATH``."""
    return str(Path(sys.executable).parent / name)


def run(cmd: list[str], log: Path | None = None, **env_vars: str) -> None:
    """Print ``cmd`` as a shell line a user can paste, then run it offline without wandb. With ``log``, its
    output goes to that file (appended) instead of the console, and a failure raises with the log's tail."""
    prefix = "".join(f"{k}={v} " for k, v in env_vars.items())
    print(f"\n$ {prefix}" + " ".join(cmd) + (f"   > {log}" if log else ""), flush=True)
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", **env_vars}
    if log is None:
        subprocess.run(cmd, check=True, env=env)
        return
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("a") as out:
        code = subprocess.run(cmd, env=env, stdout=out, stderr=subprocess.STDOUT).returncode
    if code != 0:
        tail = "".join(log.read_text(errors="replace").splitlines(keepends=True)[-30:])
        raise RuntimeError(f"{Path(cmd[0]).name} exited with status {code}; the end of {log}:\n{tail}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--task", default="Stack", help="gym_actionflow task name")
    parser.add_argument("--variant", default="D0")
    parser.add_argument("--episodes", type=int, default=100, help="expert episodes to record")
    parser.add_argument("--steps", type=int, default=2000, help="lerobot-train optimisation steps")
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--eval-episodes", type=int, default=20)
    parser.add_argument("--output-dir", type=Path, default=Path("outputs/demo"))
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--loader",
        choices=LOADERS,
        default="auto",
        help="lerobot-train's data loader: stream (LeRobot's streaming dataset, fast, shuffles locally), map "
        "(its map-style dataset, shuffles every frame, ~4x the data cost) or auto (map for "
        + ", ".join(sorted(MAP_LOADER_TASKS)) + ", stream otherwise)",
    )
    parser.add_argument(
        "--torch-threads",
        type=int,
        default=1,
        help="OMP_NUM_THREADS for lerobot-train: on a 2-core CPU the trainer shares the cores with its "
        "loader worker, and one thread each is faster than oversubscribing (use 0 to leave it to torch)",
    )
    args = parser.parse_args(argv)

    start = time.time()
    if args.output_dir.exists():
        shutil.rmtree(args.output_dir)
    out = args.output_dir
    repo_id = f"local/{args.task.lower()}_{args.variant.lower()}_{args.episodes}"
    dataset = out / "dataset"
    timings: dict[str, float] = {}

    t = time.time()
    run([
        cli("actionflow-record"), "--task", args.task, "--variant", args.variant,
        "--episodes", str(args.episodes), "--seed", "0", "--noise", "1",
        "--repo-id", repo_id, "--root", str(dataset),
    ])  # fmt: skip
    timings["record"] = time.time() - t

    t = time.time()
    run([
        cli("lerobot-train"), "--policy.type=actionflow", "--policy.device=cpu",
        "--policy.push_to_hub=false",
        "--policy.optimizer_lr=1e-3", "--policy.scheduler_warmup_steps=100",
        f"--policy.scheduler_decay_steps={args.steps}",
        f"--dataset.repo_id={repo_id}", f"--dataset.root={dataset}",
        *task_policy_flags(args.task),
        f"--steps={args.steps}", f"--batch_size={args.batch_size}", *loader_flags(args.task, args.loader),
        f"--save_freq={args.steps}", f"--log_freq={max(args.steps // 20, 1)}",
        f"--seed={args.seed}", f"--output_dir={out / 'train'}",
    ], **({"OMP_NUM_THREADS": str(args.torch_threads)} if args.torch_threads > 0 else {}))  # fmt: skip
    timings["train"] = time.time() - t
    ckpt = out / "train" / "checkpoints" / "last" / "pretrained_model"

    t = time.time()
    run([
        cli("lerobot-eval"), f"--policy.path={ckpt}", "--policy.device=cpu",
        "--env.type=actionflow", f"--env.task={args.task}-v0", f"--env.variant={args.variant}",
        f"--eval.n_episodes={args.eval_episodes}", f"--eval.batch_size={min(args.eval_episodes, 10)}",
        "--eval.use_async_envs=false",
        f"--seed={EVAL_SEED}", f"--output_dir={out / 'eval'}",
    ])  # fmt: skip
    timings["eval"] = time.time() - t
    info = json.loads((out / "eval" / "eval_info.json").read_text())
    overall = info["overall"]

    t = time.time()
    rrd = out / "rollout.rrd"
    from lerobot_actionflow.tools.visualize import main as visualize

    print(
        f"\n$ python -m lerobot_actionflow.tools.visualize {ckpt} --task {args.task}-v0 --seed {EVAL_SEED}",
        flush=True,
    )
    visualize([str(ckpt), "--task", f"{args.task}-v0", "--variant", args.variant,
               "--seed", str(EVAL_SEED), "--out", str(rrd)])  # fmt: skip
    timings["rerun"] = time.time() - t

    total = time.time() - start
    videos = sorted((out / "eval").rglob("*.mp4"))
    print("\n" + "=" * 78)
    print(
        f"ActionFlow on {args.task}-v0 ({args.variant}), trained on {args.episodes} expert episodes for "
        f"{args.steps} steps (CPU)"
    )
    print(
        f"  success rate: {overall['pc_success']:.0f} % over {overall['n_episodes']} new layouts "
        "(lerobot-eval)"
    )
    print(f"  checkpoint:   {ckpt}")
    if videos:
        print(f"  videos:       {videos[0].parent} ({len(videos)} mp4)")
    print(f"  3D recording: {rrd}   open it with:  {Path(sys.executable).parent / 'rerun'} {rrd}")
    stages = ", ".join(f"{k} {v / 60:.1f} min" for k, v in timings.items())
    print(f"  wall time:    {total / 60:.1f} min ({stages})")


if __name__ == "__main__":
    main()
