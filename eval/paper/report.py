"""Tables and plots of the paper benchmark, rebuilt from the cells' JSON alone
(``python -m eval.paper report``).

Per experiment and profile: ``<profile>_<experiment>.md`` (one table per task group, the profile's settings,
the harness commands that made the cells and the one that made the file) and ``<profile>_<experiment>.png``:
success vs demonstrations per task, success vs inference steps, or success on the training vs the test
layout. Numbers are final-checkpoint success; several training seeds give their mean and range (min-max),
plotted as error bars; a profile
that evaluates checkpoints during training adds a second table, the best of those evaluations, labelled.
The head of each file names the commits its cells were run at (their recorded provenance).

Cells evaluated on the development layouts (seeds from 100000, where settings were tuned) are never pooled
with held-out ones (from 200000): when an experiment has held-out cells, they make the tables and the plot
and the development cells are listed apart; when it has none yet, the file says in its head that every number
in it is on development layouts and not a held-out result.
"""

from __future__ import annotations

import json
import re
import statistics
from collections import defaultdict
from pathlib import Path
from typing import NamedTuple

from eval.paper.profiles import DIFFUSION_NORMALISATION
from lerobot_actionflow.recipes import LAYOUTS

TITLES = {
    "sample-efficiency": "Sample efficiency: success vs demonstrations",
    "inference-steps": "Inference steps: success vs integration / denoising steps",
    "generalisation": "Generalisation: success on the training vs the test layout",
}


PUBLISHED_INFERENCE_STEPS = {
    # The paper's Robomimic table with state observations ("ph" datasets: proficient human demonstrations;
    # mean of 3 seeds, 50 initial states): success per inference steps IS, DDIM for diffusion (DDPM at 100).
    "RobosuiteLift": {"Diffusion Policy": {2: 1.00, 5: 1.00, 10: 1.00, 20: 1.00, 100: 1.00},
                      "Flow Matching": {2: 1.00, 5: 1.00, 10: 0.99, 20: 0.99, 100: 0.99}},
    "RobosuiteCan": {"Diffusion Policy": {2: 0.93, 5: 0.99, 10: 0.98, 20: 0.99, 100: 0.98},
                     "Flow Matching": {2: 0.99, 5: 0.98, 10: 0.99, 20: 0.99, 100: 0.99}},
    "RobosuiteSquare": {"Diffusion Policy": {2: 0.72, 5: 0.90, 10: 0.91, 20: 0.86, 100: 0.91},
                        "Flow Matching": {2: 0.83, 5: 0.91, 10: 0.87, 20: 0.85, 100: 0.88}},
    "RobosuiteToolHang": {"Diffusion Policy": {2: 0.51, 5: 0.81, 10: 0.90, 20: 0.90, 100: 0.85},
                          "Flow Matching": {2: 0.73, 5: 0.85, 10: 0.81, 20: 0.85, 100: 0.87}},
}  # fmt: skip
"""Published figures set beside ours (paper, appendix, Robomimic results with state observations)."""


def published_table(task: str) -> str | None:
    """The paper's numbers for ``task`` as a markdown table, or None where it published none."""
    ref = PUBLISHED_INFERENCE_STEPS.get(task)
    if ref is None:
        return None
    steps = sorted({k for row in ref.values() for k in row})
    lines = ["| paper (robomimic ph demos, 3 seeds) | " + " | ".join(f"IS={k}" for k in steps) + " |",
             "|---|" + "---|" * len(steps)]
    lines += [f"| {name} | " + " | ".join(f"{row[k]:.0%}" for k in steps) + " |" for name, row in ref.items()]
    return "\n".join(lines)


SUPERSEDED = "superseded"
"""Subfolder of an experiment's cells for cells whose settings the profile no longer uses (kept, with their
commands, as the record of what those settings measured; never pooled with today's cells)."""


def load_cells(cells_dir: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted(cells_dir.glob("*.json"))]


def loader_of(cell: dict) -> str:
    """Which LeRobot loader a cell's ``lerobot-train`` used, read from its command."""
    train = cell.get("commands", {}).get("train", "")
    return "streaming" if "--dataset.streaming=true" in train else "map-style"


def training_of(cell: dict) -> str:
    """How a cell's policy was trained, read from its ``lerobot-train`` command: steps, loader and, for
    Diffusion Policy, whether it normalised the object poses (``environment_state``; LeRobot's own mapping
    leaves them raw); for the Euclidean flow, the frame of its velocity (``--policy.euclidean_frame``)."""
    if not cell.get("steps"):
        return ""
    text = f"{cell['steps']} steps, {loader_of(cell)} loader"
    train = cell.get("commands", {}).get("train", "")
    if "--policy.type=diffusion" in train:
        text += ", object poses " + ("min-max normalised" if DIFFUSION_NORMALISATION in train else "raw")
        lr = re.search(r"--policy\.optimizer_lr=(\S+)", train)
        text += f", lr {lr.group(1) if lr else '1e-4'}"  # without the flag, LeRobot's default
    if "--policy.action_space=euclidean" in train:  # before the flag existed, the EEF frame was the only one
        frame = "each action's frame" if "--policy.euclidean_frame=action" in train else "the EEF frame"
        text += f", velocity in {frame}"
    return text


def superseded_section(results: Path, profile: str, experiment: str) -> list[str]:
    """Markdown lines listing an experiment's superseded cells (none: no lines), for its table in
    ``results``."""
    relative = f"cells/{profile}/{experiment}/{SUPERSEDED}/"
    folder = results / relative
    cells = load_cells(folder) if folder.is_dir() else []
    if not cells:
        return []
    lines = [
        "## Superseded cells (earlier settings of the profile)", "",
        f"Kept in [{relative}]({relative}) with their commands; not in the tables above.", "",
        "| group | model | layout | training | success |", "|---|---|---|---|---|",
    ]  # fmt: skip
    def order(c: dict) -> tuple:  # a group's rows together, columns in their tables' order
        return c["group"], series(c), c.get("demos") or 0, c.get("k") or 0, c["eval_variant"]

    for c in sorted(cells, key=order):
        lines.append(f"| {c['group']} | {series(c)} | {column(c, c['experiment'])} | {training_of(c)} | "
                     f"{c['success']:.0%} of {c['n_episodes']} |")
    return [*lines, ""]


BEFORE_PROVENANCE = "before cells recorded their commit"
"""How the report names cells run before cells recorded their provenance."""


def _counted(counts: dict[str, int]) -> str:
    return ", ".join(f"{name} ({n} cell{'' if n == 1 else 's'})" for name, n in sorted(counts.items()))


def commits_line(cells: list[dict]) -> str:
    """Which commits the cells were run at, with their counts (``abc1234567 (12 cells)``; a commit run with
    uncommitted changes says so). Cells run before cells recorded their commit are counted apart, each by the
    first commit that held its result (``provenance.landed_in``): the code that ran it is that or older."""
    ran: dict[str, int] = defaultdict(int)
    landed: dict[str, int] = defaultdict(int)
    for c in cells:
        info = c.get("provenance") or {}
        if info.get("commit"):
            ran[f"`{info['commit'][:10]}`" + (" with uncommitted changes" if info.get("dirty") else "")] += 1
        else:
            landed[f"`{info['landed_in'][:10]}`" if info.get("landed_in") else "unknown"] += 1
    parts = []
    if ran:
        parts.append("Commits of the cells: " + _counted(ran) + ".")
    if landed:
        n = sum(landed.values())
        parts.append(f"Run {BEFORE_PROVENANCE} ({n} cells), each first landed in: " + _counted(landed) + ".")
    return " ".join(parts)


def layouts_of(cell: dict) -> str | None:
    """``heldout`` or ``dev``, from a cell's first evaluation seed; None for a replay (recorded layouts)."""
    seeds = cell.get("eval_seeds")
    if not seeds:
        return None
    return "heldout" if seeds[0] >= LAYOUTS["heldout"] else "dev"


def development_section(cells: list[dict], experiment: str) -> list[str]:
    """Development-layout cells listed apart from the held-out tables: the numbers settings were tuned on."""
    if not cells:
        return []
    lines = [
        f"## Development layouts (seeds from {LAYOUTS['dev']}): tuning, not a result", "",
        "The same kind of cells on the layouts the settings were chosen on; kept as the record of that "
        "tuning, never pooled with the held-out tables above.", "",
    ]  # fmt: skip
    for group, rows in aggregate(cells).items():
        lines += [f"### {group}", "", markdown_table(rows), ""]
    return lines


def _minutes(values: list[float]) -> str:
    lo, hi = min(values) / 60, max(values) / 60
    return f"{lo:.1f}" if round(lo, 1) == round(hi, 1) else f"{lo:.1f}-{hi:.1f}"


def timing_section(cells: list[dict]) -> list[str]:
    """Markdown lines with the wall time the cells took, per group and model, read from each cell's
    ``seconds``: a training shared by several cells (one per K or layout) is counted once, every evaluation
    on its own; a dataset once. No timed cell: no lines."""
    timed = [c for c in cells if c.get("seconds")]
    if not timed:
        return []
    trainings: dict = defaultdict(dict)  # (group, model) -> {train command: seconds}
    evals: dict = defaultdict(list)
    records: dict = {}
    for c in timed:
        name = f"{c['model']} ({c['note']})" if c.get("note") else c["model"]
        commands, seconds = c.get("commands", {}), c["seconds"]
        if "train" in seconds:
            trainings[c["group"], name][commands.get("train", c["key"])] = seconds["train"]
        for part in ("eval", "replay"):
            if part in seconds:
                evals[c["group"], name].append(seconds[part])
        if "record" in seconds:
            records[commands.get("record", c["key"])] = seconds["record"]
    lines = [
        "## Wall time per cell", "",
        "As each cell recorded it (`seconds` in its JSON), on the machine that ran it, most often with a "
        "second cell sharing the CPU; a training shared by several cells is counted once.", "",
        "| group | model | trainings | training (min) | evaluations | evaluation per cell (min) |",
        "|---|---|---|---|---|---|",
    ]  # fmt: skip
    for key in sorted(set(trainings) | set(evals)):
        train, ev = list(trainings.get(key, {}).values()), evals.get(key, [])
        train_min, eval_min = _minutes(train) if train else "", _minutes(ev) if ev else ""
        lines.append(f"| {key[0]} | {key[1]} | {len(train)} | {train_min} | {len(ev)} | {eval_min} |")
    record_s = sum(records.values())
    train_s = sum(sum(t.values()) for t in trainings.values())
    eval_s = sum(sum(e) for e in evals.values())
    lines += ["", f"In all {(record_s + train_s + eval_s) / 3600:.1f} h: recording {record_s / 60:.0f} min "
              f"({len(records)} dataset{'' if len(records) == 1 else 's'}), training {train_s / 3600:.1f} h, "
              f"evaluation {eval_s / 3600:.1f} h.", ""]  # fmt: skip
    return lines


def series(cell: dict) -> str:
    """What a table row / plot line is: the model, its evaluation setting, and its note (e.g. the UNet)."""
    name = cell["model"]
    if cell.get("schedule"):
        name += f" {cell['schedule']}"
    return f"{name} ({cell['note']})" if cell.get("note") else name


def column(cell: dict, experiment: str) -> str:
    if experiment == "sample-efficiency":
        return f"{cell['demos']} demos"
    if experiment == "inference-steps":
        return f"K={cell['k']}"
    return f"{cell['eval_variant']} layout" if cell["task"] == "MugHanging" else f"{cell['eval_variant']}"


class Rate(NamedTuple):
    """One table entry: success over the training seeds of a cell."""

    mean: float
    low: float
    high: float
    seeds: int
    episodes: int

    def text(self) -> str:
        """``84% of 50``, or with several seeds ``84% of 50 (80-88%, 3 seeds)``: the mean and the range."""
        out = f"{self.mean:.0%} of {self.episodes}"
        if self.seeds > 1:
            out += f" ({100 * self.low:.0f}-{100 * self.high:.0f}%, {self.seeds} seeds)"
        return out

    def error_bar(self) -> tuple[float, float]:
        """Percentage points below and above the mean to the lowest and highest seed."""
        return 100 * (self.mean - self.low), 100 * (self.high - self.mean)


def aggregate(cells: list[dict], value: str = "success") -> dict:
    """``{group: {series: {column: Rate}}}`` over training seeds."""
    pooled: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for c in cells:
        v = c["success"] if value == "success" else c.get("best_of_periodic", {}).get("success")
        if v is not None:
            pooled[c["group"]][series(c)][column(c, c["experiment"])].append((v, c["n_episodes"]))
    out: dict = {}
    for group, rows in pooled.items():
        out[group] = {}
        for name, cols in rows.items():
            out[group][name] = {}
            for col, vals in cols.items():
                rates = [v for v, _ in vals]
                out[group][name][col] = Rate(
                    statistics.fmean(rates), min(rates), max(rates), len(rates), vals[0][1]
                )
    return out


def _sort_key(col: str) -> tuple:
    """Numeric columns by value (demos, K); layouts with the training layout first."""
    digits = "".join(ch for ch in col if ch.isdigit())
    return (0, int(digits)) if digits else (1, not col.startswith("train"), col)


def markdown_table(rows: dict) -> str:
    cols = sorted({c for r in rows.values() for c in r}, key=_sort_key)
    lines = ["| model | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    for name, r in rows.items():
        cells = []
        for c in cols:
            if c not in r:
                cells.append("")
                continue
            cells.append(r[c].text())
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(experiment: str, table: dict, path: Path, caption: str) -> None:
    try:
        import matplotlib
    except ModuleNotFoundError as err:
        raise ModuleNotFoundError(
            "the paper benchmark's plots need matplotlib: pip install matplotlib (or -e '.[test]')"
        ) from err
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = list(table)
    names = sorted({name for rows in table.values() for name in rows})
    colour = {name: f"C{i % 10}" for i, name in enumerate(names)}  # one colour per series in every panel
    layouts = sorted({c for rows in table.values() for r in rows.values() for c in r}, key=_sort_key)
    bar_colour = {col: f"C{i % 10}" for i, col in enumerate(layouts)}  # one colour per layout in every panel
    fig, axes = plt.subplots(1, len(groups), figsize=(4.2 * len(groups), 3.6), squeeze=False)
    for ax, group in zip(axes[0], groups, strict=True):
        rows = table[group]
        if experiment == "generalisation":
            cols = sorted({c for r in rows.values() for c in r}, key=_sort_key)
            width = 0.8 / max(len(cols), 1)
            for j, col in enumerate(cols):
                xs = [i + j * width for i, r in enumerate(rows.values()) if col in r]
                ys = [100 * r[col].mean for r in rows.values() if col in r]
                bars = list(zip(*(r[col].error_bar() for r in rows.values() if col in r), strict=True))
                ax.bar(xs, ys, width, yerr=bars, capsize=3, label=col, color=bar_colour[col])
            ax.set_xticks([i + width * (len(cols) - 1) / 2 for i in range(len(rows))])
            ax.set_xticklabels([n.split(" (")[0] for n in rows], rotation=20, fontsize=8)
        else:
            for name, r in rows.items():
                cols = sorted(r, key=_sort_key)
                xs = [_sort_key(c)[1] for c in cols]
                bars = list(zip(*(r[c].error_bar() for c in cols), strict=True))
                ax.errorbar(xs, [100 * r[c].mean for c in cols], yerr=bars, marker="o", capsize=3, label=name,
                            color=colour[name])  # fmt: skip
            ax.set_xscale("log")
            ticks = sorted({_sort_key(c)[1] for r in rows.values() for c in r})
            ax.set_xticks(ticks, [str(t) for t in ticks])
            ax.minorticks_off()
            ax.set_xlabel("demonstrations" if experiment == "sample-efficiency" else "inference steps K")
        ax.set_title(group, fontsize=10)
        ax.set_ylim(0, 105)
        ax.set_ylabel("success (%)")
    # One legend for all panels, under them, so no line of any panel is hidden behind it.
    labelled = {}
    for ax in axes[0]:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            labelled.setdefault(label, handle)
    legend_rows = -(-len(labelled) // 3)
    fig.set_size_inches(fig.get_figwidth(), 3.6 + 0.2 * legend_rows)  # room for the legend under the panels
    bottom = (0.18 + 0.2 * legend_rows) / fig.get_figheight()
    fig.legend(list(labelled.values()), list(labelled), loc="lower center", ncol=3, fontsize=7,
               bbox_to_anchor=(0.5, 0.03), frameon=False)  # fmt: skip
    fig.text(0.01, 0.005, caption, fontsize=6, family="monospace")
    fig.tight_layout(rect=(0, bottom, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, metadata={"Description": caption})
    plt.close(fig)


def write(results: Path, profile: str, experiment: str, report_command: str) -> tuple[Path, Path] | None:
    """Rebuild the table and plot of one experiment from its cells; None when no cell has finished."""
    every = load_cells(results / "cells" / profile / experiment)
    if not every:
        return None
    heldout = any(layouts_of(c) == "heldout" for c in every)
    cells = [c for c in every if layouts_of(c) != "dev"] if heldout else every
    apart = [c for c in every if layouts_of(c) == "dev"] if heldout else []
    table = aggregate(cells)
    stem = results / f"{profile}_{experiment}"
    made_by = sorted({c["harness_command"] for c in every if c.get("harness_command")})
    where = "held-out layouts" if heldout else "development layouts (tuning), not held-out"
    caption = f"{profile} profile, {where}; made by: {report_command}"
    plot(experiment, table, stem.with_suffix(".png"), caption)
    first = next((c for c in cells if c.get("steps")), cells[0])  # a trained cell, not a replay
    lines = [
        f"# {TITLES[experiment]} ({profile} profile)", "",
        f"This file and [{stem.name}.png]({stem.name}.png) were made by `{report_command}` from the "
        f"{len(cells)} cells in [cells/{profile}/{experiment}/](cells/{profile}/{experiment}/) (each "
        "cell's JSON holds its `actionflow-record`, `lerobot-train` and `lerobot-eval` commands and "
        "timings). The cells were run by:", "", *[f"    {c}" for c in made_by], "", commits_line(every), "",
        f"Final-checkpoint success over {first['n_episodes']} evaluation episodes per cell, evaluation seeds "
        "from "
        f"{first['eval_seeds'][0] if first.get('eval_seeds') else 'n/a'} (no recorded seed is evaluated); "
        f"training: {first['steps']} steps at batch {first['batch_size']} on `{first['device']}`.", "",
    ]  # fmt: skip
    if not heldout:
        lines += [
            f"**Development layouts only.** Every number below is on seeds from {LAYOUTS['dev']}, the "
            "layouts the settings were tuned on: not a held-out result. `--layouts heldout` (the harness's "
            f"default) evaluates the same trainings on seeds from {LAYOUTS['heldout']}.", "",
        ]  # fmt: skip
    tasks = {c["group"]: c["task"] for c in cells}
    for group, rows in table.items():
        lines += [f"## {group}", "", markdown_table(rows), ""]
        steps = sorted({c["steps"] for c in cells if c["group"] == group and c.get("steps")})
        if steps and steps != [first["steps"]]:
            trained = " / ".join(map(str, steps))
            lines += [f"Trained for {trained} steps (this group's setting in the profile).", ""]
        published = published_table(tasks[group]) if experiment == "inference-steps" else None
        if published:
            lines += [
                "Beside it, the paper's figures for the task (human demonstrations and robosuite's own "
                "controller; ours: scripted demonstrations, the cpu profile's training):", "", published, "",
            ]
    best = aggregate(cells, value="best")
    if best:
        lines += ["## Best of the periodic evaluations during training (the published protocols' number)", ""]
        for group, rows in best.items():
            lines += [f"### {group}", "", markdown_table(rows), ""]
    lines += [f"![{TITLES[experiment]}]({stem.name}.png)", ""]
    lines += development_section(apart, experiment)
    lines += timing_section(every)
    lines += superseded_section(results, profile, experiment)
    stem.with_suffix(".md").write_text("\n".join(lines))
    return stem.with_suffix(".md"), stem.with_suffix(".png")
