"""The import directions of the layout, read from the source: eval -> lerobot_actionflow -> gym_actionflow;
inside lerobot_actionflow the schema is a leaf, the policy core is plain torch, nothing imports the tools."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "lerobot_actionflow"


def imported_modules(path: Path) -> set[str]:
    """Every module a file imports, at any depth (lazy imports inside functions included)."""
    modules = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            modules.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            modules.add(node.module)
    return modules


def importing(files, packages: tuple[str, ...]) -> dict[str, list[str]]:
    """``{file: the modules of ``packages`` (or their submodules) it imports}``, for the files that do."""
    found = {}
    for path in files:
        modules = imported_modules(path)
        bad = sorted(m for m in modules if any(m == p or m.startswith(f"{p}.") for p in packages))
        if bad:
            found[str(path.relative_to(ROOT))] = bad
    return found


def test_schema_is_a_leaf():
    """The data contract every tool converts through imports nothing of ours."""
    assert importing([PACKAGE / "schema.py"], ("lerobot_actionflow", "gym_actionflow")) == {}


def test_policy_core_imports_neither_lerobot_nor_the_simulator():
    files = sorted((PACKAGE / "core").glob("*.py"))
    assert importing(files, ("lerobot", "gym_actionflow", "gymnasium", "mujoco")) == {}


def test_simulation_suite_imports_nothing_of_the_policy():
    files = sorted((ROOT / "envs" / "gym_actionflow").rglob("*.py"))
    assert importing(files, ("lerobot_actionflow", "lerobot", "torch")) == {}


@pytest.mark.parametrize("folder", ["core", "."])
def test_the_policy_never_imports_the_tools(folder):
    files = sorted((PACKAGE / folder).glob("*.py"))
    assert importing(files, ("lerobot_actionflow.tools",)) == {}
