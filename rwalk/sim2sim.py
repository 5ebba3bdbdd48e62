"""Sim-to-sim: the torch-free runtime (``rwalk.deploy``) on plain MuJoCo, against the env.

``closed_loop`` runs the env's evaluation (N envs, each from its own start) and,
beside it, one ``rwalk.deploy.Controller`` per env driving its own ``MjData``
with ``mujoco.mj_step``: the same model (``get_model`` of the env's batch, so the
same drawn physics), the same start state (``get_data``), the same gait tick.
The env's policy is the same ONNX file, run by onnxruntime on the env's own
policy input, so that the comparison isolates the runtime: its observation,
gait, inverse kinematics and stepping against the env's. Each control period
the two robots' ``qpos`` and ``qvel`` are compared bit for bit until the env's
episode ends.

``policy_gap`` measures the one step that differs when the env runs the
checkpoint's torch policy instead: the actions of torch's matmuls against
onnxruntime's on the same inputs (a few float32 ulp), a gap the closed loop then
grows (the walk is chaotic).

``walk`` runs the runtime alone on any world XML from the robot's standing
keyframe, settled first as the env settles its starts (``Settle``: the env's
zero-residual gait, here on the world's own ``mj_step``): falls and velocity error
of a deployed policy on a world of the user's choice.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import torch

from rwalk import episodes
from rwalk.constants import OBS_LINVEL, OBS_QUAT, STAND_KEYFRAME
from rwalk.deploy import Controller
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.physics import Physics
from rwalk.rewards import fallen, quat_to_rpy
from rwalk.rl.rsl_rl_env import RslRlVecEnv
from rwalk.starts import SETTLE_ATTEMPTS, SettleError

#: Most physics steps a world may take per runtime substep (``walk``: each target is held
#: over as many of the world's timesteps as fill the runtime's).
MAX_HOLD = 1000


@dataclass(frozen=True)
class Trace:
    """One episode of the runtime against the env's, on the same physics."""

    env: int
    """The env's index (its start: a single env seeded seed + env)."""
    steps: int
    """Control periods compared (to the end of the env's episode)."""
    first_difference: int | None
    """The first period after which qpos or qvel differ in any bit; None: none did."""
    max_difference: float
    """The largest |Δqpos| or |Δqvel| over the compared periods (0.0: bit-identical)."""


def closed_loop(folder: Path, env: BatchedEnv, seed: int, steps: int) -> list[Trace]:
    """Step the env's evaluation and one runtime per env in lockstep (see the module).

    Args:
        folder: the export folder (``policy.onnx``, ``policy.json``).
        env: the evaluation's envs, of the policy's task and pieces.
        seed: env i starts like a single env seeded seed + i.
        steps: control periods at most (episodes end earlier when they fall).
    """
    core = env.core
    n = core.num_envs
    controllers = [Controller(folder) for _ in range(n)]
    adapter = RslRlVecEnv(env, policy_obs=controllers[0].pieces, critic_obs=(), reward_scale=1.0)
    session = controllers[0].session
    env.set_seed(seed)
    core.reset()
    batch = core.sim.batch
    models = [batch.get_model(i) for i in range(n)]
    datas = [batch.get_data(i) for i in range(n)]
    state = [np.zeros((s[0], n, s[2]), np.float32) for s in controllers[0].state_shapes]
    names = controllers[0].state_names
    # The env's readings: sensors of the last settling substep's start, as mj_step leaves
    # them (get_data does not carry them; an mj_forward would read the state after it).
    readings = core.sim.sensordata.copy()
    for i, controller in enumerate(controllers):
        controller.reset(readings[i], tick=core.world.settled_tick)
        controller.command = float(core.task.target[i])  # read only by a commanded policy
    alive = np.ones(n, dtype=bool)
    first: list[int | None] = [None] * n
    worst = np.zeros(n)
    walked = np.zeros(n, dtype=int)
    with torch.inference_mode():
        for step in range(steps):
            obs = adapter.get_observations()["policy"].numpy()
            action, *state = session.run(None, {"obs": obs, **dict(zip(names, state, strict=True))})
            _, end = episodes.step(core, torch.from_numpy(action), auto_reset=False)
            for i in np.flatnonzero(alive):
                data = datas[i]
                for row in controllers[i].step(readings[i]):
                    data.ctrl[:] = row
                    mujoco.mj_step(models[i], data)
                readings[i] = data.sensordata
                gap = max(np.abs(data.qpos - core.sim.qpos[i]).max(),
                          np.abs(data.qvel - core.sim.qvel[i]).max())  # fmt: skip
                worst[i] = max(worst[i], gap)
                if first[i] is None and not (
                    np.array_equal(data.qpos, core.sim.qpos[i])
                    and np.array_equal(data.qvel, core.sim.qvel[i])
                ):
                    first[i] = step + 1
                walked[i] = step + 1
            if end is not None:
                alive[end.ids.numpy()] = False
            if not alive.any():
                break
    return [Trace(i, int(walked[i]), first[i], float(worst[i])) for i in range(n)]


def policy_gap(policy, folder: Path) -> float:
    """The largest |torch action - ONNX action| on the current inputs of ``policy``'s env
    (an ``rwalk.evaluation.Policy``, fresh memory), in action units."""
    controller = Controller(folder)
    obs = policy.adapter.get_observations()["policy"].numpy()
    n = obs.shape[0]
    state = {
        name: np.zeros((s[0], n, s[2]), np.float32)
        for name, s in zip(controller.state_names, controller.state_shapes, strict=True)
    }
    onnx_action = controller.session.run(None, {"obs": obs, **state})[0]
    policy.reset()
    torch_action = policy().numpy()
    return float(np.abs(onnx_action - torch_action).max())


@dataclass(frozen=True)
class Walk:
    """Episodes of the runtime alone on a world XML."""

    world: str
    episodes: int
    fall_rate: float
    fall_rate_se: float
    velocity_error: float
    """Mean over episodes of each episode's mean |v_x - v*| per control period (m/s)."""
    velocity_error_se: float
    forward_velocity: float


@dataclass(frozen=True)
class Settle:
    """How the env settles a start, for ``walk`` to repeat on a world's own ``mj_step``:
    ``settle_steps`` control periods of the zero-residual gait from phase 0."""

    ctrl: np.ndarray
    """The servo targets of settling, one row per runtime substep
    (``rwalk.starts.Starts.settle_ctrl``). Shape: (settle_steps x K, 12)."""
    tick: int
    """The gait tick where settling leaves a start (``rwalk.world.World.settled_tick``)."""

    @classmethod
    def of(cls, core) -> Settle:
        """The settling of ``core``'s starts (its config's settle_steps)."""
        return cls(np.asarray(core.starts.settle_ctrl), int(core.world.settled_tick))


def hold_of(world: Path | str, timestep: float, dt: float) -> int:
    """The physics steps of ``world`` (its ``timestep``) that fill one runtime substep of
    ``dt`` seconds.

    Raises:
        ValueError: naming the world, unless the timestep is a number > 0 that divides
            ``dt`` into at most MAX_HOLD steps.
    """
    ratio = dt / timestep if timestep > 0 and math.isfinite(timestep) else math.nan
    hold = round(ratio) if math.isfinite(ratio) else 0
    if not (1 <= hold <= MAX_HOLD and math.isclose(hold * timestep, dt, rel_tol=1e-9)):
        raise ValueError(f"{world}: timestep {timestep:g} s does not divide the runtime's "
                         f"{dt:g} s into at most {MAX_HOLD} steps")  # fmt: skip
    return hold


def check_world(world: Path, dt: float) -> None:
    """Fail before any walk unless the runtime can walk on ``world``: it loads, has the
    robot's standing keyframe, and its timestep divides the runtime's ``dt``.

    Raises:
        ValueError: naming the world (MuJoCo's own message for an XML it cannot load).
    """
    model = mujoco.MjModel.from_xml_path(str(world))
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, STAND_KEYFRAME) < 0:
        raise ValueError(f"{world}: no keyframe {STAND_KEYFRAME!r} (the robot's standing pose)")
    hold_of(world, float(model.opt.timestep), dt)


def walk(
    folder: Path,
    world: Path,
    count: int,
    steps: int,
    v_target: float,
    seed: int = 0,
    physics: Physics | None = None,
    settle: Settle | None = None,
) -> Walk:
    """``count`` episodes of at most ``steps`` periods: falls (|roll| or |pitch| > π/3)
    and velocity error.

    Each starts from the standing keyframe (x, y jittered ±5 cm by ``seed``) and is
    settled as the env settles its starts: the rows of ``settle`` held in turn, a start
    that falls or diverges drawn again (up to SETTLE_ATTEMPTS times); the policy then
    walks from the gait tick where settling leaves it, as in the env's evaluation.
    ``settle`` None: no settling, the gait from phase 0. ``physics``: settings applied to
    the world's model (each of the runtime's targets is then held over as many of its
    substeps as fill ``dt``).

    Raises:
        ValueError: naming the world, for a timestep that does not divide the runtime's.
        SettleError: naming the world, if starts fall while settling in every attempt.
    """
    model = mujoco.MjModel.from_xml_path(str(world))
    if physics is not None:
        physics.apply(model)
    data = mujoco.MjData(model)
    controller = Controller(folder)
    hold = hold_of(world, float(model.opt.timestep), controller.dt)
    if "command" in controller.pieces:
        controller.command = v_target
    rng = np.random.default_rng(seed)
    falls, errors, speeds = np.zeros(count), np.zeros(count), np.zeros(count)
    for episode in range(count):
        readings = _settled_start(model, data, rng, hold, settle, world)
        controller.reset(readings, tick=0 if settle is None else settle.tick)
        velocities = []
        for _ in range(steps):
            for row in controller.step(readings):
                data.ctrl[:] = row
                mujoco.mj_step(model, data, nstep=hold)
            readings = data.sensordata.copy()
            velocities.append(float(readings[OBS_LINVEL.start]))
            if _fallen(readings):
                falls[episode] = 1.0
                break
        errors[episode] = np.mean(np.abs(np.asarray(velocities) - v_target))
        speeds[episode] = np.mean(velocities)
    return Walk(str(world), count, float(falls.mean()), _se(falls), float(errors.mean()),
                _se(errors), float(speeds.mean()))  # fmt: skip


def _fallen(readings: np.ndarray) -> bool:
    """Whether the robot of these readings fell (or its state diverged)."""
    if not np.isfinite(readings).all():
        return True
    return bool(fallen(quat_to_rpy(tuple(readings[OBS_QUAT].tolist()))))


def _settled_start(model, data, rng: np.random.Generator, hold: int, settle: Settle | None,
                   world: Path) -> np.ndarray:  # fmt: skip
    """Place a start in ``data`` (the standing keyframe, x and y jittered by ``rng``) and
    settle it (``walk``); returns its readings, as ``mj_step`` leaves them."""
    key = model.keyframe(STAND_KEYFRAME).id
    for _ in range(SETTLE_ATTEMPTS):
        mujoco.mj_resetDataKeyframe(model, data, key)
        data.qpos[:2] += rng.uniform(-0.05, 0.05, 2)
        mujoco.mj_forward(model, data)
        if settle is None:
            return data.sensordata.copy()
        for row in settle.ctrl:
            data.ctrl[:] = row
            mujoco.mj_step(model, data, nstep=hold)
        readings = data.sensordata.copy()
        if not _fallen(readings):
            return readings
    raise SettleError(
        f"{world}: starts fell or diverged while settling ({len(settle.ctrl)} substeps of "
        f"the base gait) in each of {SETTLE_ATTEMPTS} attempts"
    )


def step_latency(folder: Path, world: Path, steps: int) -> dict[str, float]:
    """Wall time of ``Controller.step`` (readings in, targets out, the ONNX policy on one
    thread included) over ``steps`` periods of a walk on ``world`` from standing: the
    median and 90th percentile, microseconds. Physics steps are not timed."""
    model = mujoco.MjModel.from_xml_path(str(world))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.keyframe(STAND_KEYFRAME).id)
    mujoco.mj_forward(model, data)
    controller = Controller(folder, threads=1)
    if "command" in controller.pieces:
        controller.command = 0.15
    targets = controller.reset(data.sensordata)
    times = np.zeros(steps)
    for step in range(steps):
        for row in targets:
            data.ctrl[:] = row
            mujoco.mj_step(model, data)
        readings = data.sensordata.copy()
        start = time.perf_counter()
        targets = controller.step(readings)
        times[step] = time.perf_counter() - start
    return {"median_us": float(np.median(times) * 1e6),
            "p90_us": float(np.percentile(times, 90) * 1e6), "steps": steps}  # fmt: skip


def _se(values: np.ndarray) -> float:
    return float(values.std(ddof=1) / math.sqrt(len(values))) if len(values) > 1 else 0.0


def walk_table(walks: list[dict], band: float) -> str:
    """Markdown: each world's falls and velocity error under the env's physics and the
    reference's, and whether the difference lies within ``band`` reference standard errors."""
    lines = ["| world | physics | falls | velocity error (m/s) | within the band |",
             "| --- | --- | --- | --- | --- |"]  # fmt: skip
    by_world: dict[str, dict[str, dict]] = {}
    for row in walks:
        by_world.setdefault(row["world"], {})[row["physics"]] = row
    for world, rows in by_world.items():
        reference = rows.get("reference")
        for name, row in rows.items():
            within = ""
            if reference is not None and row is not reference:
                checks = [
                    abs(row[key] - reference[key]) <= band * max(reference[key + "_se"], floor)
                    for key, floor in (("fall_rate", 0.01), ("velocity_error", 0.002))
                ]
                within = "yes" if all(checks) else "no"
            falls = f"{row['fall_rate']:.0%} ± {row['fall_rate_se']:.0%}"
            error = f"{row['velocity_error']:.4f} ± {row['velocity_error_se']:.4f}"
            lines.append(f"| {Path(world).name} | {name} | {falls} | {error} | {within} |")
    return "\n".join(lines)
