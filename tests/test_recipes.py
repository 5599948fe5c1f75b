"""Task recipes: one home for how each task trains and evaluates, read by every path."""

from __future__ import annotations

import dataclasses

import gym_actionflow
import pytest

from lerobot_actionflow import ActionFlowConfig
from lerobot_actionflow.recipes import EVAL_SEED, LAYOUTS, LOADERS, TaskRecipe, task_recipe
from lerobot_actionflow.recipes.commands import eval_command, train_command
from lerobot_actionflow.tools.recipe import main as recipe_main


@pytest.mark.parametrize("task", [t.name for t in gym_actionflow.TASKS])
def test_every_task_has_a_recipe_whose_policy_settings_are_config_fields(task):
    """Guards against a recipe file that names a config field LeRobot would refuse at `lerobot-train`, or a
    task that silently falls back to defaults because its file is missing."""
    recipe = task_recipe(task)
    assert recipe.task == task and recipe.notes, f"{task} has no recipe file (or one without notes)"
    fields = {f.name for f in dataclasses.fields(ActionFlowConfig)}
    assert set(recipe.train.policy) <= fields
    spec = gym_actionflow.find_task(task)
    assert set(recipe.eval_variants(spec.variants[0])) <= set(spec.variants)
    assert recipe.train.loader in LOADERS and recipe.eval.layouts in LAYOUTS


def test_mug_hanging_recipe_is_the_measured_one():
    """The settings behind MugHanging's figures (map-style loader, smoothing 0.5, 6000 steps, evaluated on the
    training and the moved hanger) come from its recipe, as flags lerobot-train parses."""
    recipe = task_recipe("gym_actionflow/MugHanging-v0")
    cmd = train_command(recipe, "local/mug", "data/mug", "out/train")
    assert "--policy.action_smoothing=0.5" in cmd and "--num_workers=2" in cmd and "--steps=6000" in cmd
    assert not any(c.startswith("--dataset.streaming") for c in cmd)
    assert recipe.eval_variants("train") == ("train", "test")
    evals = eval_command(recipe, "test", "ckpt", "out/eval", env_kwargs={"mug_yaw": "slight"})
    assert f"--seed={EVAL_SEED}" in evals and "--env.mug_yaw=slight" in evals
    assert "--env.variant=test" in evals


def test_stack_trains_with_no_policy_flags_and_the_streaming_loader():
    """The main job's training command carries no --policy.* setting beyond the type, device and push: the
    config's defaults are the recipe."""
    cmd = train_command(task_recipe("Stack"), "local/stack", "data", "out")
    assert [c for c in cmd if c.startswith("--policy.")] == [
        "--policy.type=actionflow", "--policy.device=cpu", "--policy.push_to_hub=false"
    ]  # fmt: skip
    assert "--dataset.streaming=true" in cmd and "--steps=2000" in cmd


def test_overrides_are_checked_and_named():
    """A dataset recipe's [train] / [eval] tables override the task's; a bad field is an error naming the
    field, the file and what was expected."""
    base = task_recipe("MugHanging")
    merged = base.with_overrides({"train": {"steps": 100, "policy": {"dim": 64}}}, "x.toml")
    assert merged.train.steps == 100 and merged.train.policy == {"action_smoothing": 0.5, "dim": 64}
    bad = [
        ({"train": {"steps": 2.5}}, "train.steps=2.5 in x.toml; expected int >= 1"),
        ({"train": {"steps": True}}, "train.steps=True in x.toml"),
        ({"train": {"loader": "fast"}}, "train.loader='fast' in x.toml; expected one of"),
        ({"train": {"policy": {"not_a_field": 1}}}, "unknown ActionFlowConfig field(s) ['not_a_field']"),
        ({"eval": {"layouts": "test"}}, "eval.layouts='test' in x.toml; expected one of ('dev', 'heldout')"),
        ({"eval": {"shots": 3}}, "[eval] in x.toml has unknown field(s) ['shots']"),
        ({"evaluate": {}}, "x.toml has unknown table(s) ['evaluate']"),
    ]
    for table, message in bad:
        with pytest.raises(ValueError) as err:
            base.with_overrides(table, "x.toml")
        assert message in str(err.value), (table, str(err.value))


def test_unknown_task_is_refused_by_name():
    with pytest.raises(ValueError, match="unknown task 'Stak'"):
        task_recipe("Stak")
    assert TaskRecipe("Stack").eval.first_seed == LAYOUTS["dev"] == 100_000 < LAYOUTS["heldout"]


def test_actionflow_recipe_prints_runnable_commands(capsys):
    """`actionflow-recipe MugHanging` prints the record, train and two evaluation commands with the task's
    settings; `--list` prints every task."""
    recipe_main(["MugHanging", "--episodes", "20", "--out", "out/mug"])
    lines = [line for line in capsys.readouterr().out.splitlines() if not line.startswith("#")]
    assert lines[0].startswith("actionflow-record --task MugHanging --variant train --episodes 20")
    assert lines[0].endswith("--root out/mug/dataset")
    assert lines[1].startswith("OMP_NUM_THREADS=1 lerobot-train --policy.type=actionflow")
    assert "--policy.action_smoothing=0.5" in lines[1] and "--dataset.root=out/mug/dataset" in lines[1]
    assert [line.split("--env.variant=")[1].split()[0] for line in lines[2:]] == ["train", "test"]
    recipe_main(["--list"])
    table = capsys.readouterr().out
    assert all(f"| {t.name} |" in table for t in gym_actionflow.TASKS)


def test_actionflow_recipe_refuses_bad_input_with_exit_2(capsys):
    for argv, message in ((["Stak"], "unknown task 'Stak'"), (["Stack", "--episodes", "0"], "--episodes 0"),
                          ([], "give a task name")):  # fmt: skip
        with pytest.raises(SystemExit) as exit_info:
            recipe_main(argv)
        assert exit_info.value.code == 2
        assert message in capsys.readouterr().err


def test_every_dataset_recipe_carries_its_tasks_training(tmp_path, capsys):
    """Each datasets/*.toml reads as one recipe: what to record plus its task's training and evaluation; a
    [train] table in the file overrides the task's, and `actionflow-recipe FILE` prints it."""
    import tomllib
    from pathlib import Path

    from lerobot_actionflow.recipes.dataset import load_dataset_recipe

    files = sorted((Path(__file__).resolve().parents[1] / "datasets").glob("*.toml"))
    assert files
    overriding = []
    for path in files:
        dataset = load_dataset_recipe(path)
        tables = tomllib.loads(path.read_text())
        if "train" not in tables and "eval" not in tables:
            assert dataset.recipe == task_recipe(dataset.record.task), path.name
            continue
        overriding.append(path.name)
        assert dataset.recipe != task_recipe(dataset.record.task), path.name
        for key, value in tables.get("train", {}).items():
            assert getattr(dataset.recipe.train, key) == value, (path.name, key)
    # The two Lightbulb camera recipes train for their own steps (the socket-and-camera one streamed;
    # eval/results/cameras.md); every other one is its task's.
    assert overriding == ["lightbulb_rgb_paper_fixed_100.toml", "lightbulb_rgb_socket_paper_fixed_100.toml"]
    own = tmp_path / "mug_short.toml"
    own.write_text(
        'task = "MugHanging"\nvariant = "train"\nepisodes = 5\nrepo_id = "local/mug_short"\n'
        "[train]\nsteps = 300\n[eval]\nvariants = [\"test\"]\n"
    )
    dataset = load_dataset_recipe(own)
    assert dataset.recipe.train.steps == 300 and dataset.recipe.train.policy == {"action_smoothing": 0.5}
    recipe_main([str(own), "--out", str(tmp_path / "o")])
    lines = [line for line in capsys.readouterr().out.splitlines() if not line.startswith("#")]
    assert "--steps=300" in lines[1] and len(lines) == 3 and "--env.variant=test" in lines[2]
