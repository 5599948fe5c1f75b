"""What made a result (the code's commit, the package versions, the machine), and commands a reader can paste.

A committed result must say where it came from without naming anybody's disk: a paper cell and every
benchmark table carry :func:`provenance` (the git commit and whether the tree had uncommitted changes, the
versions of the packages that decide the numbers, the CPU, its cores and the GPU), and store their commands
through :func:`portable_command`, which writes console scripts by their bare names (``lerobot-train``,
``python``) and paths inside the working directory or the repository as relative ones.
"""

from __future__ import annotations

import functools
import os
import platform
import shlex
import subprocess
import sys
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("torch", "lerobot", "numpy", "mujoco", "gymnasium", "lerobot_policy_actionflow")
"""Distributions whose versions a result records: the ones that change its numbers."""


def _git(*args: str) -> str | None:
    """``git <args>`` in the repository (read-only: no optional index lock), or None outside a checkout."""
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}
    try:
        done = subprocess.run(["git", *args], cwd=REPO, env=env, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout if done.returncode == 0 else None


def git_state() -> dict[str, str | bool | None]:
    """``{"commit": sha or None, "dirty": whether tracked or new files differ from it (None: unknown)}``."""
    commit = _git("rev-parse", "HEAD")
    status = _git("status", "--porcelain") if commit else None
    dirty = None if status is None else bool(status.strip())
    return {"commit": commit.strip() if commit else None, "dirty": dirty}


def versions() -> dict[str, str | None]:
    """The installed version of each of :data:`PACKAGES` (None: not installed)."""
    found: dict[str, str | None] = {}
    for name in PACKAGES:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = None
    return found


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; elsewhere what :mod:`platform` knows)."""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        for line in cpuinfo.read_text(errors="replace").splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def gpu_name() -> str | None:
    """The first CUDA device's name, or None without torch or a GPU."""
    try:
        import torch
    except ModuleNotFoundError:
        return None
    return torch.cuda.get_device_name(0) if torch.cuda.is_available() else None


def machine() -> dict[str, str | int | None]:
    """The CPU model, its core count, the GPU (None without one) and the Python version."""
    python = platform.python_version()
    return {"cpu": cpu_model(), "cores": os.cpu_count(), "gpu": gpu_name(), "python": python}


@functools.cache
def provenance() -> dict:
    """The commit, package versions and machine of this process, gathered once: no absolute path in it."""
    return {**git_state(), "versions": versions(), "machine": machine()}


def describe(info: dict | None = None) -> str:
    """:func:`provenance` as one Markdown line for a benchmark's table."""
    info = info or provenance()
    commit = f"`{info['commit'][:10]}`" if info.get("commit") else "unknown"
    if info.get("dirty"):
        commit += " with uncommitted changes"
    packages = ", ".join(f"{k} {v}" for k, v in info["versions"].items() if v)
    host = info["machine"]
    gpu = host.get("gpu") or "no GPU"
    return f"Provenance: commit {commit}; {packages}; {host['cpu']}, {host['cores']} cores, {gpu}."


def _portable_path(text: str) -> str:
    if not text.startswith("/"):
        return text
    path = Path(text)
    if path.parent == Path(sys.executable).parent:  # this environment's console script or interpreter
        return "python" if path.name.startswith("python") else path.name
    for base in (Path.cwd(), REPO):
        if path.is_relative_to(base):
            return str(path.relative_to(base))
    return text


def portable(token: str) -> str:
    """One argument with an absolute path made portable, also as the value of ``--flag=PATH``."""
    if token.startswith("-") and "=" in token:
        flag, _, value = token.partition("=")
        return f"{flag}={_portable_path(value)}"
    return _portable_path(token)


def portable_command(cmd: Sequence[str]) -> str:
    """A command as a shell line without this machine's paths: ``/x/.venv/bin/lerobot-train`` ->
    ``lerobot-train``, ``/x/.venv/bin/python`` -> ``python``, ``<cwd>/outputs/a`` -> ``outputs/a``. Paths
    outside the working directory and the repository are kept: the caller chose them."""
    return shlex.join(portable(token) for token in cmd)
