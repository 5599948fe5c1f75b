"""Running a command of a recipe: print it as a line a user can paste, then run it with this environment's
console scripts, offline, without wandb."""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
from pathlib import Path


def resolve(name: str) -> str:
    """A console script of this environment (``lerobot-train``...) by its path beside the running
    interpreter, so that a command runs with this interpreter whatever the ``PATH``; other names unchanged."""
    if name == "python":
        return sys.executable
    local = Path(sys.executable).parent / name
    return str(local) if "/" not in name and local.is_file() else name


def run(cmd: list[str], log: Path | None = None, **env_vars: str) -> None:
    """Print ``cmd`` (with ``env_vars`` as a prefix), then run it. With ``log``, its output goes to that file
    (appended) instead of the console, and a failure raises with the log's tail."""
    prefix = "".join(f"{k}={v} " for k, v in env_vars.items())
    print(f"\n$ {prefix}{shlex.join(cmd)}" + (f"   > {log}" if log else ""), flush=True)
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", **env_vars}
    argv = [resolve(cmd[0]), *cmd[1:]]
    if log is None:
        subprocess.run(argv, check=True, env=env)
        return
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("a") as out:
        code = subprocess.run(argv, env=env, stdout=out, stderr=subprocess.STDOUT).returncode
    if code != 0:
        tail = "".join(log.read_text(errors="replace").splitlines(keepends=True)[-30:])
        raise RuntimeError(f"{cmd[0]} exited with status {code}; the end of {log}:\n{tail}")
