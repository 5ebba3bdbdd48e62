"""One training over several processes (rwalk.runners.distributed): 2 ranks under torchrun
train one policy, rank 0 alone writes the run, every rank holds the same parameters after
every update, and a group that cannot train ends with a message instead of a hang.

The runs are subprocesses of 2 ranks x 8 tiny envs, as a user would start them: torchrun
(``python -m torch.distributed.run``), or the 2 processes started here with the variables
torchrun would set, when the ranks need different flags."""

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from test_runners import ROOT, TINY_TRAIN

from rwalk.rl import distributed
from rwalk.rl.checkpoints import LOCK_NAME, checkpoint_files, load_checkpoint
from rwalk.runners import train

TINY = [*TINY_TRAIN, "--num-envs", "8", "--no-export"]
"""2 ranks x 8 envs, 4 steps per iteration, 2 settle steps, 30-step episodes."""
TORCHRUN = [sys.executable, "-m", "torch.distributed.run"]
TRAIN = [sys.executable, "-m", "rwalk.runners.train"]
GROUP_VARIABLES = (
    *("RANK", "LOCAL_RANK", "WORLD_SIZE", "LOCAL_WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT"),
    *("TORCHELASTIC_RUN_ID", distributed.PARAMETER_HASHES_ENV),
)


def environment(**extra: str) -> dict[str, str]:
    """This checkout's rwalk for every rank, whatever its folder; no inherited group."""
    env = {k: v for k, v in os.environ.items() if k not in GROUP_VARIABLES}
    return env | {"PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"} | extra


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def run(command: list[str], timeout: float = 240, **extra: str) -> tuple[int, str]:
    done = subprocess.run(command, cwd=ROOT, env=environment(**extra), capture_output=True,
                          text=True, timeout=timeout, check=False)  # fmt: skip
    return done.returncode, done.stdout + done.stderr


def start_ranks(*argvs: list[str], **extra: str) -> list[subprocess.Popen]:
    """One process per argv, rank r getting argvs[r]: what torchrun would start on one machine."""
    port = free_port()
    ranks = []
    for rank, argv in enumerate(argvs):
        group = {"RANK": str(rank), "LOCAL_RANK": str(rank), "WORLD_SIZE": str(len(argvs)),
                 "LOCAL_WORLD_SIZE": str(len(argvs)), "MASTER_ADDR": "127.0.0.1",
                 "MASTER_PORT": str(port)}  # fmt: skip
        env = environment(**group, **extra)
        ranks.append(subprocess.Popen([*TRAIN, *argv], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True))  # fmt: skip
    return ranks


def finish(ranks: list[subprocess.Popen], timeout: float = 120) -> list[tuple[int, str]]:
    try:
        outputs = [rank.communicate(timeout=timeout)[0] for rank in ranks]
        return [(rank.returncode, out) for rank, out in zip(ranks, outputs, strict=True)]
    finally:
        for rank in ranks:
            if rank.poll() is None:
                rank.kill()
                rank.wait()


def hashes(folder: Path, rank: int) -> list[tuple[int, str]]:
    """(iteration, hash of the actor and critic state) after each update of ``rank``."""
    lines = (folder / f"rank{rank}.txt").read_text().split()
    return [(int(it), digest) for it, digest in zip(lines[::2], lines[1::2], strict=True)]


@pytest.fixture(scope="module")
def two_ranks(tmp_path_factory) -> tuple[Path, str]:
    """(folder, output) of a finished 2-rank torchrun training of 2 iterations with
    exports, rank r in folder/rank<r> with --log-dir run (so any write by rank 1 would land
    in rank1/run), parameter hashes in folder/hashes."""
    folder = tmp_path_factory.mktemp("ddp")
    for rank in (0, 1):
        (folder / f"rank{rank}").mkdir()
    in_own_folder = 'cd "$0/rank$LOCAL_RANK" && exec "$1" -m rwalk.runners.train "${@:2}"'
    code, out = run(
        [*TORCHRUN, "--standalone", "--nproc-per-node", "2", "--no-python",
         "bash", "-c", in_own_folder, str(folder), sys.executable,
         *TINY, "--export", "--max-iterations", "2", "--log-dir", "run"],
        **{distributed.PARAMETER_HASHES_ENV: str(folder / "hashes")},
    )  # fmt: skip
    assert code == 0, out[-4000:]
    return folder, out


# (a) a 2-rank run finishes; rank 0 alone writes ------------------------------------------------
def test_two_ranks_train_and_rank_0_alone_writes_the_run(two_ranks):
    folder, out = two_ranks
    run = folder / "rank0" / "run"
    assert [it for it, _ in checkpoint_files(run)] == [0, 1]
    assert load_checkpoint(run / "model_1.pt")["iter"] == 1
    assert (run / "config.json").is_file() and list(run.glob("events.out.tfevents.*"))
    assert (run / "exported" / "policy.onnx").is_file()
    assert not (run / LOCK_NAME).exists()
    assert not list((folder / "rank1").iterdir()), "rank 1 wrote to its run folder"
    assert "rank 0 of 2" in out and "rank 1 of 2" in out
    assert out.count("[rwalk] iteration 2/2") == 1  # rank 0 speaks for the group


def test_each_rank_has_its_own_seed_stream_and_share_of_the_cores(two_ranks):
    _, out = two_ranks
    threads = distributed.default_threads(distributed.Group(1, 1, 2, 2))
    stride = 8 + 4  # 8 envs and their settled-start pool of 4 (--settle-pool-fraction 0.5)
    assert f"8 envs seeded from 0, {threads} threads" in out
    assert f"8 envs seeded from {stride}, {threads} threads" in out


# (b) the same policy on every rank after every update ------------------------------------------
def test_all_ranks_hold_bit_identical_parameters_after_every_update(two_ranks):
    folder, _ = two_ranks
    rank0, rank1 = hashes(folder / "hashes", 0), hashes(folder / "hashes", 1)
    assert [it for it, _ in rank0] == [0, 1]
    assert rank0 == rank1
    assert rank0[0][1] != rank0[1][1]  # the updates changed the parameters


# (e) --resume continues the whole group from rank 0's checkpoint --------------------------------
def test_resume_continues_every_rank_from_rank_0s_checkpoint(two_ranks, tmp_path):
    # started the way each machine of a multi-machine training is (static rendezvous)
    run_dir = Path(shutil.copytree(two_ranks[0] / "rank0" / "run", tmp_path / "run"))
    port = free_port()
    code, out = run(
        [*TORCHRUN, "--nnodes", "1", "--node-rank", "0", "--rdzv-endpoint", f"127.0.0.1:{port}",
         "--nproc-per-node", "2",
         "-m", "rwalk.runners.train", *TINY, "--max-iterations", "4",
         "--log-dir", str(run_dir), "--resume", str(run_dir)],
        **{distributed.PARAMETER_HASHES_ENV: str(tmp_path / "hashes")},
    )  # fmt: skip
    assert code == 0, out[-4000:]
    assert out.count("next iteration 2") == 1
    assert [it for it, _ in checkpoint_files(run_dir)] == [0, 1, 2, 3]
    assert load_checkpoint(run_dir / "model_3.pt")["iter"] == 3
    # rank 1 loaded the optimiser's state too: else its Adam steps would differ from rank 0's
    rank0, rank1 = hashes(tmp_path / "hashes", 0), hashes(tmp_path / "hashes", 1)
    assert [it for it, _ in rank0] == [2, 3] and rank0 == rank1


def test_a_warm_start_starts_every_rank_from_rank_0s_file(two_ranks, tmp_path):
    source = two_ranks[0] / "rank0" / "run"
    code, out = run(
        [*TORCHRUN, "--standalone", "--nproc-per-node", "2", "-m", "rwalk.runners.train",
         *TINY, "--max-iterations", "1", "--log-dir", str(tmp_path / "run"),
         "--warm-start", str(source)],
        **{distributed.PARAMETER_HASHES_ENV: str(tmp_path / "hashes")},
    )  # fmt: skip
    assert code == 0, out[-4000:]
    assert out.count(f"warm start from {source / 'model_1.pt'}") == 1
    rank0, rank1 = hashes(tmp_path / "hashes", 0), hashes(tmp_path / "hashes", 1)
    assert [it for it, _ in rank0] == [0] and rank0 == rank1
    assert rank0 != hashes(two_ranks[0] / "hashes", 0)[:1]  # not a fresh start's update


def test_the_default_recipe_trains_its_teacher_then_its_student_over_two_ranks(tmp_path):
    precise = [flag for flag in TINY if flag not in ("--recipe", "plain")]
    run_dir = tmp_path / "run"
    code, out = run(
        [*TORCHRUN, "--standalone", "--nproc-per-node", "2", "-m", "rwalk.runners.train",
         *precise, "--max-iterations", "2", "--student-iterations", "2",
         "--log-dir", str(run_dir)],
        **{distributed.PARAMETER_HASHES_ENV: str(tmp_path / "hashes")},
    )  # fmt: skip
    assert code == 0, out[-4000:]
    assert [it for it, _ in checkpoint_files(run_dir)] == [0, 1]
    assert [it for it, _ in checkpoint_files(run_dir / "student")] == [0, 1]
    assert "student_state_dict" in load_checkpoint(run_dir / "student" / "model_1.pt")
    rank0, rank1 = hashes(tmp_path / "hashes", 0), hashes(tmp_path / "hashes", 1)
    assert [it for it, _ in rank0] == [0, 1, 0, 1] and rank0 == rank1  # teacher, then student


# (c) ranks that differ refuse to start; rank 0's setup errors reach every rank ------------------
def test_ranks_with_different_flags_refuse_to_start_naming_the_rank_and_flag(tmp_path):
    argv = [*TINY, "--max-iterations", "2", "--log-dir", str(tmp_path / "run")]
    results = finish(start_ranks(argv, [*argv, "--gamma", "0.98"]))
    for rank, (code, out) in enumerate(results):
        assert code == 1, out[-3000:]
        assert f"rank {rank} of 2: the ranks were started with different settings" in out
        assert "rank 1 has --gamma 0.98 (rank 0: 0.99)" in out
    assert not (tmp_path / "run").exists()  # refused before anything was written


def test_ranks_may_differ_in_threads_and_stop_together_at_the_time_budget(tmp_path):
    # Each rank's own clock could stop it one chunk apart from the others, and the one
    # that trains on would wait for ever: the stop is rank 0's, broadcast.
    argv = [*TINY, "--max-iterations", "100000", "--max-minutes", "0.001",
            "--log-dir", str(tmp_path / "run")]  # fmt: skip
    results = finish(start_ranks([*argv, "--threads", "1"], [*argv, "--threads", "2"]))
    assert [code for code, _ in results] == [0, 0], results[0][1][-3000:] + results[1][1][-3000:]
    assert "1 threads" in results[0][1] and "2 threads" in results[1][1]
    assert "stopping: the 0.001-minute budget is reached" in results[0][1]
    assert [it for it, _ in checkpoint_files(tmp_path / "run")] == [0]


def test_rank_0s_setup_error_ends_every_rank_with_its_message(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "model_0.pt").write_bytes(b"another run's")
    argv = [*TINY, "--max-iterations", "2", "--log-dir", str(tmp_path / "run")]
    for code, out in finish(start_ranks(argv, argv)):
        assert code == 1, out[-3000:]
        assert "already holds another run's checkpoints (model_0.pt" in out


def test_torchrun_variables_that_make_no_group_are_named():
    assert distributed.Group.from_env({}) == distributed.Group()
    assert not distributed.Group.from_env({"WORLD_SIZE": "1", "RANK": "0"}).distributed
    with pytest.raises(distributed.GroupError, match=r"RANK is not set.*torchrun"):
        distributed.Group.from_env({"WORLD_SIZE": "2"})
    bad = {"WORLD_SIZE": "2", "RANK": "2", "LOCAL_RANK": "0", "LOCAL_WORLD_SIZE": "2"}
    with pytest.raises(distributed.GroupError, match=r"RANK must be in \[0, WORLD_SIZE=2\), got 2"):
        distributed.Group.from_env(bad)
    with pytest.raises(distributed.GroupError, match="LOCAL_RANK must be an integer, got 'x'"):
        distributed.Group.from_env(bad | {"RANK": "1", "LOCAL_RANK": "x"})


def test_one_process_sets_up_no_group(tmp_path, monkeypatch):
    import torch.distributed as dist

    for name in GROUP_VARIABLES:
        monkeypatch.delenv(name, raising=False)

    def refuse(*args, **kwargs):
        raise AssertionError("a single process joined a process group")

    monkeypatch.setattr(dist, "init_process_group", refuse)
    train.main([*TINY, "--max-iterations", "1", "--log-dir", str(tmp_path)])
    assert not dist.is_initialized()
    assert load_checkpoint(tmp_path / "model_0.pt")["iter"] == 0


# (d) a rank that dies or hangs ends the group with a message, no hang --------------------------
def start_endless_torchrun(log_dir: Path, timeout_s: int) -> tuple[subprocess.Popen, list[str]]:
    """A 2-rank training that would run for ever, and its output lines as they come."""
    torchrun = subprocess.Popen(
        [*TORCHRUN, "--standalone", "--nproc-per-node", "2", "-m", "rwalk.runners.train",
         *TINY, "--max-iterations", "100000", "--log-dir", str(log_dir),
         "--dist-timeout", str(timeout_s)],
        cwd=ROOT, env=environment(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(torchrun.stdout), daemon=True).start()  # type: ignore[arg-type]
    return torchrun, lines


def end_everything(torchrun: subprocess.Popen, lines: list[str]) -> None:
    """Kill torchrun and the ranks it started (their pids are in its output), stopped or not."""
    if torchrun.poll() is None:
        torchrun.kill()
        torchrun.wait()
    for line in list(lines):
        if " of 2 (pid " in line:
            pid = int(line.split("(pid ")[1].split(")")[0])
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGCONT)
                os.kill(pid, signal.SIGKILL)


def rank_pid(lines: list[str], rank: int, torchrun: subprocess.Popen, log_dir: Path) -> int:
    """The pid of ``rank`` once the group has trained an iteration (model_0.pt exists)."""
    deadline = time.monotonic() + 120
    while not (log_dir / "model_0.pt").exists():
        assert torchrun.poll() is None, "".join(lines)[-4000:]
        assert time.monotonic() < deadline, "no checkpoint within 120 s"
        time.sleep(0.05)
    line = next(line for line in lines if f"rank {rank} of 2 (pid " in line)
    return int(line.split("(pid ")[1].split(")")[0])


def test_a_rank_killed_mid_run_ends_the_group_with_a_message(tmp_path):
    log_dir = tmp_path / "run"
    torchrun, lines = start_endless_torchrun(log_dir, timeout_s=30)
    try:
        os.kill(rank_pid(lines, 1, torchrun, log_dir), signal.SIGKILL)
        killed = time.monotonic()
        code = torchrun.wait(timeout=90)
    finally:
        end_everything(torchrun, lines)
    out = "".join(lines)
    assert code != 0
    assert time.monotonic() - killed < 60, "the group outlived its rank by a minute"
    # torchrun names the killed rank; rank 0 says why it stopped, unless torchrun's SIGTERM
    # reached it before its next exchange with rank 1 failed
    assert "ChildFailedError" in out and "Signal 9 (SIGKILL)" in out, out[-4000:]
    assert "Exception ignored" not in out, out[-4000:]  # no traceback after rank 0's message


def test_a_sigterm_in_a_ranks_teardown_adds_nothing_to_its_one_line_error():
    # A rank whose group failed prints its one-line error; torchrun's SIGTERM (ending the
    # group) may then land in its teardown, in an env's __del__ (TorchRL envs close there),
    # where a SystemExit cannot end anything and is printed as a traceback.
    script = """if True:
        import os, signal
        from rwalk.rl import distributed

        class Env:
            def __del__(self):
                os.kill(os.getpid(), signal.SIGTERM)  # torchrun's, as the env is freed
                self.closed = True

        def train():  # as rwalk.rl.training.train
            distributed.exit_with_launcher()
            env = Env()
            try:
                raise RuntimeError("gloo: Connection closed by peer")
            finally:
                distributed.leave()

        try:
            train()
        except RuntimeError:
            raise SystemExit("rank 0 of 2: the training's process group failed") from None
    """
    code, out = run([sys.executable, "-c", script])
    assert (code, out) == (1, "rank 0 of 2: the training's process group failed\n")


@pytest.mark.slow
def test_a_rank_that_hangs_times_the_group_out_with_a_message(tmp_path):
    # A stopped rank keeps its connections open: only --dist-timeout ends the wait.
    # (torchrun then waits 30 s for the stopped rank to take its SIGTERM before killing it.)
    log_dir = tmp_path / "run"
    torchrun, lines = start_endless_torchrun(log_dir, timeout_s=5)
    try:
        os.kill(rank_pid(lines, 1, torchrun, log_dir), signal.SIGSTOP)
        code = torchrun.wait(timeout=120)
    finally:
        end_everything(torchrun, lines)
    out = "".join(lines)
    assert code != 0
    assert "rank 0 of 2: the training's process group failed" in out, out[-4000:]
    assert "--dist-timeout 5 s" in out


def test_failed_collectives_are_told_from_other_errors():
    import torch.distributed as dist

    gloo = "[third_party/gloo/gloo/transport/tcp/pair.cc:534] Connection closed by peer"
    assert distributed.is_group_failure(RuntimeError(gloo))
    assert distributed.is_group_failure(dist.DistBackendError("NCCL communicator aborted"))
    assert not distributed.is_group_failure(RuntimeError("3 of 8 starts fell while settling"))


@pytest.mark.slow  # ~20 s; a group from a static rendezvous resumes in test_resume_continues_...
def test_two_agents_as_two_nodes_train_resume_and_end_together(tmp_path):
    """torchrun's multi-node launch on this machine: two agents (--nnodes 2, one process
    each) meet through a c10d rendezvous, train one run, resume it, and end together."""
    run_dir = tmp_path / "run"

    def agent(node: int, port: int, flags: tuple[str, ...]) -> subprocess.Popen:
        rendezvous = ["--rdzv-backend", "c10d", "--rdzv-endpoint", f"127.0.0.1:{port}",
                      "--rdzv-id", f"rwalk-{port}"]  # fmt: skip
        command = [*TORCHRUN, "--nnodes", "2", "--node-rank", str(node), "--nproc-per-node",
                   "1", *rendezvous, "-m", "rwalk.runners.train", *TINY, "--threads", "1",
                   "--log-dir", str(run_dir), *flags]  # fmt: skip
        return subprocess.Popen(command, cwd=ROOT, env=environment(), stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)  # fmt: skip

    def nodes(*flags: str) -> list[tuple[int, str]]:
        port = free_port()
        return finish([agent(node, port, flags) for node in (0, 1)], timeout=300)

    first = nodes("--max-iterations", "2")
    assert [code for code, _ in first] == [0, 0], first[0][1][-3000:] + first[1][1][-3000:]
    assert all("rank" in out and "of 2" in out for _, out in first)
    assert [it for it, _ in checkpoint_files(run_dir)] == [0, 1]
    again = nodes("--resume", str(run_dir), "--max-iterations", "3")
    assert [code for code, _ in again] == [0, 0], again[0][1][-3000:] + again[1][1][-3000:]
    assert "resumed from" in again[0][1] + again[1][1]
    assert [it for it, _ in checkpoint_files(run_dir)] == [0, 1, 2]
    assert load_checkpoint(run_dir / "model_2.pt")["iter"] == 2
    assert not (run_dir / LOCK_NAME).exists()
