"""Each mode's measurement, the worker runs that measure a mode, and the worker itself.

- ``MODES_HELP``: what each mode times and how (rwalk-bench's --help prints it).
- ``measure_*`` and ``MEASURES``: a measure function per worker mode, (n, threads,
  window) -> {mode: result row}.
- ``ONLY_MODES`` and ``worker_runs``: the modes --only takes and the worker runs that
  measure them ((a) comes from (b)'s worker, (e) from one worker per terrain).
- ``worker``: one mode, its rows printed as JSON lines (``python -m rwalk.bench.modes
  MODE N THREADS WINDOW``); ``run_worker`` runs it in a fresh process.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import torch

from rwalk.bench import envpool
from rwalk.bench.meters import (
    EnvMeter,
    Floor,
    against_floor,
    config_timing,
    env_stepper,
    floor_result,
    interleaved,
    peak_rss_mb,
    robot_seconds_per_core_second,
    spread_episodes,
    timed,
    training_defaults,
)

#: What each mode times and how, for rwalk-bench's --help.
MODES_HELP = """\
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
  s  two rwalk-train --share-cores runs of N envs sharing the machine: seconds per
     iteration of one alone (with --share-cores, and on fixed threads as the trainers run
     by default), then of each of two started side by side, and their speed over the
     one alone's (rwalk.bench.sharing; threads: the trainings' own)
  r  the cost of the robust training's world: rsl-rl's env step (RslRlVecEnv.step,
     random actions, its observation groups built, no PPO) on three envs of the same
     N in one process, alternating: the plain training env (one rough world), the
     terrain-levels map alone (envs spread over its levels), and the map with
     randomised physics, pushes, latency, observation noise and the privileged critic
  e  EnvPool's MuJoCo Playground ports Go1JoystickRoughTerrain-v1 and
     Go1JoystickFlatTerrain-v1 beside b on world_train and world_flat, same N and
     threads, random actions, alternating, one process per terrain
     (rwalk.bench.envpool). EnvPool's Go1 holds 40-50 MB per env: keep N <= 256.

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


def measure_env(
    n: int, threads: int, window: float, task: str = "residual_walk", mode: str = "b"
) -> dict:
    """``mode`` ((b); (g): the adaptive task's) and its floor (a) on the same robots, timed
    in alternating rounds."""
    gen = torch.Generator().manual_seed(0)
    env, step, first_reset = env_stepper(n, threads, gen, task=task)
    b, a = against_floor(env.core, step, threads, gen, window)
    return {mode: b | first_reset, "a": a}


def measure_scaling(n: int, threads: int, window: float) -> dict:
    """(b) and (a) on 1 thread and on ``threads``, all four in one process, alternating."""
    gen = torch.Generator().manual_seed(0)
    steps, meters, floors = {}, {}, {}
    for t in (1, threads):
        env, steps[f"b{t}"], _ = env_stepper(n, t, gen)
        meters[t] = EnvMeter(env.core)
        floors[t] = Floor(env.core, t, gen)
        steps[f"a{t}"] = floors[t].step
    rounds = interleaved(steps, window)
    rows = {}
    for t in (1, threads):
        rows[f"b{t}"] = meters[t].result(*rounds[f"b{t}"]) | {"threads": t, "mode": "b"}
        rows[f"a{t}"] = floor_result(floors[t], *rounds[f"a{t}"]) | {"threads": t, "mode": "a"}
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
        spread_episodes(vec.core, gen)

        def step(adapter=adapter, gen=gen) -> None:
            adapter.step(torch.rand(n, 12, generator=gen) * 2 - 1)

        step()
        steps[name], meters[name] = step, EnvMeter(vec.core)
    rounds = interleaved(steps, window)
    rows = {name: meters[name].result(*rounds[name]) for name in configs}
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
    """(c): rsl-rl's collection loop on the plain training env, against its floor."""
    from rwalk.rl.config import TrainArgs as Args
    from rwalk.rl.runner import SafeRunner
    from rwalk.rl.training import make_env, rsl_rl_config

    # The plain training env, as in (b) and docs/performance.md; mode r times the robust one.
    args = dataclasses.replace(Args(), num_envs=n, threads=threads, robust=False)
    env = make_env(args)
    runner = SafeRunner(env, rsl_rl_config(args), log_dir=None, device="cpu")
    alg = runner.alg
    spread_episodes(env.core, torch.Generator().manual_seed(0))
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
    c, _ = against_floor(env.core, step, threads, torch.Generator().manual_seed(1), window)
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
    """(d): a gymnasium vector env of n single envs, in 1 process or ``processes``."""
    import gymnasium

    config = dataclasses.replace(training_defaults(1, 1), settle_pool=0)
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
    calls, seconds = timed(step, window)
    vec.close()
    timing = config_timing(config)
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
    """(e) on one terrain: rwalk beside EnvPool's Go1 (rwalk.bench.envpool)."""

    def measure(n: int, threads: int, window: float) -> dict:
        return envpool.measure(terrain, n, threads, window)

    return measure


#: The measure function of each worker mode: (n, threads, window) -> {mode: row}.
MEASURES = {
    "b": measure_env,
    "g": lambda n, threads, window: measure_env(n, threads, window, "adaptive_gait", "g"),
    "c": measure_rsl_rl,
    "d": measure_gym,
    "t": measure_scaling,
    "r": measure_robust,
    # (e) runs one process per terrain: EnvPool's pools are too large to hold two.
    "e/rough": measure_envpool("rough"),
    "e/flat": measure_envpool("flat"),
}

#: Modes --only accepts; (a) is measured by the same worker as (b), on its robots, and
#: (e) by one worker per terrain.
ONLY_MODES = ("a", "b", "c", "d", "e", "g", "r", "s", "t")


def worker_runs(only: list[tuple[str, int, int]]) -> list[tuple[str, int, int]]:
    """The worker runs that measure ``only``: (a) comes from (b)'s worker, (e) from one
    worker per terrain (a single run that reports the skip where envpool is missing);
    no run twice."""
    terrains = ("e",) if envpool.envpool_missing() else ("e/rough", "e/flat")
    runs = []
    for mode, n, threads in only:
        worker_modes = {"a": ("b",), "e": terrains}.get(mode, (mode,))
        runs += [(worker_mode, n, threads) for worker_mode in worker_modes]
    return list(dict.fromkeys(runs))


def worker(mode: str, n: int, threads: int, window: float) -> None:
    """Measure one configuration; print each result row as a JSON line.

    Modes b and g also measure the floor (a), on the same robots, alternating."""
    torch.set_num_threads(max(threads, 1) if threads else os.cpu_count() or 1)
    rows = MEASURES[mode](n, threads, window)
    for key, row in rows.items():
        row.setdefault("peak_rss_mb", peak_rss_mb())
        row.setdefault("threads", threads)
        row.setdefault("mode", key)
        row["n"] = n
        row["robot_seconds_per_core_second"] = robot_seconds_per_core_second(row)
        print("RESULT " + json.dumps(row), flush=True)


class WorkerFailed(RuntimeError):
    """A worker process exited with an error or printed no result row; the message is
    the end of its stderr."""


def run_worker(mode: str, n: int, threads: int, window: float) -> list[dict]:
    """Run worker() in a fresh Python process (its own peak RSS); its result rows.

    Raises:
        WorkerFailed: carrying the last 2,000 characters of the worker's stderr."""
    command = [sys.executable, "-m", "rwalk.bench.modes", mode, str(n), str(threads), str(window)]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    if done.returncode != 0 or not lines:
        raise WorkerFailed(done.stderr[-2000:])
    return [json.loads(line[len("RESULT ") :]) for line in lines]


if __name__ == "__main__":  # python -m rwalk.bench.modes MODE N THREADS WINDOW
    mode, n, threads, window = sys.argv[1:]
    worker(mode, int(n), int(threads), float(window))
