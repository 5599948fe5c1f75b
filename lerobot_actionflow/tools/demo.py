"""The main job: record expert demonstrations of a gym_actionflow task, train ActionFlow on them with
``lerobot-train``, evaluate it with ``lerobot-eval``, and save a 3D rerun recording of one evaluation rollout.

    python -m lerobot_actionflow.tools.demo [--task Stack] [--episodes 100] [--steps N] [--output-dir DIR]

Every step is a standard tool a LeRobot user already knows, run as a command (printed before it runs):
``actionflow-record`` writes a LeRobotDataset, ``lerobot-train --policy.type=actionflow`` trains,
``lerobot-eval --env.type=actionflow`` evaluates on new layouts (and writes videos). The training and
evaluation settings are the task's recipe (``actionflow-recipe TASK`` prints it). Only the rerun recording is
made in-process, from the same checkpoint and the first evaluation seed.
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path

from lerobot_actionflow.recipes import LOADERS, task_recipe
from lerobot_actionflow.recipes.commands import checkpoint, eval_command, train_command
from lerobot_actionflow.tools.record.recipe import Recipe
from lerobot_actionflow.tools.run import run


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--task", default="Stack", help="gym_actionflow task name")
    parser.add_argument("--variant", help="variant to record and train on (default: the task's first)")
    parser.add_argument("--episodes", type=int, default=100, help="expert episodes to record")
    parser.add_argument("--steps", type=int, help="lerobot-train optimisation steps (default: the recipe's)")
    parser.add_argument("--batch-size", type=int, help="default: the recipe's")
    parser.add_argument("--eval-episodes", type=int, default=20, help="evaluation episodes per variant")
    parser.add_argument("--output-dir", type=Path, default=Path("outputs/demo"))
    parser.add_argument("--seed", type=int, default=1, help="training seed")
    parser.add_argument(
        "--loader", choices=LOADERS, help="lerobot-train's data loader: stream (LeRobot's streaming dataset, "
        "fast, shuffles locally) or map (its map-style dataset, shuffles every frame, ~4x the data cost); "
        "default: the recipe's",
    )  # fmt: skip
    parser.add_argument(
        "--torch-threads", type=int, default=1,
        help="OMP_NUM_THREADS for lerobot-train: on a 2-core CPU the trainer shares the cores with its "
        "loader worker, and one thread each is faster than oversubscribing (use 0 to leave it to torch)",
    )  # fmt: skip
    args = parser.parse_args(argv)

    try:
        recipe = task_recipe(args.task)
    except ValueError as err:
        parser.error(str(err))
    from gym_actionflow import find_task

    variant = args.variant or find_task(recipe.task).variants[0]
    overrides = {k: v for k, v in (("steps", args.steps), ("batch_size", args.batch_size),
                                   ("loader", args.loader)) if v is not None}  # fmt: skip
    recipe = replace(recipe, train=replace(recipe.train, **overrides))
    dataset = Recipe(recipe.task, variant, args.episodes, f"local/{recipe.task.lower()}_{variant.lower()}_"
                     f"{args.episodes}")  # fmt: skip

    start = time.time()
    if args.output_dir.exists():
        shutil.rmtree(args.output_dir)
    out = args.output_dir
    root, train_dir = out / "dataset", out / "train"
    timings: dict[str, float] = {}

    t = time.time()
    run([*shlex.split(dataset.command()), "--root", str(root)])
    timings["record"] = time.time() - t

    t = time.time()
    extra = [f"--save_freq={recipe.train.steps}", f"--log_freq={max(recipe.train.steps // 20, 1)}"]
    threads = {"OMP_NUM_THREADS": str(args.torch_threads)} if args.torch_threads > 0 else {}
    run(train_command(recipe, dataset.repo_id, root, train_dir, seed=args.seed, extra=extra), **threads)
    timings["train"] = time.time() - t
    ckpt = checkpoint(train_dir)

    t = time.time()
    results = {}
    for eval_variant in recipe.eval_variants(variant):
        eval_dir = out / "eval" / eval_variant
        run(eval_command(recipe, eval_variant, ckpt, eval_dir, env_kwargs=dataset.eval_env_kwargs(),
                         episodes=args.eval_episodes))  # fmt: skip
        results[eval_variant] = json.loads((eval_dir / "eval_info.json").read_text())["overall"]
    timings["eval"] = time.time() - t

    t = time.time()
    rrd = out / "rollout.rrd"
    from lerobot_actionflow.tools.visualize import main as visualize

    first_seed = recipe.eval.first_seed
    visualize_args = [str(ckpt), "--task", f"{recipe.task}-v0", "--variant", variant,
                      "--seed", str(first_seed), "--out", str(rrd)]  # fmt: skip
    print(f"\n$ python -m lerobot_actionflow.tools.visualize {shlex.join(visualize_args)}", flush=True)
    visualize(visualize_args)
    timings["rerun"] = time.time() - t

    total = time.time() - start
    videos = sorted((out / "eval").rglob("*.mp4"))
    print("\n" + "=" * 78)
    print(
        f"ActionFlow on {recipe.task}-v0 ({variant}), trained on {args.episodes} expert episodes for "
        f"{recipe.train.steps} steps (CPU)"
    )
    for eval_variant, overall in results.items():
        print(
            f"  success rate: {overall['pc_success']:.0f} % over {overall['n_episodes']} new {eval_variant} "
            f"layouts (lerobot-eval, seeds from {first_seed})"
        )
    print(f"  checkpoint:   {ckpt}")
    if videos:
        print(f"  videos:       {out / 'eval'} ({len(videos)} mp4)")
    print(f"  3D recording: {rrd}   open it with:  {Path(sys.executable).parent / 'rerun'} {rrd}")
    stages = ", ".join(f"{k} {v / 60:.1f} min" for k, v in timings.items())
    print(f"  wall time:    {total / 60:.1f} min ({stages})")


if __name__ == "__main__":
    main()

