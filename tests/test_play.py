"""rwalk-play: evaluations, its errors (named flags and files), help, progress lines."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from conftest import write_run

import rwalk.progress
from rwalk.evaluation import check_checkpoint
from rwalk.runners.play import command_name, parse_args, play

ROOT = Path(__file__).resolve().parents[1]
QUICK = ["--episodes", "2", "--max-steps", "10", "--settle-steps", "3"]


def run(*args: str, argv0: str | None = None, env: dict | None = None):
    """``python -m rwalk.runners.play ARGS``, or the console script's code when argv0 is given."""
    if argv0 is None:
        command = [sys.executable, "-m", "rwalk.runners.play", *args]
    else:  # what the rwalk-play script does
        code = (
            f"import sys; sys.argv[0] = {argv0!r}; "
            "from rwalk.runners.play import main; sys.exit(main())"
        )
        command = [sys.executable, "-c", code, *args]
    return subprocess.run(
        command, cwd=ROOT, capture_output=True, text=True, timeout=300, check=False,
        env={**os.environ, **(env or {})},
    )  # fmt: skip


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """An rsl-rl checkpoint and the config.json beside it, as rwalk-train writes them."""
    return write_run(tmp_path_factory.mktemp("run"))


def test_play_evaluates_the_base_gait_without_opengl(tmp_path):
    done = run(
        "--base-gait", "--episodes", "3", "--max-steps", "20", "--settle-steps", "5",
        "--video", str(tmp_path / "episode.mp4"), "--json", str(tmp_path / "eval.json"),
        argv0="/venv/bin/rwalk-play", env={"MUJOCO_GL": "disable"},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr  # the console script exits 0
    assert "no video: rendering is disabled (MUJOCO_GL='disable')" in done.stderr
    assert "| base gait | 3 |" in done.stdout
    row = json.loads((tmp_path / "eval.json").read_text())[0]
    assert row["episodes"] == 3 and 0.0 <= row["fall_rate"] <= 1.0
    assert not (tmp_path / "episode.mp4").exists()


def test_play_pairs_the_policy_with_the_base_gait_without_printing_the_network(checkpoint):
    done = run("--checkpoint", str(checkpoint), "--base-gait", *QUICK)
    assert done.returncode == 0, done.stderr
    assert "| base gait | 2 |" in done.stdout and "| policy model_0.pt | 2 |" in done.stdout
    assert "Actor Model" not in done.stdout and "Linear(" not in done.stdout


def test_play_names_a_missing_checkpoint():
    done = run("--checkpoint", "/nonexistent/model_9.pt")
    assert done.returncode == 2
    assert "--checkpoint: checkpoint '/nonexistent/model_9.pt' not found" in done.stderr
    assert "config.json" not in done.stderr


def test_play_says_which_trainer_wrote_a_torchrl_checkpoint(tmp_path, capsys):
    path = tmp_path / "torchrl_2.pt"
    layout = {"iteration": 2, "actor": {"w": torch.zeros(2)}, "critic": {}, "obs_norm": {}}
    torch.save(layout, path)  # as train_torchrl wrote them before the "trainer" key
    done = run("--checkpoint", str(path))
    assert done.returncode == 2
    assert f"checkpoint {str(path)!r} was written by rwalk-train-torchrl" in done.stderr
    torch.save({**layout, "trainer": "torchrl"}, path)
    with pytest.raises(ValueError, match="written by rwalk-train-torchrl; play evaluates rsl-rl"):
        check_checkpoint(path)
    torch.save({"trainer": "sb3"}, path)
    with pytest.raises(ValueError, match=r"an unknown trainer \('sb3'\)"):
        check_checkpoint(path)


def test_play_names_the_missing_config_beside_a_checkpoint(checkpoint, tmp_path):
    lone = tmp_path / "model_0.pt"
    lone.write_bytes(checkpoint.read_bytes())
    with pytest.raises(FileNotFoundError, match=r"config.json' not found.*model_0.pt"):
        check_checkpoint(lone)
    check_checkpoint(checkpoint)  # the complete run passes


@pytest.mark.parametrize(
    ("flag", "value"),
    [
        ("--episodes", "0"),
        ("--episodes", "two"),
        ("--max-steps", "-5"),
        ("--settle-steps", "-1"),
        ("--seed", "-1"),
        ("--terrain-scale", "nan"),
        ("--terrain-scale", "1.5"),
        ("--terrain-scale", "-0.1"),
        ("--video-seconds", "0"),
        ("--video-seconds", "inf"),
    ],
)
def test_play_rejects_bad_values_naming_the_flag(flag, value, capsys):
    with pytest.raises(SystemExit) as exit_info:
        parse_args(["--base-gait", flag, value])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert f": error: {flag} must be" in err and f"got {value}" in err.replace("'", "")
    assert err.count("\n") == 1


def test_play_help_shows_the_command_and_every_default():
    done = run("--help")
    assert done.returncode == 0
    assert done.stdout.startswith("usage: python -m rwalk.runners.play ")
    entries = [line.strip("│ ").strip() for line in done.stdout.splitlines()
               if line.startswith("│ --")]  # fmt: skip
    flags = [entry.split()[0].rstrip(",") for entry in entries]
    assert flags == [
        "--checkpoint", "--base-gait", "--task", "--command", "--episodes", "--seed",
        "--terrain-scale", "--max-steps", "--settle-steps", "--video", "--video-seconds",
        "--viewer", "--json", "--progress",
    ]  # fmt: skip
    text = " ".join(done.stdout.split("│ --checkpoint", 1)[1].split())
    assert text.count("(default:") == len(flags)


def test_usage_names_the_console_script(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["/venv/bin/rwalk-play"])
    assert command_name() == "rwalk-play"
    with pytest.raises(SystemExit):
        parse_args(["--episodes", "0"])
    assert capsys.readouterr().err.startswith("rwalk-play: error: --episodes must be >= 1")
    monkeypatch.setattr(sys, "argv", ["/repo/rwalk/runners/play.py"])
    assert command_name() == "python -m rwalk.runners.play"


def test_progress_lines_only_when_asked_or_on_a_terminal(monkeypatch, capsys):
    monkeypatch.setattr(rwalk.progress, "INTERVAL", 0.0)  # a line per update
    play(["--base-gait", *QUICK, "--progress"])
    err = capsys.readouterr().err
    assert "settling starts: " in err and " physics steps/s" in err
    assert re.search(r"evaluating base gait: 100%\|[^\r\n]*\| 10/10 \[", err), err
    play(["--base-gait", *QUICK])  # stderr is not a terminal here
    assert capsys.readouterr().err == ""
