"""The layout of eval/: packages run as ``python -m eval.<package>.<module>``, no script edits ``sys.path``,
nothing writes into the source tree by default, and a result records where it came from without naming a
machine's paths."""

from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

import pytest

from eval import provenance
from eval.bench.output import DEFAULT_OUT, write_result
from eval.paper.plan import Paths

REPO = Path(__file__).resolve().parents[1]
MODULES = [
    "eval.paper.__main__", "eval.paper.plan", "eval.paper.profiles", "eval.paper.commands", "eval.paper.run",
    "eval.paper.report", "eval.paper.replay", "eval.bench.latency", "eval.bench.envs", "eval.bench.record",
    "eval.bench.train", "eval.bench.delay", "eval.diagnostics.mug_trace", "eval.diagnostics.mug_layouts",
    "eval.diagnostics.open_loop", "eval.diagnostics.lightbulb_fit", "eval.diagnostics.camera_view",
    "eval.bench.render", "eval.bench.camera_latency", "eval.bench.executor", "eval.paper.executor",
    "eval.bench.generate", "eval.diagnostics.demo_stats", "eval.diagnostics.loader_order",
]  # fmt: skip
MACHINE_PATH = re.compile(r"(/work/|/home/|/root/|/tmp/)")


def test_no_file_under_eval_or_tests_inserts_into_sys_path():
    """Scripts that reach each other through ``sys.path`` break as soon as one moves; packages import."""
    needle = "sys.path." + "insert"  # spelled apart so this file does not find itself
    files = [p for folder in ("eval", "tests") for p in (REPO / folder).rglob("*.py")]
    offenders = [str(p.relative_to(REPO)) for p in files if needle in p.read_text()]
    assert offenders == []


@pytest.mark.parametrize("name", MODULES)
def test_every_command_is_a_module_with_a_main(name):
    """Each command imports as part of its package (no script-relative import) and has a ``main(argv)``."""
    module = importlib.import_module(name)
    if name.endswith(("plan", "profiles", "commands", "run", "report", "paper.executor")):
        return  # the harness's library modules
    assert callable(module.main)


def test_default_outputs_are_git_ignored_folders():
    """A trial run must never overwrite the committed results: those need ``--out`` / ``--results-dir``."""
    assert Paths().results.parts[0] == "outputs" and Paths().work.parts[0] == "outputs"
    assert DEFAULT_OUT.parts[0] == "outputs"
    assert "outputs" in (REPO / ".gitignore").read_text()


def test_a_benchmark_writes_into_a_folder_or_to_a_named_file(tmp_path, capsys):
    assert write_result(tmp_path / "a", "latency_cpu.md", "x") == tmp_path / "a" / "latency_cpu.md"
    assert write_result(tmp_path / "b.md", "latency_cpu.md", "y\n").read_text() == "y\n"
    assert "wrote" in capsys.readouterr().out


def test_the_replay_baseline_runs_as_a_module(tmp_path):
    from eval.paper.commands import replay_command
    from eval.paper.plan import build
    from eval.paper.profiles import SMOKE

    cell = next(c for c in build("generalisation", SMOKE) if c.training is None)
    cmd = replay_command(cell, tmp_path / "data", tmp_path / "replay.json")
    assert cmd[:3] == [sys.executable, "-m", "eval.paper.replay"]
    assert provenance.portable_command(cmd).startswith("python -m eval.paper.replay --root ")


def test_provenance_names_the_commit_packages_and_machine_and_no_path():
    info = provenance.provenance()
    assert re.fullmatch(r"[0-9a-f]{40}", info["commit"]) and isinstance(info["dirty"], bool)
    assert set(info["versions"]) == set(provenance.PACKAGES)
    assert info["versions"]["lerobot_policy_actionflow"] and info["versions"]["torch"]
    assert info["machine"]["cpu"] and info["machine"]["cores"] >= 1 and "gpu" in info["machine"]
    assert not MACHINE_PATH.search(str(info)) and str(REPO) not in str(info)
    assert provenance.describe(info).startswith(f"Provenance: commit `{info['commit'][:10]}`")


def test_portable_commands_use_bare_console_scripts_and_relative_paths(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    bin_dir = Path(sys.executable).parent
    cmd = [str(bin_dir / "lerobot-train"), f"--dataset.root={tmp_path / 'data'}", "--output_dir",
           str(tmp_path), f"--policy.path={REPO / 'outputs' / 'ckpt'}", "--flag", "/elsewhere/x"]  # fmt: skip
    expected = ("lerobot-train --dataset.root=data --output_dir . --policy.path=outputs/ckpt "
                "--flag /elsewhere/x")
    assert provenance.portable_command(cmd) == expected
    assert provenance.portable_command([sys.executable, "-m", "eval.paper"]) == "python -m eval.paper"


def test_committed_cells_hold_no_machine_path():
    """The committed cells were rewritten with bare console scripts: no interpreter or home folder in them."""
    cells = sorted((REPO / "eval" / "results" / "paper" / "cells").rglob("*.json"))
    assert cells
    bad = [p.name for p in cells if MACHINE_PATH.search(p.read_text())]
    assert bad == []
