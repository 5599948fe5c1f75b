"""The README stays true: its quick tour and its own-loop snippet run as written (at tiny sizes), it stays
short, and every relative link of the README and docs/ resolves (file and anchor)."""

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MAX_README_LINES = 250

TINY_SIZES = [
    # (pattern, replacement) applied to the quick tour. Each must match: a README edit that drops or renames
    # one fails here instead of silently running the full-size command.
    (r"--episodes 100\b", "--episodes 2"),
    (r"--steps=2000\b", "--steps=2"),
    (r"--batch_size=32\b", "--batch_size=2"),
    (r"--eval\.n_episodes=20\b", "--eval.n_episodes=1"),
    (r"--eval\.batch_size=10\b", "--eval.batch_size=1"),
    # a tiny network, added by the test only (the README trains the default model)
    (
        r"(lerobot-train --policy\.type=actionflow)\b",
        r"\1 --policy.dim=32 --policy.ipa_layers=1 --policy.transformer_layers=1",
    ),
]
CHECKPOINT = "outputs/stack/train/checkpoints/last/pretrained_model"
"""Where the quick tour's `lerobot-train` leaves its checkpoint, relative to the working directory."""


def _block(marker: str, lang: str) -> str:
    """The fenced ```lang block right after `<!-- marker -->` in the README."""
    match = re.search(rf"<!-- {marker} -->\n```{lang}\n(.*?)\n```", README.read_text(), re.DOTALL)
    assert match, f"README.md has no ```{lang} block right after <!-- {marker} -->"
    return match[1]


def _substitute(text: str, pattern: str, replacement: str) -> str:
    new, count = re.subn(pattern, replacement, text)
    assert count, f"the README snippet no longer contains {pattern!r}: update tests/test_readme.py to match"
    return new


def _to_tmp(text: str, tmp_path: Path) -> str:
    """Every `outputs/...` path of a snippet moved under ``tmp_path``."""
    return _substitute(text, r"(?<![\w/.-])outputs/", f"{tmp_path}/outputs/")


def _env(tmp_path: Path) -> dict[str, str]:
    """The venv's commands first on PATH, offline, no wandb, LeRobot's cache inside ``tmp_path``."""
    bin_dir = str(Path(sys.executable).parent)
    return {
        **os.environ,
        "PATH": bin_dir + os.pathsep + os.environ.get("PATH", ""),
        "HF_HUB_OFFLINE": "1",
        "WANDB_MODE": "disabled",
        "HF_LEROBOT_HOME": str(tmp_path / "hf_lerobot_home"),
    }


def _run(args: list[str], tmp_path: Path) -> str:
    result = subprocess.run(
        args, cwd=tmp_path, env=_env(tmp_path), capture_output=True, text=True, timeout=600
    )
    output = result.stdout + result.stderr
    assert result.returncode == 0, f"{' '.join(args)[:300]}\nexited {result.returncode}:\n{output[-4000:]}"
    return output


def _own_loop_code(checkpoint_dir: Path) -> str:
    """The README's own-loop snippet, its checkpoint path under ``checkpoint_dir``, 20-step episodes."""
    code = _substitute(_block("own-loop", "python"), r'Path\("outputs/', f'Path("{checkpoint_dir}/outputs/')
    return _substitute(
        code, r'(gym\.make\("gym_actionflow/Stack-v0", variant="D0")\)', r"\1, max_episode_steps=20)"
    )


def test_readme_is_short():
    """The README is a newcomer's page; the long material belongs in docs/."""
    lines = len(README.read_text().splitlines())
    assert lines <= MAX_README_LINES, (
        f"README.md has {lines} lines: keep <= {MAX_README_LINES}, the rest in docs/"
    )


def test_quick_tour_and_own_loop_run_as_written(tmp_path):
    """Each quick-tour command exits 0 at tiny sizes and leaves what the README says (checkpoint, evaluation,
    rerun recording); the own-loop snippet runs the tour's checkpoint and an untrained policy."""
    tour = _block("quick-tour", "bash")
    for pattern, replacement in TINY_SIZES:
        tour = _substitute(tour, pattern, replacement)
    tour = _to_tmp(tour, tmp_path)
    commands = [line.strip() for line in tour.replace("\\\n", " ").splitlines()]
    commands = [c for c in commands if c and not c.startswith("#")]
    assert len(commands) == 4, commands  # record, train, evaluate, visualise
    for command in commands:
        _run(["bash", "-c", command], tmp_path)

    assert (tmp_path / CHECKPOINT / "model.safetensors").is_file()
    assert (tmp_path / "outputs/stack/eval/eval_info.json").is_file()
    assert (tmp_path / "outputs/stack/rollout.rrd").is_file()

    # The snippet twice in one process (one LeRobot import): with the tour's checkpoint, then where there is
    # none, so that it builds an untrained policy from the env's features.
    absent = tmp_path / "no_checkpoint"
    code = _own_loop_code(tmp_path) + "\n" + _own_loop_code(absent)
    output = _run([sys.executable, "-c", code], tmp_path)
    assert output.count("success:") == 2, output[-2000:]
    assert not (absent / CHECKPOINT).exists()


def _anchors(markdown: str) -> set[str]:
    """GitHub's heading anchors of a markdown file, plus explicit `<a id=...>` ones."""
    anchors = set(re.findall(r'<a id="([^"]+)"', markdown))
    for heading in re.findall(r"^#{1,6} (.+)$", markdown, re.MULTILINE):
        anchors.add(re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-"))
    return anchors


def test_relative_links_resolve():
    """A link of the README, docs/ or datasets/README.md to a file of the repository points at a file that
    exists, and to a heading that exists (docs/ is one level down: a stale `eval/...` link fails here)."""
    pages = [README, ROOT / "datasets" / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    broken = []
    for page in pages:
        text = page.read_text()
        text_outside_code = re.sub(r"```.*?```", "", text, flags=re.DOTALL)
        for target in re.findall(r"\]\(([^)\s]+)\)", text_outside_code):
            if re.match(r"[a-z]+:", target):
                continue  # https:, mailto:
            path, _, anchor = target.partition("#")
            resolved = (page.parent / path).resolve() if path else page
            if not resolved.exists():
                broken.append(f"{page.relative_to(ROOT)}: {target} (no such file)")
            elif anchor and resolved.suffix == ".md" and anchor not in _anchors(resolved.read_text()):
                broken.append(f"{page.relative_to(ROOT)}: {target} (no such heading)")
    assert not broken, "\n".join(broken)
