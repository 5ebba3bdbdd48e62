"""rwalk-train-torchrl with several collector workers on TorchRL's backends
(rwalk.rl.torchrl_collect), and its env. Tiny runs: 8 envs per worker, settle 2 steps."""

import contextlib
import json
import os
import pickle
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest
import torch
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.collectors.distributed import DistributedCollector

from rwalk.observations import PRIVILEGED_PIECES
from rwalk.rl.checkpoints import CheckpointError, load_checkpoint, save_checkpoint
from rwalk.rl.config import observation_groups
from rwalk.rl.legacy import TorchRLArgs as Args
from rwalk.rl.legacy import TrainingEnv
from rwalk.rl.torchrl_collect import (
    WorkerDied,
    WorkerEnv,
    available_cores,
    check_workers,
    curricula,
    make_collector,
    make_env,
    norm_stats,
    resumed_curricula,
    worker_threads,
)
from rwalk.rl.torchrl_ppo import check_torchrl, make_modules
from rwalk.runners import train_torchrl

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


def _env(args: Args, **changes):
    """The run's env (``changes``: make_env's seed, threads or norms instead of the run's)."""
    options = {"seed": args.seed, "threads": args.threads} | changes
    return make_env(args.env, args.train.reward_scale, **options)


def _make_collector(args: Args, env, actor):
    return make_collector(env, actor, args.env, args.train, seed=args.seed,
                          threads=args.threads, iterations=args.max_iterations)  # fmt: skip


@contextmanager
def _collector(args: Args):
    """(collector, actor) of ``args``, shut down afterwards."""
    env = _env(args)
    actor, _ = make_modules(args.train, env)
    collector = _make_collector(args, env, actor)
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
    assert config["train"]["collectors"] == 2 and config["train"]["backend"] == "process"


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


@pytest.mark.slow
def test_ray_workers_train_on_a_running_local_ray_cluster(tmp_path):
    """A real cluster, as a user would run one: ``ray start --head``, then the trainer with
    RAY_ADDRESS=auto (its workers are the cluster's, not a private ray.init). Ray 2.60's
    ``ray start`` asks for its token (RAY_AUTH_MODE=token, in ~/.ray/auth_token)."""
    pytest.importorskip("ray", reason='the ray extra: pip install -e ".[ray]"')
    ray = Path(sys.executable).with_name("ray")
    port = str(_free_port())
    env = {**os.environ, "RAY_ADDRESS": "auto", "RAY_AUTH_MODE": "token"}
    started = subprocess.run([str(ray), "start", "--head", "--port", port, "--num-cpus", "2",
                              "--include-dashboard", "false", "--disable-usage-stats"],
                             env=env, capture_output=True, text=True, timeout=180,
                             check=False)  # fmt: skip
    assert started.returncode == 0, started.stdout[-2000:] + started.stderr[-2000:]
    try:
        done = subprocess.run(
            [sys.executable, "-m", "rwalk.runners.train_torchrl", *TINY, "--collectors", "2",
             "--backend", "ray", "--log-dir", str(tmp_path)],
            cwd=ROOT, env=env, capture_output=True, text=True, timeout=600, check=False,
        )  # fmt: skip
        assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
        assert "[torchrl] iteration 2/2" in done.stdout
        assert load_checkpoint(tmp_path / "torchrl_2.pt")["iteration"] == 2
    finally:
        subprocess.run([str(ray), "stop", "--force"], env=env, capture_output=True,
                       timeout=120, check=False)  # fmt: skip


def _free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_max_minutes_stops_after_the_iteration_that_spends_it(tmp_path, capsys):
    train_torchrl.main([*TINY, "--max-iterations", "5", "--max-minutes", "1e-9",
                        "--log-dir", str(tmp_path)])  # fmt: skip
    out = capsys.readouterr().out
    assert "[torchrl] iteration 1/5" in out and "iteration 2/5" not in out
    assert "stopping: the 1e-09-minute budget is reached" in out
    assert sorted(p.name for p in tmp_path.glob("torchrl_*.pt")) == ["torchrl_1.pt"]
    assert load_checkpoint(tmp_path / "torchrl_1.pt")["iteration"] == 1


# ------------------------------------------------------------------------- the trainer's env


def test_the_default_env_is_the_robust_world_with_a_privileged_critic():
    args = _args(collectors=1)  # small sizes; the world is the default
    assert Args().robust and args.robust
    env = _env(args)
    base = env.base_env
    assert base.config.terrain_levels is not None and base.config.randomization is not None
    assert base.config.observation_noise is not None and base.config.pushes is not None
    assert base.groups == observation_groups(base.core.task, TrainingEnv(), ())
    policy, critic = base.groups["policy"], base.groups["critic"]
    assert policy == ("observation_from_start", "phase", "lateral_offset")
    assert critic == (*policy, *PRIVILEGED_PIECES)
    widths = {key: env.observation_spec[key].shape[-1] for key in ("policy", "critic")}
    privileged = sum(base.core.piece_size(name) for name in PRIVILEGED_PIECES)
    assert widths["critic"] == widths["policy"] + privileged
    actor, value = make_modules(args.train, env)
    td = env.reset()
    assert actor(td.clone())["action"].shape == (8, 12)
    assert value(td.clone())["state_value"].shape == (8, 1)
    assert value.in_keys == ["critic"] and widths["critic"] > widths["policy"]


# ------------------------------------------------------------- the curricula in checkpoints


def _levels(state: dict) -> torch.Tensor:
    """The terrain levels in an env's ``state_dict`` (its one extra state: ``Curricula``'s)."""
    (extra,) = [value for key, value in state.items() if key.endswith("_extra_state")]
    return extra["terrain_level"]


def test_an_env_keeps_its_terrain_levels_in_its_state_dict_and_loads_them():
    args = _args(collectors=1)
    env = _env(args)
    levels = torch.tensor([3, 1, 4, 1, 5, 2, 6, 5])
    assert env.base_env.core.load_curriculum_state({"terrain_level": levels}) is None
    assert torch.equal(_levels(env.state_dict()), levels)
    other = _env(args, norms=norm_stats(env))
    assert torch.count_nonzero(_levels(other.state_dict())) == 0  # the start level
    other.load_state_dict(env.state_dict())
    assert torch.equal(_levels(other.state_dict()), levels)
    built = _env(args, norms=norm_stats(env), curricula={"terrain_level": levels})
    assert torch.equal(_levels(built.state_dict()), levels)
    built.reset()  # the first starts are on the saved levels, not judged
    assert torch.equal(built.base_env.core.curriculum.terrain_level, levels)


def test_a_resumed_run_goes_on_from_each_workers_terrain_levels(tmp_path):
    done = _train("--collectors", "2", "--max-iterations", "1", "--log-dir", str(tmp_path))
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    first = load_checkpoint(tmp_path / "torchrl_1.pt")
    assert [torch.count_nonzero(env["terrain_level"]) for env in first["curricula"]] == [0, 0]
    mine = [torch.tensor([1, 2, 3, 0, 1, 2, 3, 0]), torch.tensor([2, 0, 1, 3, 2, 0, 1, 3])]
    save_checkpoint(first | {"curricula": [{"terrain_level": m} for m in mine]},
                    tmp_path / "torchrl_1.pt")  # fmt: skip
    done = _train("--collectors", "2", "--max-iterations", "2", "--resume", str(tmp_path),
                  "--log-dir", str(tmp_path))  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "curricula" not in done.stdout  # no note: each worker had its own
    resumed = load_checkpoint(tmp_path / "torchrl_2.pt")["curricula"]
    # 8 steps of each episode: none has ended, so no level has moved since the resume
    assert [env["terrain_level"].tolist() for env in resumed] == [m.tolist() for m in mine]


def test_curricula_of_another_worker_count_or_none_are_said(capsys):
    a, b = {"terrain_level": torch.tensor([1])}, {"terrain_level": torch.tensor([2])}
    assert resumed_curricula([a, b], 3) == [a, b, a]
    assert "the curricula of 2 collector workers, this run has 3" in capsys.readouterr().out
    assert resumed_curricula([a, b], 2) == [a, b] and capsys.readouterr().out == ""
    assert resumed_curricula(None, 2) == [None, None]
    assert "holds no curricula" in capsys.readouterr().out


@pytest.mark.parametrize(
    "bad", [{"terrain_level": torch.zeros(3)}, [{"terrain_level": 1}], ["levels"]]
)
def test_a_checkpoint_with_bad_curricula_is_refused_naming_them(tmp_path, bad):
    norm = {"loc": torch.zeros(2), "scale": torch.ones(2)}
    saved = {"trainer": "torchrl", "iteration": 1, "actor": {}, "critic": {}, "optimizer": {},
             "obs_norm": norm, "critic_norm": norm}  # fmt: skip
    assert check_torchrl(saved, tmp_path / "t.pt") is saved  # an older one: none kept
    curricula = [bad] if isinstance(bad, dict) else bad
    with pytest.raises(CheckpointError, match=r"t\.pt.*'curricula' must be a list"):
        check_torchrl(saved | {"curricula": curricula}, tmp_path / "t.pt")


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
        kept = curricula(collector)  # TorchRL's distributed collectors give no state_dict
    assert kept is None if backend == "distributed" else len(kept) == 2
    assert before.shape == after.shape == (2, 8, 4)  # (workers, envs, steps)
    # Seeds: worker w's envs start like a batch seeded seed + w * num_envs.
    first = before["observation"][:, :, 0]  # (workers, envs, 65)
    dims = {key: before[key].shape[-1] for key in ("policy", "critic")}
    unit = {key: (torch.zeros(d), torch.ones(d)) for key, d in dims.items()}  # skips measuring,
    for worker in (0, 1):  # which steps the env
        stride = args.num_envs + args.env.config().settle_pool
        alone = _env(args, seed=args.seed + worker * stride, threads=1, norms=unit)
        torch.testing.assert_close(first[worker], alone.reset()["observation"])
    assert not torch.isclose(first[0], first[1]).all(dim=-1).any()  # env i of each differs
    # Weights: the second batch was acted by the updated policy.
    assert torch.count_nonzero(before["loc"]) == 0  # the zero-residual start
    with torch.no_grad():
        expected = actor(after.select("policy").clone())["loc"]
    torch.testing.assert_close(after["loc"], expected)
    assert torch.count_nonzero(after["loc"]) > 0


def test_worker_envs_pickle_and_share_the_cores():
    args = _args()
    unit = {"policy": (torch.zeros(3), torch.ones(3)), "critic": (torch.zeros(5), torch.ones(5))}
    maker = WorkerEnv(args.env, args.train.reward_scale, args.seed, 1, 1, unit)
    again = pickle.loads(pickle.dumps(maker))
    assert again.seed == 8 + args.env.config().settle_pool and again.threads == 1
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
        train_torchrl.parse_args(flags)
    assert exit_.value.code == 2
    assert f": error: {message}" in capsys.readouterr().err


def test_a_dead_worker_stops_the_run_before_the_weights_wait_for_it():
    args = _args()
    env = _env(args)
    actor, _ = make_modules(args.train, env)
    collector = _make_collector(args, env, actor)
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
