"""What every benchmark mode measures with: timing windows, alternating rounds, the floor.

- ``timed`` and ``interleaved``: call a step for a window of seconds; alternate
  several steps in rounds so the machine's drift lands evenly on each.
- ``Floor``: plain ``mujoco.rollout`` on an env's own robots and workload.
- ``EnvMeter``: what a core did while its steps were timed (throughput, settling,
  time in MuJoCo); ``floor_result`` the same row for a Floor.
- ``env_stepper`` (a batched env and its step with random actions) and
  ``against_floor`` (an env's step timed beside its Floor).
- ``physics_timing``, ``robot_seconds_per_core_second`` and ``peak_rss_mb``:
  the simulated time behind a step and the figures every result row carries.

Nothing here imports the modes, the EnvPool contender or the reports.
"""

from __future__ import annotations

import dataclasses
import os
import resource
import time
from collections.abc import Callable

import numpy as np
import torch

#: Alternating rounds per measurement.
ROUNDS = 4


def training_defaults(threads: int, n: int, task: str = "residual_walk"):
    """The training defaults of ``task`` for n envs on the given number of threads."""
    from rwalk.presets import training_config

    return training_config(task, num_envs=n, threads=threads)


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far. MB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def timed(step: Callable[[], float | None], window: float, min_steps: int = 3) -> tuple[int, float]:
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


def interleaved(steps: dict, window: float, rounds: int = ROUNDS) -> dict[str, tuple]:
    """Time each step() for window / rounds seconds in turn, rounds times over.

    Alternating spreads the machine's drifts and noise evenly over the contenders,
    so their ratios hold even where absolute figures wander. Returns key -> (calls,
    seconds) summed over the rounds."""
    totals = {key: (0, 0.0) for key in steps}
    for _ in range(rounds):
        for key, step in steps.items():
            calls, seconds = timed(step, window / rounds)
            totals[key] = (totals[key][0] + calls, totals[key][1] + seconds)
    return totals


def physics_timing(core) -> dict:
    """The simulated time behind a core's env step: control period, substeps, timestep.

    Seconds; read from the core (its world's timestep, overrides applied), never assumed."""
    return {"control_dt_s": core.control_dt, "substeps": core.decimation, "timestep_s": core.dt}


def config_timing(config) -> dict:
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


def spread_episodes(core, generator: torch.Generator) -> None:
    """Start every env's episode at a random step of its length, as rsl-rl's
    init_at_random_ep_len does: resets then happen at their long-run rate."""
    high = core.config.max_episode_steps
    core.episode_step.copy_(torch.randint(0, high, core.episode_step.shape, generator=generator))


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
        """One control period of all n robots; the seconds spent in the rollout."""
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


def floor_result(floor: Floor, calls: int, seconds: float) -> dict:
    """The result row of a Floor that made ``calls`` steps in ``seconds``."""
    return {
        "env_steps_per_s": calls * floor.n / seconds,
        "physics_steps_per_s": calls * floor.n * floor.k / seconds,
        "settle_share": 0.0,
    } | floor.timing


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
        """The result row of ``calls`` env steps timed at ``seconds``, since construction."""
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


def env_stepper(
    n: int,
    threads: int,
    gen: torch.Generator,
    model_path: str | None = None,
    task: str = "residual_walk",
):
    """A batched env of ``task`` with the training defaults (on another world if
    model_path is given), episodes spread, and its step(); (env, step, first-reset row)."""
    from rwalk import ResidualWalkVecEnv

    config = training_defaults(threads, n, task)
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
    spread_episodes(env.core, gen)
    torch_threads = threads or os.cpu_count() or 1

    def step() -> None:
        nonlocal td
        torch.set_num_threads(torch_threads)
        td.set("action", torch.rand(n, width, generator=gen) * 2 - 1)
        _, td = env.step_and_maybe_reset(td)

    step()  # the first partial resets fill the pool
    return env, step, first_reset


def against_floor(core, step, threads: int, gen: torch.Generator, window: float):
    """Time step() and a Floor on core's robots in alternating rounds; (row, floor row).

    The row carries its floor's physics steps/s and the peak RSS before the floor
    allocated its buffers."""
    timed(step, window / ROUNDS)  # a first round before the floor allocates its buffers
    peak_rss = peak_rss_mb()
    meter = EnvMeter(core)
    floor = Floor(core, threads, gen)
    rounds = interleaved({"env": step, "a": floor.step}, window)
    a = floor_result(floor, *rounds["a"])
    row = meter.result(*rounds["env"]) | {"peak_rss_mb": peak_rss}
    row["floor_physics_steps_per_s"] = a["physics_steps_per_s"]
    return row, a
