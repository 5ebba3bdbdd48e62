"""rwalk-train-torchrl with several collector workers on TorchRL's backends
(rwalk.runners.torchrl_collect). Tiny runs: 8 envs per worker, settle 2 steps."""

import contextlib
import json
import pickle
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest
import torch
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.collectors.distributed import DistributedCollector

from rwalk.cli import parse_dataclass
from rwalk.rl.checkpoints import load_checkpoint
from rwalk.runners import train_torchrl
from rwalk.runners.torchrl_collect import (
    WorkerDied,
    WorkerEnv,
    available_cores,
    check_workers,
    make_collector,
    make_env,
    worker_threads,
)
from rwalk.runners.train_torchrl import Args, make_modules

ROOT = Path(__file__).resolve().parents[1]
TINY = [
    "--num-envs", "8", "--num-steps-per-env", "8", "--num-mini-batches", "2",
    "--settle-steps", "2", "--hidden-dims", "16", "16", "--max-iterations", "2",
]  # fmt: skip


def _train(*flags: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "rwalk.runners.train_torchrl", *TINY, *flags],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )


def _args(**changes) -> Args:
    small = {"num_envs": 8, "num_steps_per_env": 4, "num_mini_batches": 2, "settle_steps": 2,
             "hidden_dims": (16, 16), "max_iterations": 2, "collectors": 2}  # fmt: skip
    return Args(**(small | changes))


@contextmanager
def _collector(args: Args):
    """(collector, actor) of ``args``, shut down afterwards."""
    env = make_env(args)
    actor, _ = make_modules(args, env)
    collector = make_collector(args, env, actor)
    try:
        yield collector, actor
    finally:
        collector.shutdown()


# ---------------------------------------------------------------------------- training runs


def test_two_process_workers_train_two_iterations_and_write_checkpoints(tmp_path):
    done = _train("--collectors", "2", "--log-dir", str(tmp_path))
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "[torchrl] iteration 2/2" in done.stdout and "frames/s (collecting" in done.stdout
    saved = load_checkpoint(tmp_path / "torchrl_2.pt")
    assert saved["iteration"] == 2 and saved["trainer"] == "torchrl"
    assert saved["obs_norm"]["loc"].shape == saved["obs_norm"]["scale"].shape
    config = json.loads((tmp_path / "config.json").read_text())
    assert config["collectors"] == 2 and config["backend"] == "process"


@pytest.mark.slow
def test_two_distributed_workers_train_two_iterations(tmp_path):
    done = _train("--collectors", "2", "--backend", "distributed", "--log-dir", str(tmp_path))
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "[torchrl] iteration 2/2" in done.stdout
    assert load_checkpoint(tmp_path / "torchrl_2.pt")["iteration"] == 2


@pytest.mark.slow
def test_two_ray_workers_train_two_iterations(tmp_path):
    pytest.importorskip("ray", reason='the ray extra: pip install -e ".[ray]"')
    done = _train("--collectors", "2", "--backend", "ray", "--log-dir", str(tmp_path))
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "[torchrl] iteration 2/2" in done.stdout
    assert load_checkpoint(tmp_path / "torchrl_2.pt")["iteration"] == 2


# ------------------------------------------------------------------- workers, seeds, weights


def test_one_collector_keeps_the_in_process_collector():
    with _collector(_args(collectors=1)) as (collector, _):
        assert type(collector) is Collector
        assert next(iter(collector)).shape == (8, 4)  # (envs, steps)


@pytest.mark.parametrize(
    ("backend", "kind"), [("process", MultiSyncCollector), ("distributed", DistributedCollector)]
)
def test_workers_step_their_own_seeds_and_get_each_update(backend, kind):
    args = _args(backend=backend)
    with _collector(args) as (collector, actor):
        assert type(collector) is kind
        batches = iter(collector)
        before = next(batches)
        with torch.no_grad():  # as an optimiser step would
            for parameter in actor.parameters():
                parameter.add_(0.3 * torch.randn_like(parameter))
        collector.update_policy_weights_()
        after = next(batches)
    assert before.shape == after.shape == (2, 8, 4)  # (workers, envs, steps)
    # Seeds: worker w's envs start like a batch seeded seed + w * num_envs.
    first = before["observation"][:, :, 0]  # (workers, envs, 65)
    dim = before["policy_obs"].shape[-1]
    unit = (torch.zeros(dim), torch.ones(dim))  # skips measuring, which steps the env
    for worker in (0, 1):
        alone = make_env(args, seed=args.seed + worker * args.num_envs, threads=1, obs_norm=unit)
        torch.testing.assert_close(first[worker], alone.reset()["observation"])
    assert not torch.isclose(first[0], first[1]).all(dim=-1).any()  # env i of each differs
    # Weights: the second batch was acted by the updated policy.
    assert torch.count_nonzero(before["loc"]) == 0  # the zero-residual start
    with torch.no_grad():
        expected = actor(after.select("policy_obs").clone())["loc"]
    torch.testing.assert_close(after["loc"], expected)
    assert torch.count_nonzero(after["loc"]) > 0


def test_worker_envs_pickle_and_share_the_cores():
    maker = WorkerEnv(_args(), 1, 1, torch.zeros(3), torch.ones(3))
    again = pickle.loads(pickle.dumps(maker))
    assert again.seed == 8 and again.threads == 1
    assert worker_threads(2, 0) == max(1, available_cores() // 2)
    assert worker_threads(64 * available_cores(), 0) == 1
    assert worker_threads(2, 3) == 3


# ----------------------------------------------------------------------- faults, bad input


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--backend", "mpi"], "--backend must be one of process, ray, distributed, got 'mpi'"),
        (["--collectors", "0"], "--collectors must be >= 1, got 0"),
        (
            ["--collectors", "2", "--num-envs", "2", "--num-steps-per-env", "2",
             "--num-mini-batches", "9"],
            "--num-mini-batches must be <= --collectors * --num-envs * --num-steps-per-env = 8",
        ),
    ],
)  # fmt: skip
def test_bad_collector_flags_are_usage_errors(flags, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        parse_dataclass(Args, flags, None, prog="rwalk-train-torchrl")
    assert exit_.value.code == 2
    assert f"rwalk-train-torchrl: error: {message}" in capsys.readouterr().err


def test_a_dead_worker_stops_the_run_before_the_weights_wait_for_it():
    args = _args()
    env = make_env(args)
    actor, _ = make_modules(args, env)
    collector = make_collector(args, env, actor)
    try:
        next(iter(collector))
        check_workers(collector)  # all alive
        collector.procs[1].kill()
        collector.procs[1].join()
        with pytest.raises(WorkerDied, match=r"collector worker 1 exited \(exit code -9\)"):
            check_workers(collector)
    finally:
        with contextlib.suppress(Exception):  # one worker is gone
            collector.shutdown()


def test_ray_missing_is_one_line_naming_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray fails, installed or not
    out = tmp_path / "out"
    flags = ["--collectors", "2", "--backend", "ray", "--log-dir", str(out)]
    with pytest.raises(SystemExit) as exit_:
        train_torchrl.main([*TINY, *flags])
    message = str(exit_.value.code)
    assert "error: --backend ray needs Ray" in message
    assert 'pip install -e ".[ray]"' in message and "\n" not in message
    assert not out.exists()  # nothing written
