"""``actionflow-recipe``: print a task's recipe as the commands that record, train and evaluate it.

    actionflow-recipe MugHanging                     # the task's settings and its three commands
    actionflow-recipe MugHanging --episodes 200 --out outputs/mug
    actionflow-recipe datasets/mug_hanging_train_50.toml   # a dataset recipe, with the task's settings
    actionflow-recipe --list                         # every task's training settings in one table

The settings come from the task's recipe file (``lerobot_actionflow/recipes/<task>.toml``): what a task needs
beyond ``ActionFlowConfig``'s defaults (steps, data loader, ``--policy.*`` settings, evaluation variants). The
commands print with one-thread torch (``OMP_NUM_THREADS=1``), the setting of every figure on a 2-core CPU.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from lerobot_actionflow.recipes import TaskRecipe, snake, task_recipe
from lerobot_actionflow.recipes.commands import checkpoint, eval_command, train_command


def commands(recipe: TaskRecipe, record: list[str], repo_id: str, env_kwargs: dict, out: Path) -> list[str]:
    """The recipe's shell lines: record into ``out/dataset``, train into ``out/train``, evaluate each
    variant into ``out/eval/<variant>``."""
    root, train_dir = out / "dataset", out / "train"
    lines = [shlex.join([*record, "--root", str(root)])]
    lines.append("OMP_NUM_THREADS=1 " + shlex.join(train_command(recipe, repo_id, root, train_dir)))
    variant = record[record.index("--variant") + 1]
    for eval_variant in recipe.eval_variants(variant):
        cmd = eval_command(recipe, eval_variant, checkpoint(train_dir), out / "eval" / eval_variant,
                           env_kwargs=env_kwargs)  # fmt: skip
        lines.append(shlex.join(cmd))
    return lines


def table() -> str:
    """Every task's training settings, one row each."""
    from gym_actionflow import TASKS

    rows = ["| task | steps | batch | loader | --policy.* | evaluated on |", "|---|---|---|---|---|---|"]
    for spec in TASKS:
        r = task_recipe(spec.name)
        policy = " ".join(r.train.policy_flags()) or "(defaults)"
        variants = ", ".join(r.eval_variants(spec.variants[0]))
        rows.append(f"| {r.task} | {r.train.steps} | {r.train.batch_size} | {r.train.loader} | {policy} | "
                    f"{variants} |")  # fmt: skip
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="actionflow-recipe", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("task", nargs="?", help="a task name or a dataset recipe file")
    parser.add_argument("--variant", help="variant to record and train on (default: the task's first)")
    parser.add_argument("--episodes", type=int, default=50, help="demonstrations to record (default 50)")
    parser.add_argument("--out", type=Path, help="output folder (default outputs/<repo name>)")
    parser.add_argument("--list", action="store_true", help="print every task's training settings")
    args = parser.parse_args(argv)
    if args.list:
        print(table())
        return
    if args.task is None:
        parser.error("give a task name (e.g. MugHanging), a dataset recipe file, or --list")
    if args.episodes < 1:
        parser.error(f"--episodes {args.episodes}: expected an integer >= 1")
    from lerobot_actionflow.recipes.dataset import DatasetRecipe, load_dataset_recipe

    try:
        if args.task.endswith(".toml"):
            dataset = load_dataset_recipe(args.task)
        else:
            recipe = task_recipe(args.task)
            from gym_actionflow import find_task

            variant = args.variant or find_task(recipe.task).variants[0]
            repo_id = f"local/{snake(recipe.task)}_{variant.lower()}_{args.episodes}"
            dataset = DatasetRecipe.for_task(recipe.task, variant, args.episodes, repo_id)
    except (ValueError, FileNotFoundError) as err:
        parser.error(str(err))
    record, recipe = dataset.record, dataset.recipe
    out = args.out or Path("outputs") / Path(record.repo_id).name
    print(f"# {recipe.task}: lerobot_actionflow/recipes/{snake(recipe.task)}.toml")
    for line in recipe.notes.splitlines():
        print(f"#   {line}")
    record_argv = shlex.split(record.command())
    print("\n".join(commands(recipe, record_argv, record.repo_id, record.eval_env_kwargs(), out)))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
