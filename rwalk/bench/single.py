"""How close one ``ResidualWalkEnv.step`` comes to its physics floor.

The floor of a step is its ``decimation`` physics substeps alone: one
``mujoco.rollout.Rollout.rollout`` call on the same model from the same state
(warmstart included) with the same servo targets, on the calling thread, with a
persistent Rollout object, preallocated outputs, ``skip_checks=True`` and the
controls computed beforehand. A recording pass walks the env under random
actions and keeps each step's start state and servo targets; then rounds
alternate between stepping the env through that walk again (from a pickled
copy) and rolling out the recorded steps, so both see the same physics and the
same machine load. Reported: the fastest round of each, per step, and
floor / step (1 would be no overhead at all).

Run from the command line by ``python -m rwalk.runners.single_bench``.
"""

from __future__ import annotations

import pickle
import time
from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from rwalk.config import EnvConfig
from rwalk.envs.gym_env import ResidualWalkEnv
from rwalk.physics import Physics

#: The physics settings measured: (label, timestep in seconds).
CASES: tuple[tuple[str, float], ...] = (("10 x 2 ms", 0.002), ("5 x 4 ms", 0.004))


@dataclass(frozen=True)
class SingleBench:
    """Per-step times of one case. Microseconds."""

    label: str
    steps: int
    step_us: float
    floor_us: float

    @property
    def ratio(self) -> float:
        """floor / step: the share of a step spent in the physics."""
        return self.floor_us / self.step_us


def _record(env: ResidualWalkEnv, actions: np.ndarray) -> tuple[list, list]:
    """Each step's start state (integration) and servo targets, until the env ends."""
    sim = env.core.sim
    states, controls = [], []
    rollout_all = sim.rollout_all

    def recording(ctrl: np.ndarray) -> bool:
        controls.append(ctrl.copy())
        return rollout_all(ctrl)

    sim.rollout_all = recording  # type: ignore[method-assign]
    try:
        for action in actions:
            states.append(sim.state[0].copy())
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
    finally:
        del sim.rollout_all
    return states, controls


def measure(
    label: str, timestep: float, steps: int = 200, rounds: int = 7, seed: int = 0
) -> SingleBench:
    """Time ``steps`` env steps against their floor, in ``rounds`` alternating rounds."""
    env = ResidualWalkEnv(config=EnvConfig(physics=Physics(timestep=timestep)), seed=seed)
    env.reset(seed=seed)
    snapshot = pickle.dumps(env)
    actions = np.random.default_rng(seed).uniform(-0.5, 0.5, (steps, 12)).astype(np.float32)
    states, controls = _record(env, actions)
    actions = actions[: len(controls)]

    model = env.core.model
    data = mujoco.MjData(model)
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    starts, warmstarts = [], []
    for state in states:
        mujoco.mj_setState(model, data, state, mujoco.mjtState.mjSTATE_INTEGRATION)
        start = np.empty((1, mujoco.mj_stateSize(model, full)))
        mujoco.mj_getState(model, data, start[0], full)
        starts.append(start)
        warmstarts.append(data.qacc_warmstart.copy()[None])
    k = env.core.decimation
    out_state = np.empty((1, k, starts[0].shape[1]))
    out_sensors = np.empty((1, k, model.nsensordata))
    runner = mj_rollout.Rollout(nthread=0)
    models, datas = [model], [data]
    spec = int(mujoco.mjtState.mjSTATE_CTRL.value)

    def floor() -> None:
        for start, warmstart, ctrl in zip(starts, warmstarts, controls, strict=True):
            runner.rollout(
                models, datas, start, ctrl, control_spec=spec, skip_checks=True, nstep=k,
                initial_warmstart=warmstart, state=out_state, sensordata=out_sensors,
            )  # fmt: skip

    best_step = best_floor = float("inf")
    for _ in range(rounds):
        walker = pickle.loads(snapshot)
        start = time.perf_counter()
        for action in actions:
            walker.step(action)
        best_step = min(best_step, time.perf_counter() - start)
        start = time.perf_counter()
        floor()
        best_floor = min(best_floor, time.perf_counter() - start)
    runner.close()
    n = len(actions)
    return SingleBench(label, n, best_step / n * 1e6, best_floor / n * 1e6)
