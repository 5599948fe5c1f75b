"""The paper benchmark harness (``python -m eval.paper``): one tiny cell of each experiment through the real
actionflow-record, lerobot-train and lerobot-eval, the JSON, tables and plots it writes, resuming, the
provenance of a cell, and the rule that no evaluated layout was recorded."""

from __future__ import annotations

import json
import os
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from eval.paper import run as paper_run
from eval.paper.__main__ import main as harness
from eval.paper.commands import check_disjoint, check_plan, eval_seeds
from eval.paper.plan import EXPERIMENTS, Dataset, Paths, build
from eval.paper.profiles import PROFILES, SMOKE
from eval.provenance import PACKAGES
from lerobot_actionflow.recipes import EVAL_SEED, LAYOUTS

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def smoke(tmp_path_factory) -> tuple[Paths, dict[str, str]]:
    """The smoke profile's three experiments, run once from a temporary folder into its ``work`` and
    ``results`` (given as relative paths, as a user in the repository gives ``outputs/...``)."""
    root = tmp_path_factory.mktemp("paper")
    paths = Paths(root / "work", root / "results")
    mp = pytest.MonkeyPatch()
    mp.chdir(root)
    mp.setenv("HF_LEROBOT_HOME", str(root / "hf_lerobot"))
    mp.setenv("OMP_NUM_THREADS", "1")
    # The replay baseline runs as `python -m eval.paper.replay`, which a user runs from the repository root.
    mp.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])))
    logs = {}
    try:
        for experiment in EXPERIMENTS:
            argv = [experiment, "--profile", "smoke", "--work-dir", "work", "--results-dir", "results"]
            harness(argv)
            logs[experiment] = " ".join(argv)
    finally:
        mp.undo()
    return paths, logs


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_a_tiny_cell_of_each_experiment_writes_json_table_and_plot(smoke, experiment):
    """Each experiment's cells ran the standard commands and left their JSON, the table and the plot, each
    naming the command that made it."""
    paths, argv = smoke
    cells = [json.loads(p.read_text()) for p in paths.cells("smoke", experiment).glob("*.json")]
    assert len(cells) == len(build(experiment, SMOKE)) > 0
    for cell in cells:
        assert 0.0 <= cell["success"] <= 1.0 and cell["n_episodes"] >= 1
        assert cell["harness_command"].endswith(argv[experiment])
        assert "actionflow-record" in cell["commands"]["record"]
        if cell["model"].startswith("replay"):
            assert cell["commands"]["replay"].startswith("python -m eval.paper.replay --root work/data/")
            continue
        assert "lerobot-train --policy.type=actionflow" in cell["commands"]["train"]
        assert ".partial" not in cell["commands"]["train"]  # the command a user reruns: the final folder
        assert (
            "lerobot-eval" in cell["commands"]["eval"] and "--seed=200000" in cell["commands"]["eval"]
        )  # the harness's default: the held-out layouts
        assert cell["layouts"] == "heldout" and cell["eval_seeds"][0] == LAYOUTS["heldout"] == 200_000
        assert cell["eval_seeds"][0] > cell["record_seeds"][1]
    table = (paths.results / f"smoke_{experiment}.md").read_text()
    assert "python -m eval.paper report --profile smoke --results-dir results" in table
    assert "| model |" in table
    assert "Commits of the cells: `" in table and "before cells recorded their commit" not in table
    assert all(c["group"] in table for c in cells)
    png = paths.results / f"smoke_{experiment}.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000
    assert "## Wall time per cell" in table
    if experiment == "inference-steps":
        assert any("--policy.num_inference_steps=1" in c["commands"]["eval"] for c in cells)
        assert "K=1" in table
        flow = next(c for c in cells if c["model"] == "A.1")
        assert f"| {flow['group']} | A.1 ({flow['note']}) | 1 | " in table.split("## Wall time per cell")[1]
    if experiment == "generalisation":
        assert {c["eval_variant"] for c in cells if c["task"] == "MugHanging"} == {"train", "test"}
        assert "--env.mug_yaw=slight" in next(c for c in cells if c["model"] == "A.1")["commands"]["eval"]
        assert "replay 1.5 mm off" in table


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_a_cell_records_its_provenance_and_no_absolute_path(smoke, experiment):
    """A committed cell must say which code, packages and machine made it, and hold no path of the machine
    that ran it (the interpreter's folder, the repository, the working folder) that a reader cannot paste."""
    paths, _ = smoke
    for file in paths.cells("smoke", experiment).glob("*.json"):
        cell = json.loads(file.read_text())
        info = cell["provenance"]
        assert len(info["commit"]) == 40 and isinstance(info["dirty"], bool)
        assert set(info["versions"]) == set(PACKAGES) and info["versions"]["torch"]
        assert info["machine"]["cpu"] and info["machine"]["cores"] >= 1 and "gpu" in info["machine"]
        text = file.read_text()
        for machine_path in (str(REPO), str(Path(sys.executable).parent), str(paths.work.parent)):
            assert machine_path not in text, (file.name, machine_path)
        for command in cell["commands"].values():
            assert not command.startswith("/"), command
            assert command.split()[0] in ("actionflow-record", "lerobot-train", "lerobot-eval", "python")


def test_the_wall_time_table_counts_a_shared_training_once_and_every_evaluation():
    """Three cells evaluating one training at three K: one training, three evaluations; a dataset shared
    by all of them is counted once in the total."""
    from eval.paper.report import timing_section

    def cell(k: int, train: str, eval_s: float) -> dict:
        return {"group": "Coffee D0", "model": "A.1", "key": f"k{k}",
                "commands": {"train": train, "record": "actionflow-record coffee"},
                "seconds": {"record": 60.0, "train": 600.0, "eval": eval_s}}  # fmt: skip

    cells = [cell(k, "lerobot-train a", 60.0 * i) for i, k in enumerate((1, 2, 4), start=1)]
    cells.append(dict(cell(1, "lerobot-train b", 30.0), model="DP", note="UNet 64-128-256"))
    lines = timing_section(cells)
    assert "| Coffee D0 | A.1 | 1 | 10.0 | 3 | 1.0-3.0 |" in lines
    assert "| Coffee D0 | DP (UNet 64-128-256) | 1 | 10.0 | 1 | 0.5 |" in lines
    # one dataset (60 s) + two trainings (1200 s) + four evaluations (390 s) = 1650 s
    assert any(line.startswith("In all 0.5 h: recording 1 min (1 dataset)") for line in lines)
    assert timing_section([{k: v for k, v in c.items() if k != "seconds"} for c in cells]) == []


def test_several_training_seeds_give_the_mean_and_range_in_the_table_and_error_bars_in_the_plot(tmp_path):
    """Three trainings of one cell show as their mean with the lowest and highest seed; one training as its
    rate alone; the plot draws the range as an error bar."""
    from eval.paper.report import aggregate, markdown_table, plot

    def cell(model: str, success: float) -> dict:
        return dict(group="Coffee D0", model=model, experiment="sample-efficiency", demos=50,
                    success=success, n_episodes=50)  # fmt: skip

    table = aggregate([cell("A.1", 0.62), cell("A.1", 0.9), cell("A.1", 0.74), cell("DP", 0.5)])
    rate = table["Coffee D0"]["A.1"]["50 demos"]
    assert rate.mean == pytest.approx(2.26 / 3) and (rate.low, rate.high, rate.seeds) == (0.62, 0.9, 3)
    assert rate.error_bar() == pytest.approx((100 * (rate.mean - 0.62), 100 * (0.9 - rate.mean)))
    text = markdown_table(table["Coffee D0"])
    assert "| A.1 | 75% of 50 (62-90%, 3 seeds) |" in text
    assert "| DP | 50% of 50 |" in text
    plot("sample-efficiency", table, tmp_path / "p.png", "caption")
    assert (tmp_path / "p.png").stat().st_size > 0


def test_superseded_cells_are_listed_apart_and_never_pooled_with_todays(smoke, tmp_path):
    """A cell moved to ``superseded/`` (its settings left the profile) leaves the tables and the plot's
    seeds, and is listed in its own section with its steps, loader and success."""
    import shutil

    from eval.paper.report import SUPERSEDED, series, write

    paths, _ = smoke
    cells_dir = tmp_path / "cells" / "smoke" / "generalisation"
    shutil.copytree(paths.cells("smoke", "generalisation"), cells_dir)
    old = dict(json.loads(next(cells_dir.glob("*__A.1__*.json")).read_text()), success=0.123)
    old["commands"] = dict(old["commands"], train=old["commands"]["train"] + " --dataset.streaming=true")
    (cells_dir / SUPERSEDED).mkdir()
    (cells_dir / SUPERSEDED / "old.json").write_text(json.dumps(old))
    write(tmp_path, "smoke", "generalisation", "python -m eval.paper report --profile smoke")
    table = (tmp_path / "smoke_generalisation.md").read_text()
    head, section = table.split("## Superseded cells")
    assert "12%" not in head and "seeds)" not in head  # not pooled as a second training seed
    row = f"| {old['group']} | {series(old)} | {old['eval_variant']} layout | {old['steps']} steps, streaming"
    assert row + " loader | 12% of 1 |" in section


def test_a_finished_cell_is_never_run_again(smoke, monkeypatch, capsys):
    """Rerunning an experiment whose cells have their JSON runs no command at all."""
    paths, _ = smoke

    def no_command(*args, **kwargs):
        raise AssertionError(f"a finished cell ran a command: {args}")

    monkeypatch.setattr(paper_run, "run", no_command)
    harness(["sample-efficiency", "--profile", "smoke", "--work-dir", str(paths.work),
             "--results-dir", str(paths.results)])  # fmt: skip
    assert "0 cells run now, 1 already finished" in capsys.readouterr().out


def test_an_interrupted_training_starts_again_from_nothing(tmp_path, monkeypatch):
    """A training folder left by a killed lerobot-train (``.partial``) is deleted before the new run, and the
    finished folder appears only when the trainer has returned."""
    paths = Paths(tmp_path / "work", tmp_path / "results")
    training = next(c.training for c in build("sample-efficiency", SMOKE))
    partial = paths.train(training).with_name(paths.train(training).name + ".partial")
    (partial / "checkpoints" / "000001").mkdir(parents=True)  # what the killed run left
    seen = []

    def fake_train(cmd, log=None, **env):
        out = Path(next(a for a in cmd if a.startswith("--output_dir=")).split("=", 1)[1])
        seen.append(out.exists())  # the stale folder must be gone before lerobot-train starts
        (out / "checkpoints" / "000002" / "pretrained_model").mkdir(parents=True)
        assert not paths.train(training).exists()

    monkeypatch.setattr(paper_run, "run", fake_train)
    info = paper_run.train(training, paths)
    assert seen == [False] and not partial.exists()
    assert list(paper_run.checkpoints(paths.train(training))) == [2]
    assert paper_run.train(training, paths) == info and len(seen) == 1  # finished: not trained again


def test_evaluation_seeds_never_overlap_recording_seeds():
    """Every profile's plan keeps the evaluated layouts (lerobot-eval --seed=200000 or 100000, whole
    batches) apart from any seed its recordings may try; an overlap is a clear error before anything runs."""
    for profile in PROFILES.values():
        for experiment in EXPERIMENTS:
            for layouts in LAYOUTS:
                check_plan(build(experiment, profile, layouts=layouts))
    assert eval_seeds(50, 10, "heldout") == range(200_000, 200_050)
    assert eval_seeds(50, 10) == range(EVAL_SEED, EVAL_SEED + 50)
    assert eval_seeds(5, 10) == range(EVAL_SEED, EVAL_SEED + 10)  # the last batch's extra envs count
    with pytest.raises(ValueError, match=r"seeds \[100000, 100001\] are both recorded and evaluated"):
        check_disjoint([7, 100_000, 100_001], eval_seeds(2, 2), "cell")
    cell = build("sample-efficiency", SMOKE)[0]
    late = Dataset("Stack", "D0", 2, seed=LAYOUTS["heldout"] - 3)  # the smoke plan: held-out layouts
    with pytest.raises(ValueError, match="record from a lower --seed"):
        check_plan([replace(cell, dataset=late)])


def test_the_loader_is_chosen_per_task_for_the_main_job_and_the_harness(tmp_path):
    """MugHanging and Lightbulb train on LeRobot's map-style loader (full shuffle), the other tasks on its
    streaming one: the task recipes say so, and every harness cell follows them."""
    from eval.paper.commands import train_command
    from lerobot_actionflow.recipes import LOADERS, task_recipe

    assert task_recipe("MugHanging").train.loader_flags() == list(LOADERS["map"]) == ["--num_workers=2"]
    assert task_recipe("Lightbulb").train.loader == "map" and task_recipe("Stack").train.loader == "stream"
    cells = build("generalisation", PROFILES["cpu"]) + build("sample-efficiency", PROFILES["cpu"])
    trainings = {c.training.dataset.task: c.training for c in cells if c.training}
    assert {"MugHanging", "Lightbulb", "StackThree"} <= set(trainings)
    for task, training in trainings.items():
        cmd = train_command(training, tmp_path / "data", tmp_path / "out")
        mapped = task in ("MugHanging", "Lightbulb")
        assert ("--dataset.streaming=true" in cmd) == (not mapped), (task, cmd)
        assert ("--num_workers=2" in cmd) == mapped, (task, cmd)


def test_the_inference_steps_experiment_covers_the_robomimic_tasks_beside_the_papers_figures():
    from eval.paper.report import published_table

    cpu = {g.task for g in PROFILES["cpu"].inference_steps}
    gpu = {g.task for g in PROFILES["gpu"].inference_steps}
    assert {"RobosuiteSquare", "RobosuiteToolHang"} <= cpu
    assert {"RobosuiteLift", "RobosuiteCan", "RobosuiteSquare", "RobosuiteToolHang"} <= gpu
    table = published_table("RobosuiteToolHang")
    assert "| Flow Matching | 73% | 85% | 81% | 85% | 87% |" in table  # the paper's IS = 2 ... 100
    assert "| Diffusion Policy | 51% |" in table
    assert published_table("Threading") is None


def test_a_group_may_train_longer_than_its_profile_and_the_steps_flag_still_overrides_both():
    """Tool Hang's demonstrations are 3.6 times Square's, so the cpu profile trains it for as many epochs,
    not as many steps; ``--steps`` still sets every training of a run."""
    cpu = PROFILES["cpu"]
    cells = build("inference-steps", cpu, ["RobosuiteSquare", "RobosuiteToolHang"])
    flow = {c.dataset.task: c.training.steps for c in cells if c.training.model != "DP"}
    assert flow == {"RobosuiteSquare": cpu.steps["inference-steps"], "RobosuiteToolHang": 11_000}
    floor = cpu.min_steps["diffusion"]  # the diffusion baseline keeps its own, longer minimum
    diffusion = {c.dataset.task: c.training.steps for c in cells if c.training.model == "DP"}
    assert diffusion == {"RobosuiteSquare": max(cpu.steps["inference-steps"], floor),
                         "RobosuiteToolHang": max(11_000, floor)}  # fmt: skip
    forced = build("inference-steps", cpu, ["RobosuiteToolHang"], None, 7)
    assert {c.training.steps for c in forced} == {7}


def test_mug_hanging_runs_actionflow_with_its_runtime_settings_and_longer_training():
    """The generalisation experiment trains MugHanging's ActionFlow models with the task's runtime settings
    (kept in the checkpoint's config, so lerobot-eval uses them); the diffusion baseline and the Lightbulb
    cells do not get them. Every generalisation training of ActionFlow runs 6000 steps on the cpu profile,
    every diffusion training at least its own minimum."""
    from eval.paper.commands import train_command
    from lerobot_actionflow.recipes import task_recipe

    mug_runtime = tuple(task_recipe("MugHanging").train.policy_flags())
    assert mug_runtime == ("--policy.action_smoothing=0.5",)
    assert task_recipe("Stack").train.policy_flags() == []
    cpu = PROFILES["cpu"]
    trainings = {(c.dataset.task, c.training.model, c.dataset.env_kwargs): c.training
                 for c in build("generalisation", cpu) if c.training}  # fmt: skip
    mug = [t for (task, _, _), t in trainings.items() if task == "MugHanging"]
    assert {t.model for t in mug} == {"A.1", "DP"} and len(mug) == 3  # pose A.1 and DP, point cloud A.1
    for training in trainings.values():
        cmd = train_command(training, Path("data"), Path("out"))
        flow_mug = training.dataset.task == "MugHanging" and training.model != "DP"
        assert all((flag in cmd) == flow_mug for flag in mug_runtime), (training.model, cmd)
        # MugHanging and Lightbulb both train longer than the profile's 3000; diffusion at least its minimum
        expected = max(6000, cpu.min_steps["diffusion"]) if training.model == "DP" else 6000
        assert training.steps == expected, (training.dataset.task, training.model)
    assert cpu.steps["generalisation"] == 3000
    assert all(flag.startswith("--policy.") for flag in mug_runtime)


def test_every_diffusion_training_normalises_the_object_poses_and_the_report_says_which_did(tmp_path):
    """LeRobot's Diffusion Policy has no normalisation entry for ENV features and would read the object poses
    raw; every harness training of it min-max normalises them, and a cell's training description (the
    superseded table) tells a raw-pose cell from a normalised one by its command."""
    import shlex

    from eval.paper.commands import train_command
    from eval.paper.report import training_of

    diffusion = [c.training for p in PROFILES.values() for e in EXPERIMENTS for c in build(e, p)
                 if c.training and c.training.policy_type == "diffusion"]  # fmt: skip
    assert diffusion
    for training in diffusion:
        cmd = train_command(training, tmp_path / "data", tmp_path / "out")
        mapping = [f for f in cmd if f.startswith("--policy.normalization_mapping=")]
        assert len(mapping) == 1, cmd
        assert json.loads(mapping[0].split("=", 1)[1]) == {
            "VISUAL": "MEAN_STD", "STATE": "MIN_MAX", "ENV": "MIN_MAX", "ACTION": "MIN_MAX"
        }  # fmt: skip
        cell = {"steps": training.steps, "commands": {"train": shlex.join(cmd)}}
        assert "object poses min-max normalised" in training_of(cell)
        raw = [f for f in cmd if not f.startswith("--policy.normalization_mapping=")]
        assert "object poses raw" in training_of({"steps": 5, "commands": {"train": shlex.join(raw)}})


def test_the_cpu_profile_trains_diffusion_at_least_its_minimum_with_its_learning_rate(tmp_path):
    """On the cpu profile every Diffusion Policy training runs at least ``min_steps`` (longer groups keep
    theirs) at lr 1e-3, the flow policies keep the experiment's steps, ``--steps`` still overrides both, and
    the report names each diffusion cell's learning rate from its command."""
    import shlex

    from eval.paper.commands import train_command
    from eval.paper.plan import group_steps
    from eval.paper.profiles import CPU
    from eval.paper.report import training_of

    floor = CPU.min_steps["diffusion"]
    for experiment in EXPERIMENTS:
        groups = {(g.task, g.variant): g for g in getattr(CPU, experiment.replace("-", "_"))}
        for t in {c.training for c in build(experiment, CPU) if c.training}:
            group = group_steps(CPU, experiment, groups[t.dataset.task, t.dataset.variant])
            if t.policy_type != "diffusion":
                assert t.steps == group, t.key
                continue
            assert t.steps == max(floor, group), t.key
            cmd = train_command(t, tmp_path / "data", tmp_path / "out")
            assert "--policy.optimizer_lr=1e-3" in cmd and f"--steps={t.steps}" in cmd
            assert training_of({"steps": t.steps, "commands": {"train": shlex.join(cmd)}}).endswith("lr 1e-3")
    assert {c.training.steps for c in build("inference-steps", CPU, tasks=["Threading"], steps=7)} == {7}


def test_diffusion_is_evaluated_under_ddim_at_every_k_and_under_its_own_ddpm_sampler(tmp_path):
    """The inference-steps experiment evaluates each Diffusion Policy training with DDIM at every K of the
    profile and once with the DDPM sampler it was trained with (all 100 steps), one training for all six; the
    report shows the two samplers as separate rows."""
    from eval.paper.commands import eval_command
    from eval.paper.report import series

    cells = [c for c in build("inference-steps", PROFILES["cpu"], ["Threading"]) if c.model == "DP"]
    assert len({c.training for c in cells}) == 1
    ks = PROFILES["cpu"].inference_ks
    assert sorted((c.schedule, c.k) for c in cells) == sorted([("DDPM", 100)] + [("DDIM", k) for k in ks])
    assert len({c.key for c in cells}) == len(cells)
    for c in cells:
        cmd = eval_command(c, tmp_path / "ckpt", tmp_path / "eval")
        assert f"--policy.noise_scheduler_type={c.schedule}" in cmd
        assert f"--policy.num_inference_steps={c.k}" in cmd
    rows = {series({"model": "DP", "schedule": c.schedule, "note": c.note}) for c in cells}
    assert len(rows) == 2 and all(r.startswith(("DP DDIM", "DP DDPM")) for r in rows)


def test_the_euclidean_flow_cells_name_the_frame_of_their_velocity(tmp_path):
    """Every harness training of the Euclidean flow asks for the action-frame velocity by flag, so its cells'
    commands differ from those trained before the flag (EEF frame, superseded), and the report tells them
    apart by their commands."""
    import shlex

    from eval.paper.commands import train_command
    from eval.paper.report import training_of

    euclidean = [c.training for p in PROFILES.values() for e in EXPERIMENTS for c in build(e, p)
                 if c.training and c.training.model == "A.1-euclidean"]  # fmt: skip
    assert euclidean
    for training in euclidean:
        cmd = train_command(training, tmp_path / "data", tmp_path / "out")
        assert "--policy.action_space=euclidean" in cmd and "--policy.euclidean_frame=action" in cmd
        cell = {"steps": training.steps, "commands": {"train": shlex.join(cmd)}}
        assert training_of(cell).endswith("velocity in each action's frame")
        old = [f for f in cmd if f != "--policy.euclidean_frame=action"]
        assert training_of({"steps": 5, "commands": {"train": shlex.join(old)}}).endswith("the EEF frame")
    a1 = next(c.training for c in build("inference-steps", PROFILES["cpu"]) if c.training.model == "A.1")
    assert "velocity" not in training_of({"steps": 5, "commands": {"train": shlex.join(
        train_command(a1, tmp_path / "data", tmp_path / "out"))}})


def test_variants_pick_groups_by_their_training_variant():
    """``--variants D2`` runs the published protocol's group of a task without its D0 group; a variant no
    group of the plan trains on is refused by name."""
    cpu = PROFILES["cpu"]
    d2 = build("sample-efficiency", cpu, ["Threading"], ["DP"], variants=["D2"])
    assert d2 and {(c.dataset.task, c.dataset.variant, c.model) for c in d2} == {("Threading", "D2", "DP")}
    assert {c.dataset.episodes for c in d2} == {100, 200}
    both = build("sample-efficiency", cpu, ["Threading"], ["DP"])
    assert {c.dataset.variant for c in both} == {"D0", "D2"}
    with pytest.raises(ValueError, match=r"--variants \['D1'\]: no such group .* for Threading"):
        build("sample-efficiency", cpu, ["Threading"], variants=["D1"])


def test_seeds_and_demos_pick_the_trainings_of_a_headline_table():
    """``--demos 50 --seeds 1 2 3`` trains each 50-demonstration dataset of the plan three times, one
    training per seed and nothing else; the profile's own seed keeps its cell key, so a seed-1 cell of the
    headline table is the published cell's twin. Repeated seeds and sizes no group has are refused."""
    cpu = PROFILES["cpu"]
    default = build("sample-efficiency", cpu, ["Coffee"], ["A.1"], variants=["D0"])
    cells = build("sample-efficiency", cpu, ["Coffee"], ["A.1"], variants=["D0"], seeds=[1, 2, 3], demos=[50])
    assert {c.dataset.episodes for c in default} == {20, 50, 200}
    assert {c.dataset.episodes for c in cells} == {50}
    assert sorted(c.training.seed for c in cells) == [1, 2, 3]
    assert len({c.key for c in cells}) == 3
    published = {c.key for c in default if c.dataset.episodes == 50}
    assert published == {c.key for c in cells if c.training.seed == 1}
    with pytest.raises(ValueError, match=r"--demos \[30\]: no group .* its sizes are \[20, 50, 200\]"):
        build("sample-efficiency", cpu, ["Coffee"], variants=["D0"], demos=[30])
    with pytest.raises(ValueError, match=r"--seeds \[1, 1\]: expected distinct"):
        build("sample-efficiency", cpu, ["Coffee"], seeds=[1, 1])


# ---------------------------------------------------------------------------- the Ray executor
def _ray_env(monkeypatch, root: Path) -> None:
    monkeypatch.chdir(root)
    monkeypatch.setenv("HF_LEROBOT_HOME", str(root / "hf_lerobot"))
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")  # a local Ray for one test: no token file in $HOME
    # Ray's workers import the stages (eval.paper.executor) from the repository, as the replay does.
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])))


def test_the_smoke_plan_through_a_local_ray_of_two_lanes_writes_the_local_json(smoke, tmp_path, monkeypatch):
    """``--executor ray --lanes 2`` runs the same stages as Ray tasks (Ray is the ``ray`` extra, installed by
    ``make test``): the same cells with the same commands as the local run; a finished cell is not scheduled
    again; a stage that fails fails its cell by key, not the others."""
    from eval.paper.executor import run_ray

    local_paths, _ = smoke
    _ray_env(monkeypatch, tmp_path)
    argv = ["sample-efficiency", "--profile", "smoke", "--work-dir", "work", "--results-dir", "results",
            "--executor", "ray", "--lanes", "2"]  # fmt: skip
    harness(argv)
    paths = Paths(Path("work"), Path("results"))

    def cells(where: Paths) -> dict[str, dict]:
        files = where.cells("smoke", "sample-efficiency").glob("*.json")
        return {p.name: json.loads(p.read_text()) for p in files}

    local, ray_cells = cells(local_paths), cells(paths)
    assert set(ray_cells) == set(local) and ray_cells
    for name, cell in ray_cells.items():
        assert cell["commands"] == local[name]["commands"]  # the same relative paths, the same flags
        assert cell["harness_command"].endswith("--executor ray --lanes 2")
        assert len(cell["provenance"]["commit"]) == 40 and str(tmp_path) not in json.dumps(cell)
        assert 0.0 <= cell["success"] <= 1.0
    assert (paths.results / "smoke_sample-efficiency.md").is_file()

    # A finished cell is read back, a broken one (its recording cannot start) fails by its key.
    cell = build("sample-efficiency", SMOKE)[0]
    broken = replace(cell, dataset=replace(cell.dataset, env_kwargs=(("no_such_option", "1"),)))
    broken = replace(broken, training=replace(cell.training, dataset=broken.dataset))
    finished = paths.cell(cell).stat().st_mtime_ns
    with pytest.raises(RuntimeError, match=r"1 of 2 cells failed:\n" + broken.key):
        run_ray([cell, broken], paths, workers=1, harness_command="test", lanes=2)
    assert paths.cell(cell).stat().st_mtime_ns == finished and not paths.cell(broken).exists()


def test_the_executor_flags_are_checked_and_a_dry_run_spreads_the_plan_over_lanes(capsys):
    """``--address``/``--lanes`` without Ray, or zero lanes, are refused by name; ``--dry-run --executor ray
    --lanes N`` says what the busiest lane trains (longest trainings first onto the least loaded lane)."""
    from eval.paper.executor import plan_lanes

    for bad in (["--lanes", "2"], ["--address", "head:6379"], ["--executor", "ray", "--lanes", "0"]):
        with pytest.raises(SystemExit):
            harness(["sample-efficiency", "--profile", "smoke", "--dry-run", *bad])
        assert bad[-2] in capsys.readouterr().err
    cells = build("sample-efficiency", PROFILES["cpu"], tasks=["Coffee"])
    steps = sorted((t.steps for t in {c.training for c in cells}), reverse=True)
    text = plan_lanes(cells, 2)
    assert f"{len(steps)} trainings" in text and f"of {sum(steps)} in all" in text
    busiest = int(text.split("busiest lane trains ")[1].split()[0])
    assert sum(steps) / 2 <= busiest <= sum(steps) / 2 + steps[0]
    harness(["sample-efficiency", "--profile", "gpu", "--dry-run", "--executor", "ray", "--lanes", "8"])
    assert "on 8 lanes (cuda)" in capsys.readouterr().out


# ---------------------------------------------------------------------------- held-out layouts
def test_held_out_cells_share_the_development_training_and_dev_cells_keep_their_keys():
    """A held-out cell evaluates the same training as its development twin (re-evaluating costs evaluations
    only) on seeds from 200000; the committed development cells keep the keys they were run under, so the
    harness still finds them finished."""
    for experiment in EXPERIMENTS:
        heldout = build(experiment, PROFILES["cpu"])
        dev = build(experiment, PROFILES["cpu"], layouts="dev")
        assert [c.training for c in heldout] == [c.training for c in dev]
        trained = [(h, d) for h, d in zip(heldout, dev, strict=True) if h.training is not None]
        assert all(h.key != d.key and "_heldout_" in h.key for h, d in trained)
        committed = {p.stem for p in (REPO / "eval/results/paper/cells/cpu" / experiment).glob("*.json")}
        # Held-out cells committed so far include the headline table's extra training seeds.
        three_seeds = build(experiment, PROFILES["cpu"], seeds=[1, 2, 3])
        assert committed and committed <= {c.key for c in dev} | {c.key for c in three_seeds}
        assert {k for k in committed if "_heldout_" not in k} <= {c.key for c in dev}
        cell = trained[0][0]
        ckpt = Path("ckpt")
        from eval.paper.commands import eval_command

        assert "--seed=200000" in eval_command(cell, ckpt, Path("o"))
        assert "--seed=100000" in eval_command(replace(cell, layouts="dev"), ckpt, Path("o"))
    with pytest.raises(ValueError, match="layouts 'test'"):
        build("sample-efficiency", SMOKE, layouts="test")


def test_development_cells_are_refused_into_the_committed_results(capsys):
    """Tuning on the development layouts and writing the cells into eval/results/paper would publish a
    tuned number: the harness refuses before running anything, and says what to do instead."""
    with pytest.raises(SystemExit):
        harness(["sample-efficiency", "--profile", "smoke", "--layouts", "dev", "--results-dir",
                 str(REPO / "eval/results/paper")])  # fmt: skip
    err = capsys.readouterr().err
    assert "--layouts dev" in err and "--layouts heldout" in err


def test_the_report_lists_development_cells_apart_and_says_when_it_has_no_held_out_cell(smoke, tmp_path):
    """Held-out cells make the tables; development ones go to their own section, never pooled as another
    seed. With development cells only, the head says every number is on the tuning layouts."""
    import shutil

    from eval.paper.report import write

    paths, _ = smoke
    cells_dir = tmp_path / "cells" / "smoke" / "generalisation"
    shutil.copytree(paths.cells("smoke", "generalisation"), cells_dir)
    trained = next(cells_dir.glob("*__A.1__train_heldout_*.json"))
    dev = dict(json.loads(trained.read_text()), success=0.123, layouts="dev", eval_seeds=[100_000, 100_000])
    (cells_dir / "dev.json").write_text(json.dumps(dev))
    write(tmp_path, "smoke", "generalisation", "python -m eval.paper report --profile smoke")
    table = (tmp_path / "smoke_generalisation.md").read_text()
    head, section = table.split("## Development layouts (seeds from 100000): tuning, not a result")
    assert "12%" not in head and "seeds)" not in head and "Development layouts only" not in head
    assert "12% of 1" in section.split("## Wall time per cell")[0]
    for file in cells_dir.glob("*.json"):  # now development cells only (and the replays)
        cell = json.loads(file.read_text())
        if cell.get("eval_seeds"):
            file.write_text(json.dumps(dict(cell, eval_seeds=[100_000, 100_000])))
    write(tmp_path, "smoke", "generalisation", "python -m eval.paper report --profile smoke")
    table = (tmp_path / "smoke_generalisation.md").read_text()
    assert "**Development layouts only.**" in table and "## Development layouts (seeds" not in table


def test_every_committed_cell_names_its_commit_and_no_machine_path():
    """A committed cell says which code made it: the commit it ran at, or, for a cell run before cells
    recorded provenance, the first commit that held its result; none holds a path of the machine that ran
    it."""
    import re

    from eval.paper.report import commits_line

    files = sorted((REPO / "eval/results/paper/cells").rglob("*.json"))
    assert len(files) >= 100
    for file in files:
        text = file.read_text()
        info = json.loads(text)["provenance"]
        sha = info.get("commit") or info.get("landed_in")
        assert sha and re.fullmatch(r"[0-9a-f]{40}", sha), file.name
        assert not re.search(r'"/(home|root|work|tmp|Users)/', text), file.name
        assert not any(c.startswith("/") for c in json.loads(text)["commands"].values()), file.name
    old = {"provenance": {"commit": None, "landed_in": "b" * 40}}
    cells = [{"provenance": {"commit": "a" * 40, "dirty": True}}, old, old]
    assert commits_line(cells) == (
        "Commits of the cells: `aaaaaaaaaa` with uncommitted changes (1 cell). Run before cells recorded "
        "their commit (2 cells), each first landed in: `bbbbbbbbbb` (2 cells)."
    )
