"""The trainers' safety: checkpoints are data, kills lose nothing, run folders stay one run,
and every flag is checked and explained. Most runs are in-process (tiny, ~1 s); the ones a
user would start from a shell are subprocesses."""

import dataclasses
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from test_runners import ROOT, TINY_TRAIN

from rwalk.cli import command, flags_of
from rwalk.rl import training
from rwalk.rl.checkpoints import (
    LOCK_NAME,
    CheckpointError,
    RunSetupError,
    check_rsl_rl,
    checkpoint_files,
    load_checkpoint,
    run_lock,
    save_checkpoint,
)
from rwalk.runners import train, train_torchrl

TINY = [*TINY_TRAIN, "--no-export"]


def tiny_train(log_dir: Path, *extra: str) -> None:
    train.main([*TINY, "--log-dir", str(log_dir), *extra])


def iterations(log_dir: Path) -> list[int]:
    return [it for it, _ in checkpoint_files(log_dir)]


@pytest.fixture(scope="module")
def run3(tmp_path_factory) -> Path:
    """A finished 3-iteration run (model_0.pt .. model_2.pt); copy it before changing it."""
    log_dir = tmp_path_factory.mktemp("run3")
    tiny_train(log_dir, "--max-iterations", "3")
    return log_dir


def copy_run(run: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(run, tmp_path / "run"))


class WritesAFile:
    """Unpickling this calls open(marker, "w"): a stand-in for any code a file could run."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return open, (str(self.marker), "w")


@pytest.fixture
def evil(tmp_path) -> tuple[Path, Path]:
    """(a .pt file whose loading with weights_only=False creates marker, marker)."""
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.pt"
    torch.save({"iter": 1, "actor_state_dict": WritesAFile(marker)}, path)
    return path, marker


# 1. --resume never runs code from the file -------------------------------------------------


def test_load_checkpoint_refuses_a_pickle_that_runs_code(evil):
    path, marker = evil
    with pytest.raises(CheckpointError, match=r"evil\.pt.*refused.*could run code"):
        load_checkpoint(path)
    assert not marker.exists()
    # The file really is hostile (so the check can fail): its pickle calls open(), read
    # from the opcodes without running them.
    assert ("GLOBAL", "io open") in _pickle_globals(path)


def _pickle_globals(path: Path) -> list[tuple[str, str]]:
    import pickletools
    import zipfile

    with zipfile.ZipFile(path) as archive:
        name = next(n for n in archive.namelist() if n.endswith("data.pkl"))
        ops = pickletools.genops(archive.read(name))
        return [(op.name, arg) for op, arg, _ in ops if op.name == "GLOBAL"]


def test_train_resume_from_a_hostile_file_runs_nothing_and_says_why(evil, tmp_path):
    path, marker = evil
    done = subprocess.run(
        [sys.executable, "-m", "rwalk.runners.train", *TINY, "--resume", str(path),
         "--log-dir", str(tmp_path / "logs")],
        cwd=ROOT, capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert not marker.exists()
    assert done.returncode != 0
    assert "rwalk.runners.train: error: checkpoint" in done.stderr
    assert str(path) in done.stderr and "refused" in done.stderr
    assert "Traceback" not in done.stderr
    assert not (tmp_path / "logs" / "exported").exists()


def test_rsl_rl_loading_refuses_a_torchrl_checkpoint(tmp_path):
    save_checkpoint({"trainer": "torchrl", "iteration": 2}, tmp_path / "torchrl_2.pt")
    with pytest.raises(CheckpointError, match=r"torchrl_2\.pt.*torchrl trainer"):
        check_rsl_rl(load_checkpoint(tmp_path / "torchrl_2.pt"), tmp_path / "torchrl_2.pt")


def test_rsl_rl_checkpoints_name_their_trainer(run3):
    assert load_checkpoint(run3 / "model_2.pt")["trainer"] == "rsl_rl"


# 2. a killed run loses nothing ---------------------------------------------------------------


def wait_for_new_checkpoint(log_dir: Path, process: subprocess.Popen, after: int) -> None:
    deadline = time.monotonic() + 90
    while max(iterations(log_dir), default=-1) <= after:
        assert process.poll() is None, "the training ended before it was killed"
        assert time.monotonic() < deadline, "no new checkpoint within 90 s"
        time.sleep(0.02)


def test_a_killed_run_leaves_only_loadable_checkpoints_and_resumes(tmp_path):
    rng = random.Random(0)
    log_dir = tmp_path / "run"
    endless = [*TINY, "--log-dir", str(log_dir), "--max-iterations", "100000"]
    command_line = [sys.executable, "-m", "rwalk.runners.train", *endless]
    for attempt in range(3):  # kill as the first checkpoint appears, then at random moments
        resume = ["--resume", str(log_dir)] if attempt else []
        newest = max(iterations(log_dir), default=-1)
        process = subprocess.Popen(
            [*command_line, *resume], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
        )
        wait_for_new_checkpoint(log_dir, process, after=newest)
        time.sleep(0.0 if attempt == 0 else rng.uniform(0.0, 0.4))
        process.send_signal(signal.SIGKILL)
        process.wait()
        found = checkpoint_files(log_dir)
        assert {path.name for _, path in found} == {p.name for p in log_dir.glob("model_*.pt")}
        for it, path in found:
            assert check_rsl_rl(load_checkpoint(path), path)["iter"] == it
        json.loads((log_dir / "config.json").read_text())
        assert (log_dir / LOCK_NAME).read_text().strip() == str(process.pid)  # now stale
    newest = max(iterations(log_dir))
    done = subprocess.run(
        [*command_line[:-1], str(newest + 2), "--resume", str(log_dir)],
        cwd=ROOT, capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert "taking over the stale lock" in done.stdout
    assert f"next iteration {newest + 1}" in done.stdout
    assert load_checkpoint(log_dir / f"model_{newest + 1}.pt")["iter"] == newest + 1
    assert not (log_dir / LOCK_NAME).exists()
    assert not list(log_dir.glob(".*.tmp"))


# 3. --resume takes a run folder ---------------------------------------------------------------


def test_resume_from_a_folder_skips_a_truncated_newest_checkpoint(run3, tmp_path, capsys):
    log_dir = copy_run(run3, tmp_path)
    data = (log_dir / "model_2.pt").read_bytes()
    (log_dir / "model_2.pt").write_bytes(data[: len(data) // 2])
    capsys.readouterr()
    tiny_train(log_dir, "--resume", str(log_dir), "--max-iterations", "4")
    out = capsys.readouterr().out
    assert "skipped model_2.pt: checkpoint" in out and "cannot be read" in out
    assert f"resumed from {log_dir / 'model_1.pt'}: next iteration 2" in out
    assert iterations(log_dir) == [0, 1, 2, 3]
    assert load_checkpoint(log_dir / "model_2.pt")["iter"] == 2  # rewritten, whole


def test_resume_from_a_folder_without_checkpoints_names_it(tmp_path):
    with pytest.raises(SystemExit, match=r"error: checkpoint '.*empty' not found"):
        tiny_train(tmp_path / "logs", "--resume", str(tmp_path / "empty"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit, match=r"error: no checkpoint model_<iteration>\.pt in .*empty"):
        tiny_train(tmp_path / "logs", "--resume", str(tmp_path / "empty"))


# 4. one run per folder: checkpoints and the lock -------------------------------------------


def test_a_folder_with_another_runs_checkpoints_is_refused(tmp_path):
    (tmp_path / "model_5.pt").write_bytes(b"another run")
    with pytest.raises(SystemExit, match=r"already holds another run's checkpoints.*--overwrite"):
        tiny_train(tmp_path, "--max-iterations", "1")
    assert (tmp_path / "model_5.pt").read_bytes() == b"another run"
    assert not (tmp_path / LOCK_NAME).exists()


def test_overwrite_replaces_the_old_run(tmp_path, capsys):
    (tmp_path / "model_5.pt").write_bytes(b"another run")
    (tmp_path / "events.out.tfevents.1.old").write_bytes(b"old curves")
    tiny_train(tmp_path, "--max-iterations", "1", "--overwrite")
    assert "--overwrite: deleted 1 checkpoints and 1 event files" in capsys.readouterr().out
    assert iterations(tmp_path) == [0]
    assert not (tmp_path / "events.out.tfevents.1.old").exists()


def test_resuming_an_older_checkpoint_in_its_folder_needs_overwrite(run3, tmp_path):
    log_dir = copy_run(run3, tmp_path)
    old = ["--resume", str(log_dir / "model_0.pt"), "--max-iterations", "2"]
    with pytest.raises(SystemExit, match=r"model_0\.pt is not the newest.*model_2\.pt"):
        tiny_train(log_dir, *old)
    tiny_train(log_dir, *old, "--overwrite")
    assert iterations(log_dir) == [0, 1]


def test_the_lock_holds_our_pid_and_refuses_a_second_holder(tmp_path):
    held = f"in use by another training \\(pid {os.getpid()}"
    with run_lock(tmp_path) as lock:
        assert lock.read_text().strip() == str(os.getpid())
        with pytest.raises(RunSetupError, match=held), run_lock(tmp_path):
            pass
        assert lock.read_text().strip() == str(os.getpid())
    assert not lock.exists()


def test_training_refuses_a_folder_a_running_process_holds(tmp_path):
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (tmp_path / LOCK_NAME).write_text(f"{holder.pid}\n")
        with pytest.raises(SystemExit, match=f"in use by another training \\(pid {holder.pid}"):
            tiny_train(tmp_path, "--max-iterations", "1")
        assert (tmp_path / LOCK_NAME).read_text().strip() == str(holder.pid)
        assert not iterations(tmp_path)
    finally:
        holder.kill()
        holder.wait()


def test_a_stale_lock_is_taken_over_and_removed_at_the_end(tmp_path, capsys):
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    (tmp_path / LOCK_NAME).write_text(gone.stdout)
    tiny_train(tmp_path, "--max-iterations", "1")
    assert f"taking over the stale lock {tmp_path / LOCK_NAME}" in capsys.readouterr().out
    assert iterations(tmp_path) == [0]
    assert not (tmp_path / LOCK_NAME).exists()


# 5. checkpoints at the multiples of --save-interval and at the end -----------------------------


def test_save_interval_saves_its_multiples_and_the_last_iteration(tmp_path):
    args = train.parse_args([*TINY, "--log-dir", str(tmp_path), "--max-iterations", "7",
                             "--save-interval", "3"])  # fmt: skip
    assert training.train(args).name == "model_6.pt"
    assert iterations(tmp_path) == [0, 3, 6]
    tiny_train(tmp_path, "--max-iterations", "9", "--save-interval", "3", "--resume", str(tmp_path))
    assert iterations(tmp_path) == [0, 3, 6, 8]
    # the default's stage at the model's physics (the last third, from iteration 5 of 7
    # here) starts within a checkpoint's chunk and saves nothing more
    staged = tmp_path / "staged"
    tiny_train(staged, "--max-iterations", "7", "--save-interval", "3")
    assert iterations(staged) == [0, 3, 6]
    for it, path in checkpoint_files(tmp_path):
        assert load_checkpoint(path)["iter"] == it


# 6. every numeric flag is checked when parsed -----------------------------------------------

BAD_FLAGS = [
    ("--save-interval", "0", "must be >= 1, got 0"),
    ("--max-iterations", "0", "must be >= 1, got 0"),
    ("--num-steps-per-env", "0", "must be >= 1, got 0"),
    ("--num-mini-batches", "0", "must be >= 1, got 0"),
    ("--num-envs", "0", "must be >= 1, got 0"),
    ("--num-learning-epochs", "0", "must be >= 1, got 0"),
    ("--reward-scale", "nan", "must be a finite number > 0, got nan"),
    ("--reward-scale", "inf", "must be a finite number > 0, got inf"),
    ("--reward-scale", "0", "must be a finite number > 0, got 0.0"),
    ("--learning-rate", "-0.001", "must be a finite number > 0, got -0.001"),
    ("--learning-rate", "nan", "must be a finite number > 0, got nan"),
    ("--max-minutes", "-1", "must be > 0, got -1.0"),
    ("--max-minutes", "nan", "must be > 0, got nan"),
    ("--gamma", "0", "must be in (0, 1], got 0.0"),
    ("--gamma", "1.5", "must be in (0, 1], got 1.5"),
    ("--entropy-coef", "-0.1", "must be >= 0, got -0.1"),
    ("--init-noise-std", "0", "must be a finite number > 0, got 0.0"),
    ("--threads", "-1", "must be >= 0, got -1"),
    ("--seed", "-1", "must be >= 0, got -1"),
]
TRAIN_ONLY = [
    ("--terrain-scale", "2", "must be in [0, 1], got 2.0"),
    ("--settle-pool-fraction", "0", "must be in (0, 1], got 0.0"),
    ("--max-episode-steps", "0", "must be >= 1, got 0"),
    ("--hidden-dims", "0", "must be sizes >= 1, got (0,)"),
    ("--logger", "neptune", "must be one of tensorboard, wandb, got 'neptune'"),
]
TORCHRL_ONLY = [
    ("--lmbda", "1.5", "must be in [0, 1], got 1.5"),
    ("--clip-epsilon", "0", "must be a finite number > 0, got 0.0"),
    ("--num-mini-batches", "9", "must be <= --num-envs * --num-steps-per-env = 8, got 9"),
]


@pytest.mark.parametrize(
    ("module", "flag", "value", "message"),
    [(train, *bad) for bad in BAD_FLAGS + TRAIN_ONLY]
    + [(train_torchrl, *bad) for bad in BAD_FLAGS]
    + [(train_torchrl, *bad) for bad in TORCHRL_ONLY],
)
def test_a_bad_flag_is_a_usage_error_naming_it(module, flag, value, message, capsys):
    small = ["--num-envs", "2", "--num-steps-per-env", "4"] if flag == "--num-mini-batches" else []
    world = ["--no-robust"] if flag == "--terrain-scale" else []  # the one rough world's
    with pytest.raises(SystemExit) as exit_:
        module.parse_args([*small, *world, flag, value])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert f": error: {flag} {message}" in err and err.count("\n") == 1


def test_the_defaults_are_valid():
    assert train.parse_args([]) == train.parse_args([]).resolved()
    train_torchrl.parse_args([])


# 7. a --resume that leaves nothing to train is an error ---------------------------------------


def test_resume_past_max_iterations_names_both_numbers(run3, tmp_path):
    state = load_checkpoint(run3 / "model_2.pt")
    save_checkpoint({**state, "iter": 5}, tmp_path / "model_5.pt")
    with pytest.raises(SystemExit) as exit_:
        train.main([*TINY_TRAIN, "--resume", str(tmp_path / "model_5.pt"),
                    "--max-iterations", "3", "--log-dir", str(tmp_path / "out")])  # fmt: skip
    message = str(exit_.value.code)
    assert "model_5.pt holds iteration 5" in message and "--max-iterations 3" in message
    assert "--max-iterations 7 or more" in message
    assert not (tmp_path / "out").exists()  # nothing written, nothing exported


def test_resume_with_the_other_training_kind_names_the_flag(run3, tmp_path):
    with pytest.raises(SystemExit) as exit_:
        train.main([*TINY, "--no-robust", "--resume", str(run3 / "model_2.pt"),
                    "--max-iterations", "5", "--log-dir", str(tmp_path / "out")])  # fmt: skip
    message = str(exit_.value.code)
    assert "trained with --robust" in message and "pass --robust to resume it" in message
    assert not (tmp_path / "out").exists()


def test_a_saved_run_without_the_robust_flag_trained_without_it():
    from rwalk.rl.legacy import TrainArgs, from_flags, migrate

    old = dataclasses.asdict(TrainArgs()) | {"curriculum_iterations": 0}
    del old["robust"]
    args = migrate({k: list(v) if isinstance(v, tuple) else v for k, v in old.items()})
    assert args.preset.robust is False and not args.env.varies
    assert args == from_flags(dataclasses.replace(TrainArgs(), robust=False))


# 8. one vocabulary ---------------------------------------------------------------------------


def test_both_trainers_share_the_names_of_shared_flags():
    shared = {
        "num_envs", "max_iterations", "num_steps_per_env", "num_learning_epochs",
        "num_mini_batches", "hidden_dims", "learning_rate", "gamma", "entropy_coef",
        "init_noise_std", "reward_scale", "settle_steps", "seed", "threads", "log_dir",
        "save_interval", "task",
    }  # fmt: skip
    for module in (train, train_torchrl):
        names = {flag[2:].replace("-", "_") for flag in flags_of(module.parse_args([]))}
        assert shared - {"settle_steps"} <= names, module
        assert "--settle-steps" in module.parse_training.__globals__["ALIASES"]


# 9, 10. --help: every flag explained, the usage line a real command ---------------------------


def help_entries(text: str) -> dict[str, str]:
    """Each flag's entry (its help and default) in a --help text."""
    entries: dict[str, str] = {}
    name = None
    for line in text.splitlines():
        stripped = line.strip("│ ").strip()
        inner = line.lstrip("│")
        if stripped.startswith("--") and len(inner) - len(inner.lstrip()) <= 2:  # a flag
            name, _, rest = stripped.partition(" ")
            name = name.rstrip(",")
            entries[name] = rest
        elif name and stripped and not stripped.startswith(("╰", "╭", "─")):
            entries[name] += " " + stripped
    return entries


@pytest.mark.parametrize("module", [train, train_torchrl])
def test_every_flag_has_help_and_its_default(module, monkeypatch, capsys):
    monkeypatch.setenv("COLUMNS", "90")
    # the parts the presets leave out are listed once named; the speed kernel's
    # (--env.shaping) is in the residual default's resolved record (its late stage)
    shown = ["--costs", "--env.shaping.tracking", "0"]
    with pytest.raises(SystemExit) as exit_:
        module.parse_args([*shown, "--help"])
    assert exit_.value.code == 0
    entries = help_entries(capsys.readouterr().out)
    flags = flags_of(module.parse_args(shown))
    assert set(flags) <= set(entries) | {f"--no-{f[2:]}" for f in flags}
    for flag in flags:
        text = entries.get(flag) or entries[f"--no-{flag[2:]}"]
        help_text = text.split("(default:")[0]
        assert "(default: " in text and len(help_text.split()) > 1, (flag, text)


def test_the_usage_line_names_the_console_script(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["/venv/bin/rwalk-train", "--help"])
    assert command("rwalk.runners.train") == "rwalk-train"
    monkeypatch.setattr(sys, "argv", ["/checkout/runners/train.py", "--help"])
    assert command("rwalk.runners.train") == "python -m rwalk.runners.train"


@pytest.mark.parametrize("module", ["runners.train", "runners.train_torchrl"])
def test_help_works_from_a_checkout(module):
    done = subprocess.run([sys.executable, "-m", module, "--help"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"usage: python -m rwalk.{module} [-h] ")
    assert "--num-envs INT" in done.stdout and "--max-iterations INT" in done.stdout


def test_atomic_writes_get_the_mode_of_a_plain_write(tmp_path):
    plain = tmp_path / "plain.bin"
    plain.write_bytes(b"x")
    atomic = save_checkpoint({"iter": 0}, tmp_path / "atomic.pt")
    assert atomic.stat().st_mode & 0o777 == plain.stat().st_mode & 0o777


def test_the_console_script_exits_0_after_training(tmp_path):
    # console scripts run sys.exit(main()): a returned Path would exit with status 1
    done = subprocess.run(
        [sys.executable, "-c", "import sys; from rwalk.runners.train import main; sys.exit(main())",
         *TINY, "--log-dir", str(tmp_path), "--max-iterations", "1"],
        cwd=ROOT, capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]


def test_the_time_budget_does_not_count_building_the_envs_as_an_iteration(tmp_path, monkeypatch):
    # A 30-minute run stopped after iteration 0: 1.4 minutes of env building were taken
    # for the time of one iteration, so 25 more looked like 37 minutes.
    clock = [0.0]
    monkeypatch.setattr(training.time, "perf_counter", lambda: clock[0])
    make_env, learn = training.make_env, training.SafeRunner.learn

    def slow_make_env(args, teacher=None):
        clock[0] += 100.0  # building takes 100 s
        return make_env(args, teacher)

    def learn_one_second_each(self, num_learning_iterations, **kwargs):
        clock[0] += 1.0 * num_learning_iterations
        return learn(self, num_learning_iterations, **kwargs)

    monkeypatch.setattr(training, "make_env", slow_make_env)
    monkeypatch.setattr(training.SafeRunner, "learn", learn_one_second_each)
    tiny_train(tmp_path, "--max-minutes", "5", "--max-iterations", "10", "--save-interval", "5")
    assert iterations(tmp_path) == [0, 5, 9]  # 110 s of a 300 s budget: every iteration ran


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["--task", "walk"],
            "unknown task 'walk'; known tasks: ['adaptive_gait', 'residual_walk']",
        ),
        (["--command-range", "0.3", "0.1"], "--command-range must be LOW HIGH"),
        (["--command-range", "0.1"], "--command-range must be a {None}|{FLOAT FLOAT}, got ['0.1']"),
        (
            ["--task", "adaptive_gait", "--start-spread", "2"],
            "--start-spread must be in [0, 1], got 2.0",
        ),
        (["--start-spread", "0.5"], "unrecognized argument '--start-spread'"),
        (
            ["--task", "adaptive_gait", "--env.schedule-stride", "nan"],
            "--env.schedule-stride must be finite, got nan",
        ),
        (
            ["--task", "adaptive_gait", "--env.schedule-window", "1", "2", "0", "0"],
            "--env.schedule-window must be 4 fractions in [0, 1]",
        ),
        (
            ["--student-nominal-physics-iterations", "-1"],
            "--student-nominal-physics-iterations must be >= 0, got -1",
        ),
        (
            ["--recipe", "plain", "--student-nominal-physics-iterations", "5"],
            "--student-nominal-physics-iterations 5 needs --student-iterations",
        ),
        (
            ["--task", "adaptive_gait", "--gait-action", "schedule", "--command-range", "0", "1"],
            "--gait-action 'schedule' needs forward target velocities (> 0 m/s); "
            "command_range (0.0, 1.0) asks for 0.0",
        ),
    ],
)
def test_bad_task_flags_are_usage_errors(argv, message, capsys):
    from rwalk.runners.train import parse_args

    with pytest.raises(SystemExit) as exit_info:
        parse_args(argv)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err
