"""``actionflow-record``'s command line: every input is checked before anything is written, a recorded folder
carries its card and its token names, and ``push`` shares it without touching it."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.datasets.streaming_dataset import StreamingLeRobotDataset

from lerobot_actionflow import schema
from lerobot_actionflow.tools.record import LOG_NAME, Recipe, load_recipe, main, record

REPO_ID = "local/stack_cli"
STACK_TOKENS = ["eef", "cube_a", "cube_b"]
BASE = ["--task", "Stack", "--episodes", "1", "--quiet"]


def _run(argv: list[str], capsys) -> tuple[int, str, str]:
    """``main(argv)`` as the command runs it: its exit code (argparse's errors exit), stdout and stderr."""
    try:
        code = main(argv)
    except SystemExit as stop:
        code = stop.code
    out, err = capsys.readouterr()
    return code, out, err


def _tree(root: Path) -> dict[str, str]:
    """Every file under ``root`` and its content hash."""
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("cli") / "stack"
    record(Recipe(task="Stack", variant="D0", episodes=1, repo_id=REPO_ID), root=root, progress=False)
    return root


# ---------------------------------------------------------------------------- bad input: exit 2, no folder
BAD_FLAGS = [
    (["--seed", "-5"], "--seed: got -5; expected an integer >= 0"),
    (["--noise", "nan"], "--noise: got nan; expected a finite number >= 0"),
    (["--noise", "inf"], "--noise: got inf; expected a finite number >= 0"),
    (["--noise", "-0.5"], "--noise: got -0.5; expected a finite number >= 0"),
    (["--episodes", "0"], "--episodes: got 0; expected an integer >= 1"),
    (["--variant", "D7"], "--variant: got 'D7'; expected one of ('D0', 'D1') for Stack"),
    (["--task", "Juggle"], "--task: unknown task 'Juggle'; gym_actionflow has: Stack, StackThree"),
    (["--env-kwarg", "foo=1"], "--env-kwarg foo: gym_actionflow/Stack-v0 takes no keyword 'foo'; expected"),
    (["--env-kwarg", "variant=D1"], "--env-kwarg variant: variant is a field of its own"),
    (["--repo-id", "a b/c"], "--repo-id: got 'a b/c'; expected a Hub repo id"),
    (["--seed", "2.7"], "argument --seed: invalid int value: '2.7'"),
    (["--episodes", "true"], "argument --episodes: invalid int value: 'true'"),
]


@pytest.mark.parametrize("flags, message", BAD_FLAGS, ids=[" ".join(f) for f, _ in BAD_FLAGS])
def test_a_bad_flag_names_itself_exits_2_and_writes_nothing(flags, message, tmp_path, capsys):
    """Guards against a bad value creating the dataset folder (and logging the value as the recording's
    identity, so that the corrected rerun is refused), and against an error that does not say which flag."""
    code, _, err = _run([*BASE, *flags, "--root", str(tmp_path / "x")], capsys)
    assert code == 2, err
    assert message in err, err
    assert err.startswith("actionflow-record: error:") or "usage:" in err
    assert not (tmp_path / "x").exists()


BAD_FIELDS = [
    ('noise = "high"', "noise in {path}: got 'high'; expected a finite number >= 0"),
    ("noise = nan", "noise in {path}: got nan; expected a finite number >= 0"),
    ("episodes = 2.7", "episodes in {path}: got 2.7; expected an integer >= 1"),
    ("episodes = true", "episodes in {path}: got True; expected an integer >= 1"),
    ("seed = -1", "seed in {path}: got -1; expected an integer >= 0"),
    ("seed = 1.0", "seed in {path}: got 1.0; expected an integer >= 0"),
    ('obs_mode = "rgb"', "obs_mode in {path}: got 'rgb'; expected one of ('state', 'pixels')"),
    ('variant = "train"', "variant in {path}: got 'train'; expected one of ('D0', 'D1') for Stack"),
    ("env_kwargs = 3", "env_kwargs in {path}: got 3; expected a table"),
    ("[env_kwargs]\nfoo = 1", "env_kwargs.foo in {path}: gym_actionflow/Stack-v0 takes no keyword 'foo'"),
]


def _recipe(tmp_path: Path, line: str) -> Path:
    fields = {"task": '"Stack"', "variant": '"D0"', "episodes": "1", "repo_id": '"local/r"'}
    key = line.split("=")[0].strip()
    body = "".join(f"{k} = {v}\n" for k, v in fields.items() if k != key)
    path = tmp_path / "r.toml"
    path.write_text(body + line + "\n")
    return path


@pytest.mark.parametrize("line, message", BAD_FIELDS, ids=[line for line, _ in BAD_FIELDS])
def test_a_bad_recipe_field_names_the_field_and_the_file(line, message, tmp_path, capsys):
    """Guards against a recipe field of the wrong type being a traceback (``noise = "high"``) or silently
    truncated (``episodes = 2.7`` recorded 2 episodes, ``episodes = true`` one)."""
    path = _recipe(tmp_path, line)
    with pytest.raises(ValueError, match=message.format(path=path).replace("(", r"\(").replace(")", r"\)")):
        load_recipe(path)
    code, _, err = _run([str(path), "--root", str(tmp_path / "x"), "--quiet"], capsys)
    assert code == 2 and message.format(path=path) in err, err
    assert not (tmp_path / "x").exists()


def test_a_flag_overrides_a_recipe_field_and_is_named_as_the_flag(tmp_path, capsys):
    path = _recipe(tmp_path, "seed = 0")
    code, _, err = _run([str(path), "--seed", "-3", "--root", str(tmp_path / "x")], capsys)
    assert code == 2 and "--seed: got -3" in err, err


def test_the_corrected_rerun_records(tmp_path, capsys):
    """The user's sequence: a bad --seed, then the same command corrected, into the same --root. It was
    refused ("holds a different recording") until the folder was deleted by hand."""
    root = str(tmp_path / "x")
    assert _run([*BASE, "--seed", "-5", "--root", root], capsys)[0] == 2
    assert _run([*BASE, "--noise", "nan", "--root", root], capsys)[0] == 2
    code, out, err = _run([*BASE, "--seed", "0", "--root", root], capsys)
    assert code == 0, err
    assert "1 episodes in" in out
    assert json.loads((tmp_path / "x" / "meta" / LOG_NAME).read_text())["kept_seeds"] == [0]


def test_recipe_objects_are_strict_too():
    with pytest.raises(ValueError, match="episodes: got True; expected an integer >= 1"):
        Recipe(task="Stack", variant="D0", episodes=True, repo_id="local/x")
    with pytest.raises(ValueError, match="noise: got inf"):
        Recipe(task="Stack", variant="D0", episodes=1, repo_id="local/x", noise=float("inf"))
    assert Recipe(task="Stack", variant="D0", episodes=1, repo_id="local/x", noise=0).noise == 0.0


def test_env_keywords_follow_kwargs_to_the_base_class():
    """MugHanging and Lightbulb pass ``**kwargs`` on to the base: its keywords count, unknown ones do not."""
    ok = {"hanger_obs": "point_cloud", "image_size": 64}
    Recipe(task="MugHanging", variant="train", episodes=1, repo_id="local/m", env_kwargs=ok)
    Recipe(task="Lightbulb", variant="D0", episodes=1, repo_id="local/l", env_kwargs={"socket_pose": "any"})
    with pytest.raises(ValueError, match="MugHanging-v0 takes no keyword 'hanger'; expected one of"):
        Recipe(task="MugHanging", variant="train", episodes=1, repo_id="local/m", env_kwargs={"hanger": 1})


@pytest.mark.parametrize("where", ["under_a_file", "proc", "read_only"])
def test_an_unwritable_root_is_one_line_and_writes_nothing(where, tmp_path, monkeypatch, capsys):
    """It was a 30-line traceback from LeRobot's mkdir, after the env was built."""
    if where == "under_a_file":
        (tmp_path / "f").write_text("")
        root = tmp_path / "f" / "x"
    elif where == "proc":
        if not Path("/proc/self").is_dir():
            pytest.skip("no /proc")
        root = Path("/proc/x")
    else:
        (tmp_path / "ro").mkdir(mode=0o555)
        root = tmp_path / "ro" / "sub" / "x"
        if os.geteuid() == 0:  # root writes into read-only folders: refuse it as a read-only mount would
            from lerobot_actionflow.tools.record import recorder

            def refuse(**_):
                raise PermissionError(13, "Permission denied")

            monkeypatch.setattr(recorder.tempfile, "mkdtemp", refuse)
    code, _, err = _run([*BASE, "--root", str(root)], capsys)
    assert code == 2, err
    if where == "read_only":
        assert "(Permission denied)" in err
    assert err.startswith(f"actionflow-record: error: --root {root}:") and err.count("\n") == 1, err
    assert not root.exists()
    assert not list(tmp_path.rglob(".actionflow_probe_*"))


def test_the_installed_command_prints_one_line_and_no_traceback(tmp_path):
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_LEROBOT_HOME": str(tmp_path / "hf")}
    res = subprocess.run(
        [str(Path(sys.executable).parent / "actionflow-record"), *BASE, "--noise", "inf", "--root",
         str(tmp_path / "x")],
        env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2
    errors = [line for line in res.stderr.splitlines() if "torchcodec" not in line]
    expected = "actionflow-record: error: --noise: got inf; expected a finite number >= 0 (0: deterministic"
    assert len(errors) == 1 and errors[0].startswith(expected), res.stderr
    assert not (tmp_path / "x").exists()


# ---------------------------------------------------------------------------- the folder describes itself
def test_token_names_are_the_features_names(dataset):
    """Guards against ``names: null`` on the token keys: a user of the dataset cannot tell which row is which
    object. A 2-D key names each axis (LeRobot's ``{axis: [names]}``); the flat environment state each
    element."""
    features = json.loads((dataset / "meta" / "info.json").read_text())["features"]
    assert features[schema.TOKEN_POSES]["names"] == {"tokens": STACK_TOKENS, "pose": list(schema.POSE_NAMES)}
    assert features[schema.TOKEN_FEATURES]["names"] == {
        "tokens": STACK_TOKENS,
        "features": ["is_eef", "is_cube_a", "is_cube_b", "gripper_opening"],
    }
    env_state = features[schema.ENV_STATE]["names"]
    assert len(env_state) == 18 and env_state[:2] == ["cube_a.x", "cube_a.y"]
    assert env_state[-1] == "cube_b.r21"
    assert features[schema.STATE]["names"] == list(schema.STATE_NAMES)


def test_named_datasets_load_map_style_and_streaming(dataset):
    """LeRobot reads the named features back (the map-style loader and the streaming one of
    ``--dataset.streaming=true``) with the same tensors."""
    ds = LeRobotDataset(REPO_ID, root=dataset)
    assert ds.meta.names[schema.TOKEN_POSES]["tokens"] == STACK_TOKENS
    streamed = next(iter(StreamingLeRobotDataset(REPO_ID, root=dataset, max_num_shards=1)))
    item = ds[int(streamed["index"])]  # the stream is shuffled
    assert tuple(item[schema.TOKEN_POSES].shape) == (3, 9)
    got = torch.as_tensor(streamed[schema.TOKEN_POSES]).reshape(3, 9)
    torch.testing.assert_close(got, item[schema.TOKEN_POSES], atol=0, rtol=0)


def test_the_card_is_written_beside_the_data(dataset):
    """Guards against a folder that describes itself only once pushed: README.md is there after recording,
    with LeRobot's Hub metadata, which token is which and the command that reproduces it."""
    card = (dataset / "README.md").read_text()
    assert card.startswith("---\n") and "- LeRobot" in card and "data_files: data/*/*.parquet" in card
    assert "0 `eef`, 1 `cube_a`, 2 `cube_b`" in card
    assert "`is_eef`, `is_cube_a`, `is_cube_b`, `gripper_opening`" in card
    assert f"--task Stack --variant D0 --episodes 1 --seed 0 --noise 1 --repo-id {REPO_ID}" in card
    assert "| episodes | 1 " in card and '"total_episodes": 1' in card


# ---------------------------------------------------------------------------- push
class FakeHub:
    """Stands in for ``huggingface_hub.HfApi``: records the calls, uploads nothing."""

    calls: list[tuple[str, dict]] = []
    fail_upload = False

    def __init__(self, *args, **kwargs):
        pass

    def __getattr__(self, name):
        def call(*args, **kwargs):
            if name == "upload_folder" and FakeHub.fail_upload:
                raise httpx.ConnectError("no route to huggingface.co")
            FakeHub.calls.append((name, {"args": args, **kwargs}))

        return call


@pytest.fixture
def hub(monkeypatch) -> type[FakeHub]:
    import huggingface_hub

    FakeHub.calls, FakeHub.fail_upload = [], False
    monkeypatch.setattr(huggingface_hub, "HfApi", FakeHub)
    monkeypatch.setattr(huggingface_hub, "get_token", lambda: "hf_fake")
    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    return FakeHub


def _uploaded(call: dict) -> list[str]:
    """The files ``upload_folder`` would send, by huggingface_hub's own pattern filter."""
    from huggingface_hub.utils import filter_repo_objects

    root = Path(call["folder_path"])
    files = [p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file()]
    return sorted(filter_repo_objects(files, ignore_patterns=call["ignore_patterns"]))


def test_push_uploads_the_folder_as_it_is_and_changes_nothing(dataset, tmp_path, hub, capsys):
    root = tmp_path / "copy"
    shutil.copytree(dataset, root)
    before = _tree(root)
    for repo in ("you/stack", "you/stack", "lab/stack_mirror"):  # again, and elsewhere: never refused
        hub.calls = []
        code, out, err = _run(["push", str(root), "--to", repo], capsys)
        assert code == 0, err
        assert f"https://huggingface.co/datasets/{repo}" in out
        names = [name for name, _ in hub.calls]  # no upload_file: the card is in the folder
        assert names == ["create_repo", "upload_folder", "delete_tag", "create_tag"]
        calls = dict(hub.calls)
        assert calls["create_repo"]["repo_id"] == repo and calls["create_repo"]["repo_type"] == "dataset"
        upload = calls["upload_folder"]
        assert upload["repo_id"] == repo and Path(upload["folder_path"]) == root
        assert calls["create_tag"]["tag"] == "v3.0"  # LeRobot loads a Hub dataset at its codebase version
        assert _uploaded(upload) == sorted(before)
        assert "README.md" in before and f"meta/{LOG_NAME}" in before
    assert _tree(root) == before
    # The recording's identity is untouched: the same record command finds it complete.
    code, out, _ = _run([*BASE, "--repo-id", REPO_ID, "--root", str(root)], capsys)
    assert code == 0 and "already complete" in out


def test_push_private(dataset, hub, capsys):
    assert _run(["push", str(dataset), "--to", "you/x", "--private"], capsys)[0] == 0
    assert dict(hub.calls)["create_repo"]["private"] is True


def test_push_to_hub_at_record_time_is_not_part_of_the_recording(tmp_path, hub, capsys):
    """``--push-to-hub`` used to become the dataset's repo_id: a later push elsewhere was refused as a
    different recording, or recorded a second copy."""
    root = tmp_path / "x"
    code, out, err = _run([*BASE, "--root", str(root), "--push-to-hub", "you/first"], capsys)
    assert code == 0, err
    assert dict(hub.calls)["upload_folder"]["repo_id"] == "you/first"
    assert json.loads((root / "meta" / LOG_NAME).read_text())["recipe"]["repo_id"] == "actionflow/stack_d0_1"
    code, out, err = _run([*BASE, "--root", str(root), "--push-to-hub", "you/second"], capsys)
    assert code == 0 and "already complete" in out, err
    assert dict(hub.calls)["upload_folder"]["repo_id"] == "you/second"


def test_push_without_a_local_card_sends_one_and_writes_none(dataset, tmp_path, hub, capsys):
    """A dataset recorded before cards were written locally still gets one on the Hub, made in memory."""
    root = tmp_path / "old"
    shutil.copytree(dataset, root)
    (root / "README.md").unlink()
    before = _tree(root)
    assert _run(["push", str(root), "--to", "you/old"], capsys)[0] == 0
    card = dict(hub.calls)["upload_file"]
    assert card["path_in_repo"] == "README.md"
    assert b"0 `eef`, 1 `cube_a`, 2 `cube_b`" in card["path_or_fileobj"]
    assert _tree(root) == before


@pytest.mark.parametrize(
    "case, message",
    [
        ("no_token", "actionflow-record push needs Hugging Face credentials: run `hf auth login`"),
        ("offline", "actionflow-record push needs the network, but HF_HUB_OFFLINE is set"),
        ("missing", "no such folder"),
        ("not_a_dataset", "not a LeRobot dataset (no meta/info.json)"),
        ("interrupted", "the recording there was interrupted"),
        ("bad_repo", "argument --to: got 'you/a b'; expected a Hub repo id"),
    ],
)
def test_push_refusals_are_one_line_and_upload_nothing(case, message, dataset, tmp_path, hub, monkeypatch,
                                                        capsys):  # fmt: skip
    import huggingface_hub

    root, repo = dataset, "you/x"
    if case == "no_token":
        monkeypatch.setattr(huggingface_hub, "get_token", lambda: None)
    elif case == "offline":
        monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    elif case == "missing":
        root = tmp_path / "nothing"
    elif case == "not_a_dataset":
        root = tmp_path
    elif case == "interrupted":
        root = tmp_path / "copy"
        shutil.copytree(dataset, root)
        (root / "meta" / "actionflow_journal").mkdir()
        (root / "meta" / "actionflow_journal" / "7.npz").write_bytes(b"")
    else:
        repo = "you/a b"
    code, _, err = _run(["push", str(root), "--to", repo], capsys)
    assert code == 2 and message in err, err
    assert hub.calls == []


def test_a_failed_upload_is_one_line(dataset, hub, capsys):
    hub.fail_upload = True
    code, _, err = _run(["push", str(dataset), "--to", "you/x"], capsys)
    assert code == 1 and err.startswith("actionflow-record: error: uploading") and "no route" in err, err
