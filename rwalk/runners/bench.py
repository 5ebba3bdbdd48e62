"""Throughput and memory of the env beside its physics floor, measured in one run.

    rwalk-bench                      # the full sweep (about 35 minutes on 2 cores, plus (e))
    rwalk-bench --quick              # N in {16, 1024}, short windows
    rwalk-bench --json bench.json --plot docs/performance.png
    rwalk-bench --only b,1024,2 --only a,64,1 --seconds 4
    rwalk-bench --only b,1024,1      # robot-seconds per core-second of the env at N=1024

    pip install -e ".[bench]"        # EnvPool (optional extra), for mode e:
    rwalk-bench --only e,256,1 --seconds 8   # rwalk vs EnvPool's Go1, rough and flat

In a checkout, ``python -m runners.bench`` takes the same arguments. Without envpool,
mode e is skipped with a one-line message; the other modes run as usual.

Modes, all on world_train with the training defaults, the same N, threads and
control period (``core.control_dt``: ``core.decimation`` physics substeps):

  b  ResidualWalkVecEnv.step_and_maybe_reset with random actions, resets included
  g  the same for AdaptiveGaitVecEnv (16-D actions: gait deltas and residuals),
     against a floor of its own
  a  in the same process as b, timed in alternating rounds with it: raw
     mujoco.rollout (persistent pool, preallocated outputs, skip_checks) on b's
     robots, from b's states, with the same random-residual workload and the servo
     targets precomputed: the physics floor
  c  rsl-rl's collection loop: PPO.act + RslRlVecEnv.step + PPO.process_env_step
  d  gymnasium SyncVectorEnv (1 process) and AsyncVectorEnv (one worker process per
     core) over the single-env ResidualWalkEnv
  t  thread scaling: b and a on 1 thread and on all cores, all four in one process,
     alternating
  r  the cost of the robust training's world: rsl-rl's env step (RslRlVecEnv.step,
     random actions, its observation groups built, no PPO) on three envs of the same
     N in one process, alternating: the plain training env (one rough world), the
     terrain-levels map alone (envs spread over its levels), and the map with
     randomised physics, pushes, latency, observation noise and the privileged critic
  e  EnvPool's MuJoCo Playground ports Go1JoystickRoughTerrain-v1 and
     Go1JoystickFlatTerrain-v1 beside b on world_train and world_flat, same N and
     threads, random actions, alternating, one process per terrain
     (rwalk.runners.bench_envpool). EnvPool's Go1 holds 40-50 MB per env: keep N <= 256.

Every row carries simulated robot-seconds per core-second: env steps/s x control
period / threads (for the floor, physics steps/s x timestep / threads). It compares
envs whose control period or substeps differ; settling counts as overhead, not as
simulated time.

Each measurement runs in a fresh subprocess (its own peak RSS). Ratios to the
floor come from contenders timed in alternating rounds in one process (c, like b,
has a floor of its own), so the machine's drift does not land on one side.
Episodes start spread over their length (like rsl-rl's init_at_random_ep_len), so
resets happen at their long-run rate inside the timing window; every physics
substep counts, settling included.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

SIZES = (1, 16, 256, 1024, 4096, 8192)
QUICK_SIZES = (16, 1024)
ROUNDS = 4
GYM_SYNC_SIZES = (1, 16)
ENVPOOL_N = 256


def _config(threads: int, n: int, task: str = "residual_walk"):
    """The training defaults of ``task`` for n envs on the given number of threads."""
    from rwalk.presets import training_config

    return training_config(task, num_envs=n, threads=threads)


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _timed(step, window: float, min_steps: int = 3) -> tuple[int, float]:
    """Call step() until window seconds and min_steps have passed; (calls, seconds).

    step() may return the seconds of its own work that count (None: all of it)."""
    calls, counted, start = 0, 0.0, time.perf_counter()
    while True:
        t0 = time.perf_counter()
        own = step()
        counted += own if own is not None else time.perf_counter() - t0
        calls += 1
        if time.perf_counter() - start >= window and calls >= min_steps:
            return calls, counted


class Floor:
    """The floor: plain mujoco.rollout on the same robots and workload as the env.

    Starts from the env's current states and applies the base gait plus uniform random
    residuals drawn from the env's own random stream: the same physics, without the
    env. The servo targets are computed outside the timed region (a fixed control
    sequence); only the rollout calls and the state copy are timed. mujoco.rollout
    cannot carry the solver warmstart, so each call starts it at zero."""

    def __init__(self, core, threads: int, gen: torch.Generator) -> None:
        import mujoco
        from mujoco import rollout

        self.n, self.k, self.model = core.num_envs, core.decimation, core.model
        self.core, self.gen = core, gen
        self.timing = physics_timing(core)
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        data = mujoco.MjData(self.model)
        self.state = np.empty((self.n, mujoco.mj_stateSize(self.model, spec)))
        for i in range(self.n):
            core.sim.batch.get_data(i, data)
            mujoco.mj_getState(self.model, data, self.state[i], spec)
        nthread = threads or os.cpu_count() or 1
        self.pool = rollout.Rollout(nthread=nthread if nthread > 1 else 0)
        self.datas = [mujoco.MjData(self.model) for _ in range(nthread)]
        self.models = [self.model] * self.n
        self.out_state = np.empty((self.n, self.k, self.state.shape[1]))
        self.out_sensors = np.empty((self.n, self.k, self.model.nsensordata))
        # The gait's tick nearest each env's phase (any task: the floor runs the base gait).
        self.tick = torch.round(core.phase * core.controller.period).long()

    def step(self) -> float:
        core, n, k = self.core, self.n, self.k
        residuals = torch.rand(n, 12, generator=self.gen) * 2 - 1
        residuals = residuals.double().view(n, 4, 3) * core.config.residual_scale
        ctrl = core.controller.joint_targets(self.tick, k, residuals)[0].numpy()
        self.tick.add_(k).remainder_(core.controller.period)
        t0 = time.perf_counter()
        self.pool.rollout(
            self.models, self.datas, self.state, ctrl, state=self.out_state,
            sensordata=self.out_sensors, skip_checks=True, nstep=k,
        )  # fmt: skip
        self.state[:] = self.out_state[:, -1]
        return time.perf_counter() - t0


def physics_timing(core) -> dict:
    """The simulated time behind a core's env step: control period, substeps, timestep.

    Seconds; read from the core (its world's timestep, overrides applied), never assumed."""
    return {"control_dt_s": core.control_dt, "substeps": core.decimation, "timestep_s": core.dt}


def _config_timing(config) -> dict:
    """physics_timing() of a config without building a core."""
    from rwalk.assets import load_model

    model = load_model(config.model_path)
    config.physics.apply(model)
    timestep = float(model.opt.timestep)
    substeps = config.substeps(timestep)
    return {"control_dt_s": timestep * substeps, "substeps": substeps, "timestep_s": timestep}


def robot_seconds_per_core_second(row: dict) -> float:
    """Simulated robot-seconds per core-second of a result row.

    Env steps/s x control period / threads; for the floor (a), physics steps/s x
    timestep / threads: the same figure, counted from the substeps. Settling is
    overhead here, not simulated time: only env steps (or, for (a), its substeps) count."""
    if row["mode"] == "a":
        return row["physics_steps_per_s"] * row["timestep_s"] / row["threads"]
    return row["env_steps_per_s"] * row["control_dt_s"] / row["threads"]


def _spread_episodes(core, generator: torch.Generator) -> None:
    high = core.config.max_episode_steps
    core.episode_step.copy_(torch.randint(0, high, core.episode_step.shape, generator=generator))


class EnvMeter:
    """What the core did while its steps were timed: throughput, settling, time in MuJoCo.

    Pool refills are rare and large, so besides the settle share inside the timed
    windows this reports the amortized one: each reset charged settle_steps x
    decimation / settle_reuse substeps, what it costs over many refills."""

    def __init__(self, core) -> None:
        self.core = core
        self.before, self.resets = dict(core.physics_steps), core.resets
        self.in_mujoco = core.rollout_seconds

    def result(self, calls: int, seconds: float) -> dict:
        core, cfg = self.core, self.core.config
        physics = {key: core.physics_steps[key] - self.before[key] for key in self.before}
        total = physics["step"] + physics["settle"]
        per_reset = (
            cfg.settle_steps * core.decimation / (cfg.settle_reuse if cfg.settle_pool else 1)
        )
        resets = core.resets - self.resets
        amortized = resets * per_reset
        return {
            "env_steps_per_s": calls * core.num_envs / seconds,
            "physics_steps_per_s": total / seconds,
            "settle_share": physics["settle"] / total,
            "settle_share_amortized": amortized / (physics["step"] + amortized),
            "resets_per_step": resets / calls,
            "time_in_mujoco": (core.rollout_seconds - self.in_mujoco) / seconds,
        } | physics_timing(core)


def _interleaved(steps: dict, window: float, rounds: int = ROUNDS) -> dict[str, tuple]:
    """Time each step() for window / rounds seconds in turn, rounds times over.

    Alternating spreads the machine's drifts and noise evenly over the contenders,
    so their ratios hold even where absolute figures wander. Returns key -> (calls,
    seconds) summed over the rounds."""
    totals = {key: (0, 0.0) for key in steps}
    for _ in range(rounds):
        for key, step in steps.items():
            calls, seconds = _timed(step, window / rounds)
            totals[key] = (totals[key][0] + calls, totals[key][1] + seconds)
    return totals


def _floor_result(floor: Floor, calls: int, seconds: float) -> dict:
    return {
        "env_steps_per_s": calls * floor.n / seconds,
        "physics_steps_per_s": calls * floor.n * floor.k / seconds,
        "settle_share": 0.0,
    } | floor.timing


def _env_stepper(
    n: int,
    threads: int,
    gen: torch.Generator,
    model_path: str | None = None,
    task: str = "residual_walk",
):
    """A batched env of ``task`` with the training defaults (on another world if
    model_path is given), episodes spread, and its step()."""
    from rwalk import ResidualWalkVecEnv

    config = _config(threads, n, task)
    if model_path is not None:
        config = dataclasses.replace(config, model_path=model_path)
    started = time.perf_counter()
    env = ResidualWalkVecEnv(n, config, seed=0, task=task)
    td = env.reset()
    width = env.core.task.action_dim
    first_reset = {
        "first_reset_seconds_per_env": (time.perf_counter() - started) / n,
        "first_reset_substeps_per_env": env.core.physics_steps["settle"] / n,
    }
    _spread_episodes(env.core, gen)
    torch_threads = threads or os.cpu_count() or 1

    def step() -> None:
        nonlocal td
        torch.set_num_threads(torch_threads)
        td.set("action", torch.rand(n, width, generator=gen) * 2 - 1)
        _, td = env.step_and_maybe_reset(td)

    step()  # the first partial resets fill the pool
    return env, step, first_reset


def _against_floor(core, step, threads: int, gen: torch.Generator, window: float):
    """Time step() and a Floor on core's robots in alternating rounds; (row, floor row).

    The row carries its floor's physics steps/s and the peak RSS before the floor
    allocated its buffers."""
    _timed(step, window / ROUNDS)  # a first round before the floor allocates its buffers
    peak_rss = _peak_rss_mb()
    meter = EnvMeter(core)
    floor = Floor(core, threads, gen)
    timed = _interleaved({"env": step, "a": floor.step}, window)
    a = _floor_result(floor, *timed["a"])
    row = meter.result(*timed["env"]) | {"peak_rss_mb": peak_rss}
    row["floor_physics_steps_per_s"] = a["physics_steps_per_s"]
    return row, a


def measure_env(n: int, threads: int, window: float, task: str = "residual_walk") -> dict:
    """(b) (or (g), the adaptive task) and its floor (a) on the same robots, timed in
    alternating rounds."""
    gen = torch.Generator().manual_seed(0)
    env, step, first_reset = _env_stepper(n, threads, gen, task=task)
    b, a = _against_floor(env.core, step, threads, gen, window)
    return {"b" if task == "residual_walk" else "g": b | first_reset, "a": a}


def measure_scaling(n: int, threads: int, window: float) -> dict:
    """(b) and (a) on 1 thread and on ``threads``, all four in one process, alternating."""
    gen = torch.Generator().manual_seed(0)
    steps, meters, floors = {}, {}, {}
    for t in (1, threads):
        env, steps[f"b{t}"], _ = _env_stepper(n, t, gen)
        meters[t] = EnvMeter(env.core)
        floors[t] = Floor(env.core, t, gen)
        steps[f"a{t}"] = floors[t].step
    timed = _interleaved(steps, window)
    rows = {}
    for t in (1, threads):
        rows[f"b{t}"] = meters[t].result(*timed[f"b{t}"]) | {"threads": t, "mode": "b"}
        rows[f"a{t}"] = _floor_result(floors[t], *timed[f"a{t}"]) | {"threads": t, "mode": "a"}
    for row in rows.values():
        row["robot_seconds_per_core_second"] = robot_seconds_per_core_second(row)
    one, many = rows["b1"], rows[f"b{threads}"]
    return {
        "t": {
            "env_steps_per_s": many["env_steps_per_s"],
            "physics_steps_per_s": many["physics_steps_per_s"],
            "settle_share": many["settle_share"],
            "control_dt_s": many["control_dt_s"],
            "substeps": many["substeps"],
            "timestep_s": many["timestep_s"],
            "env_speedup": many["env_steps_per_s"] / one["env_steps_per_s"],
            "floor_speedup": rows[f"a{threads}"]["physics_steps_per_s"]
            / rows["a1"]["physics_steps_per_s"],
            "pairs": rows,
        }
    }


def measure_robust(n: int, threads: int, window: float) -> dict:
    """(r): the plain, map-only and robust training envs through RslRlVecEnv.step,
    alternating in one process; ratios of their env steps/s."""
    from rwalk import ResidualWalkVecEnv
    from rwalk.presets import training_config
    from rwalk.wrappers import RslRlVecEnv

    robust = training_config(num_envs=n, threads=threads, robust=True)
    configs = {
        "plain": training_config(num_envs=n, threads=threads),
        "map": dataclasses.replace(robust, randomization=None, pushes=None, observation_noise=None),
        "robust": robust,
    }
    steps, meters = {}, {}
    for name, config in configs.items():
        # Each env its own generator, seeded alike: the same levels, spread and actions.
        gen = torch.Generator().manual_seed(0)
        vec = ResidualWalkVecEnv(n, config, seed=0)
        if config.terrain_levels is not None:  # every level, as a curriculum spreads them
            levels = config.terrain_levels.levels
            vec.core.terrain_level.copy_(torch.randint(0, levels, (n,), generator=gen))
        adapter = RslRlVecEnv(vec)  # resets; its default groups (privileged critic for robust)
        _spread_episodes(vec.core, gen)

        def step(adapter=adapter, gen=gen) -> None:
            adapter.step(torch.rand(n, 12, generator=gen) * 2 - 1)

        step()
        steps[name], meters[name] = step, EnvMeter(vec.core)
    timed = _interleaved(steps, window)
    rows = {name: meters[name].result(*timed[name]) for name in configs}
    fps = {name: row["env_steps_per_s"] for name, row in rows.items()}
    return {
        "r": rows["robust"]
        | {
            "robust_over_plain": fps["robust"] / fps["plain"],
            "robust_over_map": fps["robust"] / fps["map"],
            "map_over_plain": fps["map"] / fps["plain"],
            "pairs": rows,
        }
    }


def measure_rsl_rl(n: int, threads: int, window: float) -> dict:
    from rwalk.rl.config import TrainArgs as Args
    from rwalk.rl.runner import SafeRunner
    from rwalk.rl.training import make_env, rsl_rl_config

    # The plain training env, as in (b) and docs/performance.md; mode r times the robust one.
    args = dataclasses.replace(Args(), num_envs=n, threads=threads, robust=False)
    env = make_env(args)
    runner = SafeRunner(env, rsl_rl_config(args), log_dir=None, device="cpu")
    alg = runner.alg
    _spread_episodes(env.core, torch.Generator().manual_seed(0))
    obs = env.get_observations()
    filled = [0]

    def step() -> None:
        nonlocal obs
        with torch.inference_mode():
            actions = alg.act(obs)
            obs, rewards, dones, extras = env.step(actions)
            alg.process_env_step(obs, rewards, dones, extras)
        filled[0] += 1
        if filled[0] == args.num_steps_per_env:
            alg.storage.clear()
            filled[0] = 0

    step()  # the first partial resets fill the pool
    c, _ = _against_floor(env.core, step, threads, torch.Generator().manual_seed(1), window)
    return {"c": c}


class _SpreadEpisodes:
    """Env factory for gymnasium vector envs: a single env whose first episode is
    already ``offset`` steps old, like the batched modes' spread episodes."""

    def __init__(self, config, index: int, offset: int) -> None:
        self.config, self.index, self.offset = config, index, offset

    def __call__(self):
        from rwalk import ResidualWalkEnv

        offset = self.offset

        class LateFirstEpisode(ResidualWalkEnv):
            def reset(self, **kwargs):
                nonlocal offset
                out = super().reset(**kwargs)
                if offset:  # episode_step is public: trainers spread episodes the same way
                    self.core.episode_step[0], offset = offset, 0
                return out

        return LateFirstEpisode(config=self.config, seed=self.index)


def measure_gym(n: int, processes: int, window: float) -> dict:
    import gymnasium

    config = dataclasses.replace(_config(1, 1), settle_pool=0)
    gen = np.random.default_rng(0)
    offsets = gen.integers(0, config.max_episode_steps, n)
    makers = [_SpreadEpisodes(config, i, int(offsets[i])) for i in range(n)]
    if processes > 1:
        vec = gymnasium.vector.AsyncVectorEnv(makers, context="spawn")  # fork deadlocks OpenMP
    else:
        vec = gymnasium.vector.SyncVectorEnv(makers)
    vec.reset(seed=0)
    vec.action_space.seed(0)
    resets = [0]

    def step() -> None:
        _, _, terminated, truncated, _ = vec.step(vec.action_space.sample())
        resets[0] += int(np.sum(terminated | truncated))

    step()
    resets[0] = 0
    calls, seconds = _timed(step, window)
    vec.close()
    timing = _config_timing(config)
    k = timing["substeps"]
    # Each reset settles settle_steps env steps (a start that falls is redrawn: rare).
    step_physics = calls * n * k
    settle_physics = resets[0] * config.settle_steps * k
    total = step_physics + settle_physics
    return {
        "d": {
            "env_steps_per_s": calls * n / seconds,
            "physics_steps_per_s": total / seconds,
            "settle_share": settle_physics / total,
            "settle_share_amortized": settle_physics / total,
            "resets_per_step": resets[0] / calls,
        }
        | timing
    }


def measure_envpool(terrain: str):
    """(e) on one terrain: rwalk beside EnvPool's Go1 (rwalk.runners.bench_envpool)."""

    def measure(n: int, threads: int, window: float) -> dict:
        from rwalk.runners.bench_envpool import measure

        return measure(terrain, n, threads, window)

    return measure


MEASURES = {
    "b": measure_env,
    "g": lambda n, threads, window: measure_env(n, threads, window, task="adaptive_gait"),
    "c": measure_rsl_rl,
    "d": measure_gym,
    "t": measure_scaling,
    "r": measure_robust,
    # (e) runs one process per terrain: EnvPool's pools are too large to hold two.
    "e/rough": measure_envpool("rough"),
    "e/flat": measure_envpool("flat"),
}
LABELS = {
    "a": "raw mujoco.rollout (floor)",
    "b": "ResidualWalkVecEnv",
    "g": "AdaptiveGaitVecEnv",
    "c": "rsl-rl collection",
    "d": "gymnasium vector env",
    "t": "ResidualWalkVecEnv, thread scaling",
    "r": "robust training env vs plain and map-only",
    "e": "rwalk vs EnvPool Go1 joystick",
    "e/rough": "world_train vs EnvPool Go1JoystickRoughTerrain-v1",
    "e/flat": "world_flat vs EnvPool Go1JoystickFlatTerrain-v1",
}


def worker(mode: str, n: int, threads: int, window: float) -> None:
    """Measure one configuration; print each result row as a JSON line.

    Modes b and g also measure the floor (a), on the same robots, alternating."""
    torch.set_num_threads(max(threads, 1) if threads else os.cpu_count() or 1)
    rows = MEASURES[mode](n, threads, window)
    for key, row in rows.items():
        row.setdefault("peak_rss_mb", _peak_rss_mb())
        row.setdefault("threads", threads)
        row.setdefault("mode", key)
        row["n"] = n
        row["robot_seconds_per_core_second"] = robot_seconds_per_core_second(row)
        print("RESULT " + json.dumps(row), flush=True)


#: Modes --only accepts; (a) is measured by the same worker as (b), on its robots, and
#: (e) by one worker per terrain.
ONLY_MODES = ("a", "b", "c", "d", "e", "g", "r", "t")


def parse_only(text: str) -> tuple[str, int, int]:
    """argparse type of --only: ``mode,N,threads`` -> (mode, N, threads)."""
    wanted = (
        f"'mode,N,threads' with mode in {', '.join(ONLY_MODES)}, N >= 1 and threads >= 1 "
        f"(>= 2 for t), e.g. b,1024,2"
    )
    parts = text.split(",")
    try:
        mode, n, threads = parts[0].strip(), int(parts[1]), int(parts[2])
    except (IndexError, ValueError):
        raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}") from None
    if len(parts) != 3 or mode not in ONLY_MODES or n < 1 or threads < (2 if mode == "t" else 1):
        raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}")
    return mode, n, threads


def positive_seconds(text: str) -> float:
    """argparse type of --seconds: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a number of seconds > 0, got {text!r}")
    return value


def worker_runs(only: list[tuple[str, int, int]]) -> list[tuple[str, int, int]]:
    """The worker runs that measure ``only``: (a) comes from (b)'s worker, (e) from one
    worker per terrain (a single run that reports the skip where envpool is missing);
    no run twice."""
    from rwalk.runners.bench_envpool import envpool_missing

    terrains = ("e",) if envpool_missing() else ("e/rough", "e/flat")
    runs = []
    for mode, n, threads in only:
        modes = {"a": ("b",), "e": terrains}.get(mode, (mode,))
        runs += [(worker_mode, n, threads) for worker_mode in modes]
    return list(dict.fromkeys(runs))


def plan(quick: bool) -> list[tuple[str, int, int]]:
    cores = os.cpu_count() or 1
    sizes = QUICK_SIZES if quick else SIZES
    thread_counts = sorted({1, cores})
    runs = [(mode, n, t) for n in sizes for t in thread_counts for mode in "bc"]
    runs += [("g", QUICK_SIZES[-1], t) for t in thread_counts]  # the adaptive task at N=1024
    runs.append(("r", QUICK_SIZES[-1], cores))  # the robust training's world at N=1024
    runs += [("d", n, 1) for n in (GYM_SYNC_SIZES[-1:] if quick else GYM_SYNC_SIZES)]
    if cores > 1:
        runs.append(("d", cores, cores))  # AsyncVectorEnv: one worker process per core
        runs.append(("t", QUICK_SIZES[-1] if quick else 4096, cores))
    # EnvPool's Go1 holds 40-50 MB per env: N=256 at most (11-13 GB peak).
    runs += [("e", QUICK_SIZES[0] if quick else ENVPOOL_N, t) for t in thread_counts]
    return worker_runs(runs)


def _ratio_rows(results: list[dict]) -> None:
    floor = {(r["n"], r["threads"]): r["physics_steps_per_s"] for r in results if r["mode"] == "a"}
    for r in results:
        if r["mode"] in ("t", "e", "r"):  # (t) and (r) have ratios of their own; (e) no floor
            continue
        base = r.get("floor_physics_steps_per_s") or floor.get((r["n"], r["threads"]))
        r["ratio_to_floor"] = r["physics_steps_per_s"] / base if base else None


def _period(r: dict) -> str:
    """A row's control period as 'env step (substeps x timestep)'."""
    return f"{r['control_dt_s'] * 1e3:g} ms ({r['substeps']} x {r['timestep_s'] * 1e3:g} ms)"


def table(results: list[dict]) -> str:
    """The results as markdown: one table for (a)-(d), and one for (e) if it ran."""
    lines = [
        "| mode | N | threads | env steps/s | physics steps/s | control period "
        "| robot s / core s | ratio to its (a) | settle share (window / amortized) "
        "| time in MuJoCo | peak RSS (MB) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    rows = [r for r in results if r["mode"] not in ("t", "e", "r")]
    contest = [r for r in results if r["mode"] == "e"]
    if contest and not rows:
        return "\n".join(contest_table(contest))
    for r in sorted(rows, key=lambda r: (r["mode"], r["n"], r["threads"])):
        ratio = f"{r['ratio_to_floor']:.3f}" if r.get("ratio_to_floor") else "—"
        mujoco_share = f"{r['time_in_mujoco']:.1%}" if "time_in_mujoco" in r else "—"
        lines.append(
            f"| {r['mode']} {LABELS[r['mode']]} | {r['n']} | {r['threads']} | "
            f"{r['env_steps_per_s']:,.0f} | {r['physics_steps_per_s']:,.0f} | {_period(r)} | "
            f"{r['robot_seconds_per_core_second']:.2f} | {ratio} | "
            f"{r['settle_share']:.1%} / {r.get('settle_share_amortized', 0.0):.1%} | "
            f"{mujoco_share} | {r['peak_rss_mb']:,.0f} |"
        )
    if contest:
        lines += ["", *contest_table(contest)]
    return "\n".join(lines)


def contest_table(rows: list[dict]) -> list[str]:
    """(e): rwalk and EnvPool's Go1 on matching terrain, timed in alternating rounds."""
    lines = [
        "| terrain | env | N | threads | env steps/s | control period | robot s / core s "
        "| cores busy (measured) | resets per env step | memory per env (MB: added / N) "
        "| rwalk / EnvPool (robot s / core s) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    order = {"rough": 0, "flat": 1, "rwalk": 0, "envpool": 1}

    def key(r: dict) -> tuple:
        return order[r["terrain"]], r["n"], r["threads"], order[r["contender"]]

    for r in sorted(rows, key=key):
        name = f"rwalk {r['task']}" if r["contender"] == "rwalk" else f"EnvPool {r['task']}"
        ratio = f"{r['ratio_to_envpool']:.2f}" if "ratio_to_envpool" in r else ""
        lines.append(
            f"| {r['terrain']} | {name} | {r['n']} | {r['threads']} | "
            f"{r['env_steps_per_s']:,.0f} | {_period(r)} | "
            f"{r['robot_seconds_per_core_second']:.2f} | {r['cores_busy']:.2f} | "
            f"{r['resets_per_step'] / r['n']:.4f} | {r['memory_per_env_mb']:.2f} | {ratio} |"
        )
    return lines


def summary(results: list[dict]) -> list[str]:
    """The issue's floors, computed from the sweep."""
    out: list[str] = []
    if not results:
        return out
    by = {(r["mode"], r["n"], r["threads"]): r for r in results}
    cores = max(r["threads"] for r in results)
    thread_counts = sorted({1, cores})  # once each where every row ran on 1 thread
    for mode, n, t in [(m, n, t) for m in "bc" for n in (1024, 4096, 8192) for t in thread_counts]:
        if (mode, n, t) in by:
            ratio = by[(mode, n, t)]["ratio_to_floor"]
            out.append(f"({mode})/(a) physics steps/s at N={n}, {t} thread(s): {ratio:.3f}")
    batched = [r for r in results if r["mode"] == "b"]
    gyms = [r for r in results if r["mode"] == "d"]
    if batched and gyms:
        best_b = max(batched, key=lambda r: r["env_steps_per_s"])
        best_d = max(gyms, key=lambda r: r["env_steps_per_s"])
        out.append(
            f"best (b) {best_b['env_steps_per_s']:,.0f} env steps/s (N={best_b['n']}) vs best (d) "
            f"{best_d['env_steps_per_s']:,.0f} (N={best_d['n']}, {best_d['threads']} process(es)): "
            f"{best_b['env_steps_per_s'] / best_d['env_steps_per_s']:.2f}x"
        )
    if ("d", 1, 1) in by and ("a", 1, 1) in by:
        single, floor = by[("d", 1, 1)], by[("a", 1, 1)]
        share = single["physics_steps_per_s"] / floor["physics_steps_per_s"]
        out.append(
            f"single env: {single['env_steps_per_s']:,.0f} steps/s, {share:.3f} of the N=1 floor"
        )
    if ("b", 256, cores) in by and ("b", 4096, cores) in by:
        small, large = by[("b", 256, cores)], by[("b", 4096, cores)]
        per_env = (large["peak_rss_mb"] - small["peak_rss_mb"]) * 1024 / (4096 - 256)
        out.append(f"memory per additional env (N=4096 vs 256): {per_env:.1f} KB")
    for r in results:
        if r["mode"] == "t":
            out.append(
                f"(b) {r['threads']} threads vs 1 at N={r['n']}, one process, alternating: "
                f"{r['env_speedup']:.2f}x (raw mujoco.rollout: {r['floor_speedup']:.2f}x)"
            )
    for r in results:
        if r["mode"] == "r":
            out.append(
                f"(r) robust training env at N={r['n']}, {r['threads']} thread(s), one process, "
                f"alternating: {r['robust_over_plain']:.3f} of the plain env's env steps/s "
                f"({r['robust_over_map']:.3f} of the map alone; map alone "
                f"{r['map_over_plain']:.3f} of plain)"
            )
    if ("b", 4096, cores) in by:
        r = by[("b", 4096, cores)]
        out.append(
            f"training defaults at N=4096: {r['env_steps_per_s']:,.0f} env steps/s, settle share "
            f"{r['settle_share']:.1%} in the window, {r['settle_share_amortized']:.1%} amortized; "
            f"first reset {r['first_reset_seconds_per_env'] * 1e3:.1f} ms per env"
        )
    return out + _robot_seconds_lines(results)


def _robot_seconds_lines(results: list[dict]) -> list[str]:
    """Simulated robot-seconds per core-second: (a)-(c) at N >= 1024 on 1 thread, and
    each (e) pair."""
    out = []
    for n in sorted({r["n"] for r in results if r["n"] >= 1024}):
        rows = {r["mode"]: r for r in results if r["n"] == n and r["threads"] == 1}
        shown = [m for m in "bca" if m in rows]
        if shown:
            figures = ", ".join(
                f"({m}) {rows[m]['robot_seconds_per_core_second']:.2f}" for m in shown
            )
            out.append(
                f"robot-seconds per core-second at N={n}, 1 thread: {figures} "
                f"(control period {_period(rows[shown[0]])})"
            )
    pairs = {}
    for r in results:
        if r["mode"] == "e":
            pairs.setdefault((r["terrain"], r["n"], r["threads"]), {})[r["contender"]] = r
    for pair in pairs.values():
        ours, theirs = pair["rwalk"], pair["envpool"]
        out.append(
            f"(e) {ours['terrain']}, N={ours['n']}, {ours['threads']} thread(s), alternating: "
            f"rwalk {ours['task']} {ours['robot_seconds_per_core_second']:.2f} vs EnvPool "
            f"{theirs['task']} {theirs['robot_seconds_per_core_second']:.2f} robot-seconds per "
            f"core-second: {ours['ratio_to_envpool']:.2f}x; memory per env "
            f"{ours['memory_per_env_mb']:.2f} vs {theirs['memory_per_env_mb']:.1f} MB"
            + (
                " (EnvPool's memory keeps N below 1024 here: rwalk's N >= 1024 figure is (b)'s)"
                if ours["n"] < 1024
                else ""
            )
        )
    return out


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    for mode in "abc":
        for t in sorted({r["threads"] for r in results}):
            rows = sorted(
                (r for r in results if r["mode"] == mode and r["threads"] == t),
                key=lambda r: r["n"],
            )
            if rows:
                ax.plot(
                    [r["n"] for r in rows], [r["physics_steps_per_s"] for r in rows],
                    marker="o", linestyle="-" if t > 1 else "--",
                    label=f"({mode}) {LABELS[mode]}, {t} thread{'s' if t > 1 else ''}",
                )  # fmt: skip
    for r in results:
        if r["mode"] == "d":
            kind = "Async" if r["threads"] > 1 else "Sync"
            ax.scatter([r["n"]], [r["physics_steps_per_s"]], marker="x", s=60, color="k")
            ax.annotate(f"(d) {kind}VectorEnv", (r["n"], r["physics_steps_per_s"]), fontsize=7)
    ax.set(xscale="log", xlabel="N (envs)", ylabel="physics steps / s (settling included)")
    ax.set_title("Throughput beside the raw mujoco.rollout floor (world_train)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="N in {16, 1024}, 2 s windows")
    parser.add_argument(
        "--seconds",
        type=positive_seconds,
        help="timing window per measurement (default: 2 with --quick, else 8)",
    )
    parser.add_argument("--json", type=Path, help="save the results here")
    parser.add_argument("--plot", type=Path, help="save a throughput-vs-N PNG here")
    parser.add_argument(
        "--only",
        action="append",
        type=parse_only,
        help="measure only 'mode,N,threads' (repeatable, e.g. b,1024,2; a comes with b)",
    )
    parser.add_argument("--worker", nargs=4, help=argparse.SUPPRESS)
    return parser.parse_args(argv)


def bench(argv: list[str] | None = None) -> list[dict]:
    """Run the sweep of the command line ``argv``; returns the result rows (a failed
    or skipped measurement has none)."""
    return _sweep(parse_args(argv))[0]


def _sweep(args: argparse.Namespace) -> tuple[list[dict], int]:
    """Run, report and save the sweep of ``args``; (result rows, failed runs)."""
    from rwalk.runners.bench_envpool import envpool_missing

    window = args.seconds or (2.0 if args.quick else 8.0)
    runs = worker_runs(args.only) if args.only else plan(args.quick)
    results, failed = [], 0
    started = time.perf_counter()
    for i, (mode, n, threads) in enumerate(runs, 1):
        print(
            f"[{i}/{len(runs)}] ({mode}) {LABELS[mode]}, N={n}, threads={threads} ...",
            end=" ",
            flush=True,
        )
        if mode == "e":  # worker_runs keeps a bare (e) only where envpool is missing
            print(f"skipped: {envpool_missing()}", flush=True)
            continue
        command = [
            sys.executable,
            "-m",
            "rwalk.runners.bench",
            "--worker",
            mode,
            str(n),
            str(threads),
            str(window),
        ]
        done = subprocess.run(command, capture_output=True, text=True, check=False)
        lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
        if done.returncode != 0 or not lines:
            print(f"failed:\n{done.stderr[-2000:]}")
            failed += 1
            continue
        rows = [json.loads(line[len("RESULT ") :]) for line in lines]
        results.extend(rows)
        print(
            ", ".join(
                f"({' '.join(filter(None, (r['mode'], r.get('contender'))))}) "
                f"{r['env_steps_per_s']:,.0f} env steps/s "
                f"{r['physics_steps_per_s']:,.0f} physics steps/s"
                for r in rows
            )
            + f" ({time.perf_counter() - started:.0f} s elapsed)",
            flush=True,
        )
    _ratio_rows(results)
    print()
    print(table(results))
    print()
    for line in summary(results):
        print(line)
    if args.json:
        from rwalk.rl.checkpoints import atomic_write_text

        atomic_write_text(args.json, json.dumps(results, indent=2))
    if args.plot:
        plot(results, args.plot)
    return results, failed


def main(argv: list[str] | None = None) -> int:
    """Console script ``rwalk-bench``: exit status 1 if measurements failed and none
    succeeded (a skipped one, such as (e) without envpool, is no failure)."""
    args = parse_args(argv)
    if args.worker:
        mode, n, threads, window = args.worker
        worker(mode, int(n), int(threads), float(window))
        return 0
    results, failed = _sweep(args)
    return 1 if failed and not results else 0


if __name__ == "__main__":
    sys.exit(main())
