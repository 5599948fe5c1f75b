"""Where a benchmark writes its table: ``outputs/bench/<its file name>`` unless ``--out`` says otherwise.

The committed results live in ``eval/results/``; a benchmark writes there only when asked (``--out
eval/results``, or ``--out eval/results/<name>.md`` for a file of another name), so a trial run never
overwrites them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

DEFAULT_OUT = Path("outputs/bench")
COMMITTED = Path("eval/results")


def add_out_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--out`` option every benchmark shares: a folder, or a ``.md`` file."""
    parser.add_argument(
        "--out", type=Path, default=DEFAULT_OUT,
        help=f"folder of the results file, or the .md file itself (default {DEFAULT_OUT}, git-ignored; the "
        f"committed results: --out {COMMITTED})",
    )  # fmt: skip


def write_result(out: Path, name: str, text: str) -> Path:
    """Write ``text`` to ``out/name`` (to ``out`` itself if it names a ``.md`` file) and say where."""
    path = out if out.suffix == ".md" else out / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text if text.endswith("\n") else text + "\n")
    hint = f" (the committed one: --out {COMMITTED})" if out == DEFAULT_OUT else ""
    print(f"wrote {path}{hint}")
    return path
