"""What a hostile or careless user hands us: crafted checkpoints and config.json files, absurd
values and flags, broken lock files. Each case is a one-line error naming the file, field or
flag (exit status 2 for usage errors), never a traceback, a hang or an unbounded allocation."""

import dataclasses
import json
import math
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import torch

from rwalk import EnvConfig, Physics, Pushes, Randomization, TerrainLevels
from rwalk.core import Core
from rwalk.rl import checkpoints
from rwalk.rl.checkpoints import (
    LOCK_NAME,
    CheckpointError,
    RunSetupError,
    check_rsl_rl,
    load_checkpoint,
    run_lock,
    save_checkpoint,
)
from rwalk.rl.config import ConfigError, TrainArgs, load_saved_args
from rwalk.rl.legacy import from_flags

ROOT = Path(__file__).resolve().parents[1]
FLAT = "model/world_flat.xml"
LIMITS = "import resource; resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30)); "


def cli(module: str, *args: str, timeout: int = 120) -> subprocess.CompletedProcess:
    """``python -m module args`` under a 3 GiB address-space limit and a time limit: a
    command that tried to grow without bound or hang fails the test instead of the machine."""
    code = LIMITS + f"import runpy, sys; sys.argv[0] = {module!r}; "
    code += f"runpy.run_module({module!r}, run_name='__main__')"
    return subprocess.run([sys.executable, "-c", code, *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout, check=False)  # fmt: skip


def one_line_error(done: subprocess.CompletedProcess, *needles: str, status: int = 2) -> str:
    """The command failed with ``status`` and a short error naming every needle, no traceback."""
    err = done.stderr.strip()
    assert done.returncode == status, (done.returncode, err[-2000:])
    assert "Traceback" not in err, err[-2000:]
    last = err.splitlines()[-1]
    assert len(last) < 2000, len(last)
    for needle in needles:
        assert needle in last, (needle, last)
    return last


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory) -> Path:
    """A finished tiny rwalk-train run (model_0.pt, model_1.pt, config.json)."""
    folder = tmp_path_factory.mktemp("run")
    from rwalk.runners import train

    train.main(["--num-envs", "4", "--num-steps-per-env", "4", "--settle-steps", "2",
                "--max-episode-steps", "20", "--hidden-dims", "8", "--max-iterations", "2",
                "--save-interval", "1", "--no-export", "--recipe", "plain",
                "--log-dir", str(folder)])  # fmt: skip
    return folder


def crafted(tmp_path: Path, run_folder: Path, changes: dict, name: str = "model_1.pt") -> Path:
    """A copy of the run whose model_1.pt has ``changes`` written over its contents."""
    folder = tmp_path / "crafted"
    shutil.copytree(run_folder, folder)
    state = load_checkpoint(folder / name) | changes
    save_checkpoint(state, folder / name)
    return folder / name


# 1. memory from a tiny file ------------------------------------------------------------------


def test_a_memo_shared_trainer_value_is_never_expanded(tmp_path, run_folder):
    bomb: list = [0]
    for _ in range(60):  # 2^60 items once expanded, a few hundred bytes as a pickle
        bomb = [bomb, bomb]
    path = crafted(tmp_path, run_folder, {"trainer": bomb})
    assert path.stat().st_size < 1 << 20
    with pytest.raises(CheckpointError, match="written by the unknown trainer") as error:
        check_rsl_rl(load_checkpoint(path), path)
    assert len(str(error.value)) < 300
    done = cli("rwalk.runners.play", "--checkpoint", str(path), "--episodes", "1")
    one_line_error(done, "--checkpoint", "unknown trainer")


def with_pickle(tmp_path: Path, pickled: bytes) -> Path:
    """A torch checkpoint file whose data.pkl is ``pickled`` (written by hand: torch.save
    itself overflows the C stack on deep nesting)."""
    source = tmp_path / "source.pt"
    torch.save({"iter": 1}, source)
    path = tmp_path / "model_1.pt"
    with zipfile.ZipFile(source) as src, zipfile.ZipFile(path, "w") as dst:
        for entry in src.infolist():
            data = pickled if entry.filename.endswith("data.pkl") else src.read(entry)
            dst.writestr(entry.filename, data)
    return path


def test_a_deeply_nested_value_is_a_checkpoint_error(tmp_path, run_folder):
    # {"trainer": ((((...[]...)))) 100000 deep, "iter": 1}: tuples of one, built iteratively
    deep = b"\x80\x02}(X\x07\x00\x00\x00trainer]" + b"\x85" * 100_000
    path = with_pickle(tmp_path, deep + b"X\x04\x00\x00\x00iterK\x01u.")
    shutil.copy(run_folder / "config.json", tmp_path / "config.json")
    with pytest.raises(CheckpointError, match="unknown trainer"):
        check_rsl_rl(load_checkpoint(path), path)
    done = cli("rwalk.runners.play", "--checkpoint", str(path), "--episodes", "1")
    one_line_error(done, "--checkpoint", "unknown trainer")


def test_a_deflated_checkpoint_is_refused_before_it_unpacks(tmp_path, run_folder):
    plain = run_folder / "model_1.pt"
    packed = tmp_path / "model_1.pt"
    with zipfile.ZipFile(plain) as src, zipfile.ZipFile(packed, "w", zipfile.ZIP_DEFLATED) as dst:
        for entry in src.infolist():
            dst.writestr(entry.filename, src.read(entry))
    with pytest.raises(CheckpointError, match="compressed entries"):
        load_checkpoint(packed)


def test_the_unpacked_size_is_capped(monkeypatch, run_folder):
    monkeypatch.setattr(checkpoints, "MAX_CHECKPOINT_BYTES", 1000)
    with pytest.raises(CheckpointError, match="more than the limit of 1000"):
        load_checkpoint(run_folder / "model_1.pt")


def test_a_file_that_is_no_zip_is_refused(tmp_path):
    path = tmp_path / "model_0.pt"
    path.write_bytes(b"\x80\x02}q\x00." + b"x" * 100)  # a bare pickle (torch's legacy format)
    with pytest.raises(CheckpointError, match="not a torch checkpoint"):
        load_checkpoint(path)


# 4. config.json is data --------------------------------------------------------------------


BAD_CONFIGS = [
    ("{not json", "is not JSON"),
    ('{"env": {}}', 'no object "args"'),
    ('{"args": [1, 2]}', 'no object "args"'),
    ("[" * 100_000 + "]" * 100_000, "is not JSON"),
    ('{"args": {"reward_scale": NaN}}', "--reward-scale must be a finite number > 0, got nan"),
    ('{"args": {"command_range": [0.3, 0.1]}}', "--command-range must be LOW HIGH"),
    ('{"args": {"policy_obs": ["nope"]}}', "has no piece 'nope'"),
    ('{"args": {"hidden_dims": [200000000, 128]}}', "--hidden-dims must be at most 8 layers"),
    ('{"args": {"hidden_dims": [2e8, 128]}}', "--hidden-dims must be an int"),
    ('{"args": {"flux": 1}}', "unknown key 'flux'"),
    ('{"args": {"task": ["a"]}}', "--task must be a str"),
    ('{"trainer": "torchrl", "args": {}}', "run of the 'torchrl' trainer"),
]


@pytest.mark.parametrize(("text", "message"), BAD_CONFIGS)
def test_a_bad_config_json_is_named_field_by_field(tmp_path, text, message):
    path = tmp_path / "config.json"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"config\.json") as error:
        load_saved_args(path)
    assert message in str(error.value) and len(str(error.value)) < 2000


@pytest.mark.parametrize(("text", "message"), BAD_CONFIGS[:3] + BAD_CONFIGS[6:8])
def test_play_names_a_bad_config_json_in_one_line(tmp_path, run_folder, text, message):
    folder = tmp_path / "run"
    shutil.copytree(run_folder, folder)
    (folder / "config.json").write_text(text)
    done = cli("rwalk.runners.play", "--checkpoint", str(folder / "model_1.pt"))
    one_line_error(done, "--checkpoint", "config.json", message)


def test_a_config_json_of_other_models_is_a_one_line_error(tmp_path, run_folder):
    folder = tmp_path / "run"
    shutil.copytree(run_folder, folder)
    config = json.loads((folder / "config.json").read_text())
    config["train"]["hidden_dims"] = [16, 16]
    (folder / "config.json").write_text(json.dumps(config))
    done = cli("rwalk.runners.play", "--checkpoint", str(folder / "model_1.pt"))
    one_line_error(done, "--checkpoint", "does not fit this run's models")


def test_a_huge_config_json_is_read_no_further_than_the_cap(tmp_path):
    path = tmp_path / "config.json"
    path.write_text('{"args": {}, "pad": "' + "x" * (2 << 20) + '"}')
    with pytest.raises(ConfigError, match="larger than"):
        load_saved_args(path)


# 6. checkpoint fields -----------------------------------------------------------------------


def resume_refused(tmp_path: Path, path: Path) -> str:
    """rwalk-train --resume ``path`` (in this process): the one-line message it exits with,
    having written nothing."""
    from rwalk.runners import train

    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exit_:
        train.main(["--resume", str(path), "--log-dir", str(out), "--max-iterations", "5",
                    "--no-export"])  # fmt: skip
    assert not any(out.glob("model_*.pt"))  # nothing written, model_-4.pt least of all
    message = str(exit_.value.code)
    assert "\n" not in message and len(message) < 2000
    return message


@pytest.mark.parametrize("bad", [-5, 2.5, "2", math.nan, True, 10**12])
def test_a_bad_iteration_is_named(tmp_path, run_folder, bad):
    path = crafted(tmp_path, run_folder, {"iter": bad})
    with pytest.raises(CheckpointError, match="'iter' must be an iteration"):
        check_rsl_rl(load_checkpoint(path), path)
    assert "'iter' must be an iteration" in resume_refused(tmp_path, path)


@pytest.mark.parametrize(
    ("levels", "message"),
    [(torch.full((4,), math.nan), "integer tensor"), ([1, 2, 3, 4], "integer tensor"),
     (torch.zeros(4, dtype=torch.float64), "integer tensor")],
)  # fmt: skip
def test_bad_terrain_levels_in_a_checkpoint_are_named(tmp_path, run_folder, levels, message):
    path = crafted(tmp_path, run_folder, {"env_state": {"terrain_level": levels}})
    refused = resume_refused(tmp_path, path)
    assert "env_state" in refused and message in refused


def test_a_model_state_that_is_no_dict_of_tensors_is_named(tmp_path, run_folder):
    path = crafted(tmp_path, run_folder, {"actor_state_dict": {"w": [1.0, 2.0]}})
    with pytest.raises(CheckpointError, match="'actor_state_dict' must be a dict of named"):
        check_rsl_rl(load_checkpoint(path), path)


# 5. --resume takes the run's own flags ---------------------------------------------------------


def test_resume_takes_the_runs_task_and_refuses_contradicting_flags(tmp_path):
    from rwalk.runners import train

    folder = tmp_path / "adaptive"
    tiny = ["--num-envs", "4", "--num-steps-per-env", "4", "--settle-steps", "2",
            "--max-episode-steps", "20", "--save-interval", "1", "--no-export"]  # fmt: skip
    train.main([*tiny, "--task", "adaptive_gait", "--recipe", "plain", "--hidden-dims", "8",
                "--max-iterations", "1", "--log-dir", str(folder)])  # fmt: skip
    saved = json.loads((folder / "config.json").read_text())
    # No --task, no --hidden-dims: the run's own come back (it used to fail on the shapes).
    train.main([*tiny, "--resume", str(folder), "--max-iterations", "2", "--log-dir", str(folder)])
    again = json.loads((folder / "config.json").read_text())
    assert again["preset"]["task"] == "adaptive_gait" and again["train"]["hidden_dims"] == [8]
    assert (folder / "model_1.pt").is_file()
    with pytest.raises(SystemExit) as exit_:
        train.main([*tiny, "--resume", str(folder), "--max-iterations", "3",
                    "--log-dir", str(folder), "--hidden-dims", "16"])  # fmt: skip
    message = str(exit_.value.code)
    assert "--hidden-dims 8" in message and "not --hidden-dims 16" in message
    assert json.loads((folder / "config.json").read_text()) == again  # nothing overwritten
    assert saved["train"]["hidden_dims"] == [8]


# 8. values that overflow --------------------------------------------------------------------


def test_a_kick_interval_meant_as_never_never_kicks():
    core = Core(EnvConfig(model_path=FLAT, settle_steps=2, pushes=Pushes(interval=(1e30, 1e30))),
                3, seed=0)  # fmt: skip
    core.reset()
    for _ in range(20):
        core.step(torch.zeros(3, 12))
    assert core.pushes.done == 0


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: EnvConfig(command_range=(1e300, 1e300)), "EnvConfig.command_range"),
        (lambda: EnvConfig(command_range=(math.nan, math.nan)), "EnvConfig.command_range"),
        (lambda: EnvConfig(settle_steps=10**12), "EnvConfig.settle_steps must be at most"),
        (lambda: EnvConfig(max_episode_steps=10**30), "EnvConfig.max_episode_steps must be at"),
        (lambda: TerrainLevels(levels=10**6), "height samples"),
        (lambda: TerrainLevels(cell=1e-5), "height samples"),
        (lambda: TerrainLevels(tile_length=1e7), "height samples"),
        (lambda: TerrainLevels(recycle="no"), "recycle must be a bool"),
        (lambda: TerrainLevels(review=1.5), "review must be a fraction in .0, 1., got 1.5"),
        (lambda: TerrainLevels(review=math.nan), "review must be a fraction in .0, 1., got nan"),
        (lambda: Physics(iterations=10**12), "Physics.iterations must be at most"),
        (lambda: Physics(timestep="x"), "Physics.timestep must be a finite number"),
        (lambda: Physics(solver=["CG"]), "Physics.solver must be one of"),
        (lambda: Core(EnvConfig(), 10**9), "num_envs must be at most"),
    ],
)
def test_absurd_values_are_value_errors_naming_the_field(make, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        make()


def test_an_absurd_randomisation_is_named_when_settling_fails():
    lopsided = Randomization.nominal(com_offset=(0.3, 0.3), payload=(2.0, 2.0))
    core = Core(EnvConfig(model_path=FLAT, settle_steps=50, randomization=lopsided), 2, seed=0)
    with pytest.raises(RuntimeError, match=r"starts fell .*randomised physics .*com_offset"):
        core.reset()


# 9. flags and locks --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--command-range", "nan", "nan"], "--command-range must be LOW HIGH"),
        (["--command-range", "1e300", "1e300"], "--command-range must be speeds within"),
        (["--seed", str(2**64)], "--seed must be at most"),
        (["--max-episode-steps", str(10**30)], "--max-episode-steps must be at most"),
        (["--settle-steps", str(10**12)], "--settle-steps must be at most"),
        (["--hidden-dims", str(10**9)], "--hidden-dims must be at most"),
        (["--num-envs", str(10**9)], "--num-envs must be at most"),
        (["--policy-obs", "nope"], "--policy-obs: residual_walk has no piece 'nope'"),
        (["--log-dir", ""], "--log-dir must name a folder"),
    ],
)
def test_absurd_flags_are_usage_errors(flags, message, capsys):
    from rwalk.runners import train

    with pytest.raises(SystemExit) as exit_:
        train.parse_args(flags)
    assert exit_.value.code == 2 and message in capsys.readouterr().err


def test_a_usage_error_is_one_line_and_status_2():
    one_line_error(cli("rwalk.runners.train", "--settle-steps", str(10**12)), "--settle-steps")


def test_a_log_dir_that_is_a_file_is_named(tmp_path):
    (tmp_path / "file").write_text("x")
    done = cli("rwalk.runners.train", "--log-dir", str(tmp_path / "file"), "--num-envs", "2")
    one_line_error(done, "is not a folder", status=1)


@pytest.mark.parametrize("content", [str(2**31), str(2**70), "-1", "0", "garbage", ""])
def test_a_lock_naming_no_process_is_taken_over(tmp_path, content):
    (tmp_path / LOCK_NAME).write_text(content + "\n")
    taken = []
    with run_lock(tmp_path, report=taken.append):
        assert (tmp_path / LOCK_NAME).read_text().strip() == str(os.getpid())
    assert taken and not (tmp_path / LOCK_NAME).exists()


def test_a_lock_that_is_a_folder_is_named(tmp_path):
    (tmp_path / LOCK_NAME).mkdir()
    with pytest.raises(RunSetupError, match="is not a file"), run_lock(tmp_path):
        pass


def test_the_args_of_a_run_round_trip_through_its_config_json(tmp_path):
    args = dataclasses.replace(TrainArgs(), task="adaptive_gait", hidden_dims=(32, 16),
                               command_range=(0.05, 0.25), max_minutes=math.inf)  # fmt: skip
    path = tmp_path / "config.json"
    path.write_text(json.dumps({"args": dataclasses.asdict(args)}))
    assert load_saved_args(path) == from_flags(args)  # a schema-1 record, migrated


# 3. both trainers own their folders ----------------------------------------------------------

TORCHRL = ["--num-envs", "4", "--num-steps-per-env", "4", "--num-mini-batches", "2",
           "--settle-steps", "2", "--max-episode-steps", "20", "--hidden-dims", "8",
           "--save-interval", "1"]  # fmt: skip


def torchrl_main(*flags: str) -> None:
    from rwalk.runners import train_torchrl

    train_torchrl.main([*TORCHRL, *flags])


def test_the_torchrl_trainer_owns_its_folder_and_resumes(tmp_path, run_folder, capsys):
    folder = tmp_path / "torchrl"
    torchrl_main("--max-iterations", "1", "--log-dir", str(folder))
    config = (folder / "config.json").read_text()
    with pytest.raises(SystemExit, match="already holds another run's checkpoints"):
        torchrl_main("--max-iterations", "1", "--log-dir", str(folder))  # twice into one folder
    assert (folder / "config.json").read_text() == config  # nothing replaced
    torchrl_main("--resume", str(folder), "--max-iterations", "2", "--log-dir", str(folder))
    assert "resumed after iteration 1" in capsys.readouterr().out
    resumed = load_checkpoint(folder / "torchrl_2.pt")
    assert resumed["iteration"] == 2 and resumed["trainer"] == "torchrl"
    # into rwalk-train's run folder: refused, its files untouched
    other = tmp_path / "rsl"
    shutil.copytree(run_folder, other)
    before = {p.name: p.read_bytes() for p in other.iterdir() if p.is_file()}
    with pytest.raises(SystemExit, match="already holds another run's checkpoints"):
        torchrl_main("--max-iterations", "1", "--log-dir", str(other))
    assert {p.name: p.read_bytes() for p in other.iterdir() if p.is_file()} == before


def test_rsl_rl_tools_name_a_torchrl_folder_in_one_line(tmp_path):
    folder = tmp_path / "torchrl"
    torchrl_main("--max-iterations", "1", "--log-dir", str(folder))
    from rwalk.runners import train

    with pytest.raises(SystemExit, match=r"no checkpoint model_<iteration>\.pt"):
        train.main(["--resume", str(folder), "--log-dir", str(tmp_path / "out")])
    with pytest.raises(SystemExit, match="written by the torchrl trainer"):
        train.main(["--resume", str(folder / "torchrl_1.pt"), "--log-dir", str(tmp_path / "o")])
    done = cli("rwalk.runners.play", "--checkpoint", str(folder / "torchrl_1.pt"))
    one_line_error(done, "--checkpoint", "rwalk-train-torchrl")


def test_runners_end_input_errors_in_one_line(tmp_path, capsys):
    from rwalk.runners import play, robustness

    with pytest.raises(SystemExit) as exit_:
        play.main(["--base-gait", "--episodes", str(2**31 - 1)])
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and err.endswith(f"num_envs must be at most {1 << 24}, got "
                                                  f"{2**31 - 1}") and "\n" not in err  # fmt: skip
    (tmp_path / "out.json").mkdir()  # a folder where the results file should go
    with pytest.raises(SystemExit) as exit_:
        play.main(["--base-gait", "--episodes", "1", "--max-steps", "2", "--settle-steps", "1",
                   "--json", str(tmp_path / "out.json")])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "\n" not in err  # refused before evaluating, one line
    assert "error: --json" in err and "out.json" in err and "is a folder" in err
    (tmp_path / "bad.json").write_text('{"rows": [{"condition": "x", "policy": 3}]}')
    with pytest.raises(SystemExit) as exit_:
        robustness.main(["--tables", str(tmp_path / "bad.json")])
    assert (
        exit_.value.code == 2 and "needs the texts condition and policy" in capsys.readouterr().err
    )
