"""Mode (e) of rwalk-bench: rwalk beside EnvPool's Go1 joystick envs, in one process.

EnvPool (the optional ``bench`` extra) ships C++ ports of MuJoCo Playground's tasks.
Its ``Go1JoystickRoughTerrain-v1`` and ``Go1JoystickFlatTerrain-v1`` are another
quadruped stepped in batches on the CPU: this mode times one of them and rwalk's
batched env on the matching world (``world_train`` vs rough, ``world_flat`` vs
flat), same N, same thread count, random actions, in alternating rounds.

The robots differ (Go1 vs rwalk's quadruped) and so does the physics (Go1: 4 ms
Euler, 1 solver iteration, feet-only contacts), so env steps/s alone says little:
the figure compared is simulated robot-seconds per core-second, env steps/s x
control period / threads. Each side's control period is read from its own
config (rwalk's ``core.control_dt``, EnvPool's ``ctrl_dt``), never assumed.

Memory: each side's resident memory added by building it and taking its first
steps (current RSS, /proc/self/statm), per env. EnvPool's Go1 holds 40-50 MB
per env, so N is capped by the memory this machine has free (see
``check_memory``); rwalk's N >= 1024 figures come from mode (b).

Built on ``rwalk.bench.meters`` (rwalk's side is mode (b)'s env and meter);
``rwalk.bench.modes`` runs it, never the other way round.
"""

from __future__ import annotations

import importlib.util
import os
import time

import numpy as np
import torch

from rwalk.bench.meters import (
    EnvMeter,
    env_stepper,
    interleaved,
    peak_rss_mb,
    robot_seconds_per_core_second,
)

#: (rwalk world, EnvPool task) per terrain.
TERRAINS = {
    "rough": ("model/world_train.xml", "Go1JoystickRoughTerrain-v1"),
    "flat": ("model/world_flat.xml", "Go1JoystickFlatTerrain-v1"),
}

#: Resident memory of EnvPool's Go1 joystick envs, measured with envpool 1.2.5
#: (rough, N=16: 1.0 GB, N=64: 2.9 GB, N=256: 10.4 GB; flat, N=256: 12.4 GB),
#: rounded up: MB per env and MB for the pool.
ENVPOOL_MB_PER_ENV = 50.0
ENVPOOL_MB_FIXED = 500.0

MISSING = "envpool is not installed (pip install -e '.[bench]' adds it)"


def envpool_missing() -> str | None:
    """Why mode (e) cannot run here, or None when envpool can be imported."""
    try:
        found = importlib.util.find_spec("envpool") is not None
    except (ImportError, ValueError):
        found = False
    return None if found else MISSING


def _rss_mb() -> float:
    """Current resident memory of this process. MB."""
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _available_mb() -> float | None:
    """MemAvailable of /proc/meminfo (MB), or None where there is none."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def check_memory(n: int, available_mb: float | None) -> None:
    """Refuse an N whose EnvPool pool would not fit, with room to spare.

    Raises:
        MemoryError: naming N, the estimate and what is available."""
    need = ENVPOOL_MB_FIXED + ENVPOOL_MB_PER_ENV * n
    if available_mb is not None and need > 0.8 * available_mb:
        raise MemoryError(
            f"N={n}: EnvPool's Go1 needs about {need / 1024:.1f} GB "
            f"({ENVPOOL_MB_PER_ENV:.0f} MB per env), more than 80% of the "
            f"{available_mb / 1024:.1f} GB available: choose a smaller N"
        )


class _Contender:
    """A step() that tallies the process's CPU seconds (all its threads) and resets."""

    def __init__(self, step) -> None:
        self._step = step
        self.cpu, self.resets = 0.0, 0

    def step(self) -> None:
        start = time.process_time()
        self.resets += self._step() or 0
        self.cpu += time.process_time() - start


def _rwalk(n: int, threads: int, world: str) -> tuple[_Contender, EnvMeter, float]:
    """rwalk's batched env on ``world``; (contender, its EnvMeter, MB it added)."""
    before = _rss_mb()
    env, step, _ = env_stepper(n, threads, torch.Generator().manual_seed(0), world)
    contender = _Contender(step)
    contender.step()
    return contender, EnvMeter(env.core), _rss_mb() - before


def _envpool(n: int, threads: int, task: str) -> tuple[_Contender, dict, float]:
    """EnvPool's ``task`` with N envs on ``threads`` threads, stepped synchronously
    (batch_size = N) with uniform random actions; (contender, timing facts, MB added)."""
    import envpool

    check_memory(n, _available_mb())
    before = _rss_mb()
    env = envpool.make_gymnasium(task, num_envs=n, batch_size=n, num_threads=threads, seed=0)
    config = env.spec.config
    substeps = round(config.ctrl_dt / config.sim_dt)
    env.reset()
    space = env.action_space
    rng = np.random.default_rng(0)

    def step() -> int:
        actions = rng.uniform(space.low, space.high, (n, *space.shape)).astype(space.dtype)
        _, _, terminated, truncated, _ = env.step(actions)
        return int(np.sum(terminated | truncated))

    contender = _Contender(step)
    contender.step()
    timing = {"control_dt_s": float(config.ctrl_dt), "substeps": substeps}
    timing |= {"timestep_s": float(config.sim_dt), "task": task}
    return contender, timing, _rss_mb() - before


def measure(terrain: str, n: int, threads: int, window: float) -> dict:
    """rwalk and EnvPool's Go1 on ``terrain``, timed in alternating rounds.

    Returns {"rwalk": row, "envpool": row}; the rwalk row carries the ratio of the
    two robot-seconds per core-second."""
    world, task = TERRAINS[terrain]
    ours, meter, ours_mb = _rwalk(n, threads, world)
    theirs, timing, theirs_mb = _envpool(n, threads, task)
    theirs.cpu = theirs.resets = ours.cpu = 0
    timed = interleaved({"rwalk": ours.step, "envpool": theirs.step}, window)
    calls, seconds = timed["envpool"]
    rows = {
        "rwalk": meter.result(*timed["rwalk"]) | {"task": world},
        "envpool": {
            "env_steps_per_s": calls * n / seconds,
            "physics_steps_per_s": calls * n * timing["substeps"] / seconds,
            "settle_share": 0.0,  # a Playground reset runs no physics
            "resets_per_step": theirs.resets / calls,
        }
        | timing,
    }
    for key, contender, added_mb in (("rwalk", ours, ours_mb), ("envpool", theirs, theirs_mb)):
        rows[key] |= {
            "mode": "e",
            "terrain": terrain,
            "contender": key,
            "threads": threads,
            "cores_busy": contender.cpu / timed[key][1],
            "memory_added_mb": added_mb,
            "memory_per_env_mb": added_mb / n,
            "peak_rss_mb": peak_rss_mb(),
        }
        rows[key]["robot_seconds_per_core_second"] = robot_seconds_per_core_second(rows[key])
    rows["rwalk"]["ratio_to_envpool"] = (
        rows["rwalk"]["robot_seconds_per_core_second"]
        / rows["envpool"]["robot_seconds_per_core_second"]
    )
    return rows
