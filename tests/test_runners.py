"""The runner scripts, run as a user would (subprocesses, tiny budgets)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from rwalk.rl.checkpoints import load_checkpoint

ROOT = Path(__file__).resolve().parents[1]
TINY_TRAIN = [
    "--num-envs", "16", "--num-steps-per-env", "4", "--save-interval", "1",
    "--settle-steps", "2", "--settle-pool-fraction", "0.5", "--max-episode-steps", "30",
    "--hidden-dims", "16", "16", "--recipe", "plain",
]  # fmt: skip


def run(*args: str, env: dict | None = None, timeout: int = 600) -> str:
    done = subprocess.run(
        [sys.executable, "-m", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, **(env or {})},
        check=False,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done.stdout + done.stderr


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    log_dir = tmp_path_factory.mktemp("train")
    out = run(
        "rwalk.runners.train", *TINY_TRAIN, "--max-iterations", "2", "--log-dir", str(log_dir)
    )
    assert "[rwalk] iteration 2/2" in out and "ETA" in out
    return log_dir


def test_train_writes_checkpoints_logs_config_and_exports(trained):
    assert (trained / "model_1.pt").is_file()
    assert load_checkpoint(trained / "model_1.pt")["iter"] == 1
    assert list(trained.glob("events.out.tfevents.*"))
    config = json.loads((trained / "config.json").read_text())
    assert config["num_envs"] == 16 and config["env"]["settle_pool"] == 8
    assert (trained / "exported" / "policy.pt").is_file()
    assert (trained / "exported" / "policy.onnx").is_file()


def test_tensorboard_has_every_reward_term(trained):
    from rwalk.rewards import TERM_NAMES
    from rwalk.tensorboard_events import read_scalars

    tags = set(read_scalars(trained))
    expected = {f"Episode_Reward/{term}" for term in TERM_NAMES} | {
        "Episode/length", "Episode/fall_rate", "Episode/forward_velocity", "Train/mean_reward",
    }  # fmt: skip
    assert expected <= tags


def test_resume_continues_the_iteration_count(trained, tmp_path):
    out = run(
        "rwalk.runners.train", *TINY_TRAIN, "--max-iterations", "4", "--log-dir", str(tmp_path),
        "--resume", str(trained / "model_1.pt"), "--no-export",
    )  # fmt: skip
    assert "next iteration 2" in out
    assert load_checkpoint(tmp_path / "model_3.pt")["iter"] == 3
    assert not (tmp_path / "model_0.pt").exists() and not (tmp_path / "model_1.pt").exists()


def test_exported_policies_act_like_the_checkpoint(trained):
    from rwalk import ResidualWalkVecEnv
    from rwalk.evaluation import load_policy
    from rwalk.presets import evaluation_config as eval_config
    from rwalk.wrappers import RslRlVecEnv

    env = ResidualWalkVecEnv(4, eval_config(settle_steps=3), seed=0)
    env.core.reset()
    act = load_policy(trained / "model_1.pt", env)
    layout = json.loads((trained / "exported" / "policy.json").read_text())
    pieces = tuple(piece["name"] for piece in layout["input"]["pieces"])
    assert pieces[0] == "observation_from_start"  # a robust run's policy (the default)
    obs = RslRlVecEnv(env, policy_obs=pieces).get_observations()["policy"]
    expected = act()
    # Training moved the zero-initialised output layer: the actions are not trivially 0.
    assert expected.abs().max() > 1e-4
    jit = torch.jit.load(str(trained / "exported" / "policy.pt"))
    torch.testing.assert_close(jit(obs), expected, rtol=1e-5, atol=1e-8)

    import onnxruntime

    session = onnxruntime.InferenceSession(str(trained / "exported" / "policy.onnx"))
    name = session.get_inputs()[0].name  # rsl-rl exports a batch of one
    onnx_actions = np.concatenate([session.run(None, {name: row[None]})[0] for row in obs.numpy()])
    np.testing.assert_allclose(onnx_actions, expected.numpy(), rtol=1e-4, atol=1e-7)


def test_play_pairs_the_policy_with_the_base_gait(trained):
    out = run(
        "rwalk.runners.play", "--checkpoint", str(trained / "model_1.pt"), "--base-gait",
        "--episodes", "2", "--max-steps", "15", "--settle-steps", "3",
    )  # fmt: skip
    assert "| base gait | 2 |" in out and "| policy model_1.pt | 2 |" in out


def _gl_works() -> bool:
    probe = (
        "from rwalk.render import gl_available; import sys; sys.exit(0 if gl_available()[0] else 1)"
    )
    done = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, check=False)
    return done.returncode == 0


@pytest.mark.skipif(not _gl_works(), reason="no OpenGL backend (apt-get install libosmesa6)")
def test_play_films_an_episode(tmp_path):
    video = tmp_path / "episode.gif"
    run(
        "rwalk.runners.play", "--base-gait", "--episodes", "1", "--max-steps", "20",
        "--settle-steps", "2", "--video", str(video), "--video-seconds", "0.2",
    )  # fmt: skip
    import imageio.v3 as iio

    frames = iio.imread(video)
    assert frames.shape[0] >= 4 and frames.shape[-1] in (3, 4)
    assert frames.std() > 5  # not a blank image


@pytest.mark.parametrize(("task", "actions"), [("residual_walk", 12), ("adaptive_gait", 16)])
def test_train_torchrl_runs_two_iterations(tmp_path, task, actions):
    out = run(
        "rwalk.runners.train_torchrl", "--num-envs", "8", "--max-iterations", "2",
        "--num-steps-per-env", "8", "--num-mini-batches", "2", "--settle-steps", "2",
        "--hidden-dims", "16", "16", "--log-dir", str(tmp_path), "--task", task,
    )  # fmt: skip
    assert "[torchrl] iteration 2/2" in out
    saved = load_checkpoint(tmp_path / "torchrl_2.pt")
    assert saved["iteration"] == 2 and "actor" in saved and saved["trainer"] == "torchrl"
    assert saved["actor"]["module.0.module.0.0.weight"].shape[0] == 16
    weights = [v for k, v in saved["actor"].items() if k.endswith("weight")]
    assert weights[-1].shape[0] == 2 * actions  # loc and scale of each action
    assert json.loads((tmp_path / "config.json").read_text())["run"]["max_iterations"] == 2
    assert saved["groups"]["critic"][-2:] == ["physics", "heights"]  # the robust world's


def test_plot_training_draws_the_curves_with_the_base_gait(trained, tmp_path):
    from rwalk.tensorboard_events import read_scalars

    series = read_scalars(trained)
    assert [step for step, _, _ in series["Train/mean_reward"]] == [0, 1]
    assert "Episode/forward_velocity" in series
    base = tmp_path / "eval.json"
    base.write_text(json.dumps([{"name": "base gait", "forward_velocity": 0.1, "mean_length": 9}]))
    out = tmp_path / "curve.png"
    run(
        "rwalk.runners.plot_training",
        str(trained),
        "--out",
        str(out),
        "--base-gait-json",
        str(base),
    )
    import imageio.v3 as iio

    image = iio.imread(out)
    assert image.shape[0] > 300 and image.std() > 5


def test_plot_training_overlays_runs_by_iteration(trained, tmp_path):
    from rwalk.runners.plot_training import main

    out = tmp_path / "curves.png"
    main([str(trained), str(trained), "--by-iteration", "--title", "two", "--out", str(out)])
    import imageio.v3 as iio

    assert iio.imread(out).std() > 5


def test_walk_demo_prints_the_speed():
    out = run("rwalk.runners.walk_demo", "--envs", "2", "--seconds", "1")
    assert "forward speed" in out and "expected 0.1333" in out


def test_the_walk_demo_console_script_exits_0():
    # console scripts run sys.exit(main()): a returned summary would exit with status 1
    done = subprocess.run(
        [sys.executable, "-c", "import sys; from rwalk.runners.walk_demo import main; "
         "sys.exit(main())", "--envs", "1", "--seconds", "0.1"],
        cwd=ROOT, capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert "forward speed" in done.stdout


#: The runners whose command lines come from their ``Args`` dataclass (beside train and play).
RUNNERS = ("sim2sim", "robustness", "base_gait_report", "fidelity", "adaptive_report", "average",
           "single_bench", "walk_demo", "bench", "plot_training")  # fmt: skip


@pytest.mark.parametrize("name", RUNNERS)
def test_every_runner_flag_has_help_and_its_default(name, monkeypatch, capsys):
    import dataclasses
    import importlib
    import typing

    from rwalk.validation import flag

    module = importlib.import_module(f"rwalk.runners.{name}")
    args = typing.get_type_hints(module.parse_args)["return"]
    monkeypatch.setenv("COLUMNS", "90")
    with pytest.raises(SystemExit) as exit_:
        module.parse_args(["--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith(f"usage: python -m rwalk.runners.{name} [-h] ")  # the command
    assert module.__doc__.splitlines()[0] in text  # the description
    entries: dict[str, str] = {}
    entry = None
    for line in text.split("options", 1)[1].splitlines():
        line = line.strip("│ ").strip()
        if line.startswith("--"):
            entry, _, rest = line.partition(" ")
            entry = entry.rstrip(",")
            entries[entry] = rest
        elif entry and line and not line.startswith(("╰", "╭", "─")):
            entries[entry] += " " + line
    hints = typing.get_type_hints(args, include_extras=True)
    for field in dataclasses.fields(args):
        if "Positional" in repr(hints[field.name]):
            assert f" {field.name.upper()}" in text.splitlines()[0], field.name  # usage line
            continue
        entry = " ".join(entries[flag(field.name)].split())
        assert "(default: " in entry or "(repeatable)" in entry, (field.name, entry)
        assert len(entry.split("(default:")[0].split()) > 1, (field.name, entry)  # a help text


def test_plot_training_puts_runs_at_their_measured_paces(trained, tmp_path, monkeypatch, capsys):
    import matplotlib.axes

    from rwalk.runners.plot_training import main

    drawn = []
    original = matplotlib.axes.Axes.plot

    def plot(self, x, *args, **kwargs):
        drawn.append(list(x))
        return original(self, x, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", plot)
    main([str(trained), "--paces", "3", "--out", str(tmp_path / "p.png")])
    assert drawn and all(x == [0.0, 0.05] for x in drawn)  # iterations 0, 1 at 3 s each
    with pytest.raises(SystemExit) as exit_:
        main([str(trained), str(trained), "--paces", "3", "--out", str(tmp_path / "q.png")])
    assert exit_.value.code == 2 and "--paces needs one number" in capsys.readouterr().err


def test_average_writes_the_mean_policy_beside_the_run_and_resume_ignores_it(trained, capsys):
    from rwalk.rl.checkpoints import checkpoint_files
    from rwalk.runners.average import main

    main([str(trained), "--first", "0", "--last", "1"])
    out = trained / "average_0-1.pt"
    assert f"wrote {out}: the policy averaged over iterations 0, 1" in capsys.readouterr().out
    mean, first, last = (load_checkpoint(p) for p in (out, trained / "model_0.pt",
                                                      trained / "model_1.pt"))  # fmt: skip
    assert mean["averaged"] == [0, 1] and mean["iter"] == 1
    actors = first["actor_state_dict"], last["actor_state_dict"]
    assert any(not torch.equal(actors[0][name], actors[1][name]) for name in actors[1])
    for name, tensor in mean["actor_state_dict"].items():
        if name.startswith("obs_normalizer."):
            assert torch.equal(tensor, last["actor_state_dict"][name]), name
        else:
            pair = [run["actor_state_dict"][name].double() for run in (first, last)]
            assert torch.equal(tensor, ((pair[0] + pair[1]) / 2).float()), name
    for name, tensor in mean["critic_state_dict"].items():
        assert torch.equal(tensor, last["critic_state_dict"][name]), name
    assert [it for it, _ in checkpoint_files(trained)] == [0, 1]  # --resume takes model_1
    out.unlink()


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--out", "sub/x.pt"], "--out must be a file name ending in .pt, without a folder"),
        (["--out", "model_7.pt"], "that is not a checkpoint's (model_<it>.pt), got 'model_7.pt'"),
        (["--first", "-1"], "--first must be >= 0, got -1"),
        (["--first", "1", "--last", "0"], "--last (0) must be >= --first (1)"),
        (["--first", "1"], "holds 1 checkpoint(s) of iterations 1-1 (its iterations: 0, 1)"),
    ],
)
def test_average_refuses_bad_input_in_one_line(trained, capsys, argv, message):
    from rwalk.runners.average import main

    with pytest.raises(SystemExit) as exit_:
        main([str(trained), *argv])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and message in err and err.count("\n") == 1, err
    assert not list(trained.glob("average_*")) and not list(trained.glob("x.pt"))


def test_average_names_a_folder_that_is_not_a_run(tmp_path, capsys):
    from rwalk.runners.average import main

    with pytest.raises(SystemExit) as exit_:
        main([str(tmp_path)])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and f"RUN: {str(tmp_path)!r} holds no config.json" in err
