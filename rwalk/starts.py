"""Starts: each new episode's state, placed above the ground and settled by the base gait.

A start stands in the gait's phase-0 pose at its origin (``origins``: the env's
tile pad on a map, else the config's start position), perturbed by the config's
start-pose noise when asked (``randomize``), with its lowest foot just above the
highest ground under it. It is then settled: ``settle_steps`` env steps of the
zero-residual gait, all resetting envs in one batched rollout. A start that
falls or diverges while settling is redrawn.

Keys: env i of a core seeded s draws its k-th start (redraws included) from the
key (s + i mod 2^64, "start_pose", k) of ``rwalk.rng``; the k-th refill of
settled-start pool entry j draws like an env N + j would. So env i starts
exactly like a single env seeded s + i at every reset settled in place (a
partial reset served from the pool takes the pool's next entry instead).

The settled-start pool (``settle_pool`` > 0) keeps settled starts ready in a
batch of its own, on the pad of tile (0, 0) with the model's physics; a start
taken from it is moved to the env's origin (every pad is flat at height 0, so
only x and y change).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

from rwalk import exactmath, rng
from rwalk.config import EnvConfig
from rwalk.constants import OBS_CONTACT, OBS_DIM, OBS_POS, OBS_QUAT
from rwalk.rewards import fallen, quat_to_rpy
from rwalk.sim import BatchedSim
from rwalk.validation import InputError
from rwalk.world import World

#: Attempts at a start that does not fall or diverge while settling.
SETTLE_ATTEMPTS = 5
#: Most servo-target values held at once while settling (bounds memory).
SETTLE_CTRL_BUDGET = 2_000_000
#: Clearance of the lowest foot above the highest ground under the robot at a start.
START_CLEARANCE = 0.004
#: Half-width of the square searched for the highest ground under a start.
FOOTPRINT_RADIUS = 0.13
#: Random stream of the start poses (see ``rwalk.rng``).
START_STREAM = "start_pose"


class SettleError(InputError):
    """Starts that fall or diverge while settling in every attempt: the start-pose noise,
    the world or its randomised physics are too hard for the base gait."""


def sensor_observation(sensors: Tensor) -> Tensor:
    """Spec observations from sensor rows: contact counts become 0/1. (M, 65) -> (M, 65)."""
    obs = sensors.clone()
    obs[:, OBS_CONTACT] = (obs[:, OBS_CONTACT] > 0).to(obs.dtype)
    return obs


def sensor_rows(sim: BatchedSim) -> Tensor:
    """The simulation's sensor rows as a tensor sharing their memory. Shape: (M, nsensordata)."""
    with warnings.catch_warnings():  # sensordata is a read-only output; we only read it
        warnings.simplefilter("ignore", UserWarning)
        return torch.from_numpy(sim.sensordata)


class Starts:
    """Places, settles and hands out the starts of N envs.

    Args:
        config: the task's config (settling, start-pose noise, pool).
        world: the model, terrain and gait.
        sim: the N envs' simulations.
        origins: nominal start (x, y) of env ids, or of the pool for None
            (``Curriculum.origins``). Shape: (M, 2) or (2,). Metres.
        physics_steps: counters; settling adds its substeps to ``"settle"``.
    """

    def __init__(
        self,
        config: EnvConfig,
        world: World,
        sim: BatchedSim,
        origins: Callable[[np.ndarray | None], np.ndarray],
        physics_steps: dict[str, int],
    ) -> None:
        self.config = config
        self.world = world
        self.sim = sim
        self.origins = origins
        self.physics_steps = physics_steps
        self.num_envs = sim.num_sims
        self._sensors = sensor_rows(sim)
        decimation = world.decimation
        self.settle_ctrl = world.base_gait_ctrl(config.settle_steps * decimation)
        """Servo targets of settling, from phase 0. Shape: (settle_steps x K, 12)."""
        self._stand_joints = world.base_gait_ctrl(1)[0]
        tail = self.settle_ctrl[-decimation:]
        self.settle_tail = tail if len(tail) == decimation else world.base_gait_ctrl(decimation)
        """The last K servo targets of settling (a delayed first step applies them).
        Shape: (K, 12)."""
        self.pool = _StartPool(world, config) if config.settle_pool else None
        """Settled starts kept ready for partial resets, or None."""
        self.progress: Callable[[int, int], None] | None = None
        """Called with (physics steps done, total) of each settle: 0 first, then per chunk."""
        self.seed(0)

    def seed(self, seed: int) -> None:
        """Key the starts by ``seed`` and restart every env's and pool entry's counter."""
        self._seed = seed
        pool_size = self.pool.size if self.pool is not None else 0
        self.drawn = np.zeros(self.num_envs + pool_size, dtype=np.uint64)
        """Starts drawn so far by each env, then by each pool entry. Shape: (N + pool,)."""

    def place(self, ids: np.ndarray, randomize: bool) -> Tensor:
        """New settled starts in rows ``ids`` of the simulation: from the pool for a
        partial reset when the config has one (and the same start-pose noise), else
        settled in place, all in one batched rollout.

        Returns:
            Their spec observations. Shape: (M, 65).
        """
        pool = self.pool
        if (
            pool is not None
            and ids.size <= pool.size
            and ids.size < self.num_envs
            and randomize == self.config.randomize
        ):
            entries = pool.take(
                ids.size, lambda stale: self._settle_fresh(pool.sim, stale, randomize)
            )
            self.sim.state[ids] = pool.sim.state[entries]
            obs = pool.obs[torch.from_numpy(entries)]
            if self.world.terrain_map is not None:
                # Pool starts settle on the pad of tile (0, 0); every pad is flat at height 0.
                shift = self.origins(ids) - self.origins(None)
                self.sim.qpos[ids, 0:2] += shift
                obs[:, OBS_POS.start : OBS_POS.start + 2] += torch.from_numpy(shift)
            return obs
        self._settle_fresh(self.sim, ids, randomize)
        return sensor_observation(self._sensors[torch.from_numpy(ids.astype(np.int64))])

    def _settle_fresh(self, sim: BatchedSim, ids: np.ndarray, randomize: bool) -> None:
        """Place fresh starts in rows ``ids`` of ``sim`` and settle them; redraw
        the ones that fall or diverge (up to SETTLE_ATTEMPTS tries).

        Raises:
            SettleError: if some starts still fall or diverge after every attempt.
        """
        # Env i draws as seed + i, pool entry j as seed + N + j (see the module docstring).
        first = 0 if sim is self.sim else self.num_envs
        todo = ids
        for _ in range(SETTLE_ATTEMPTS):
            rows = todo.astype(np.uint64) + np.uint64(first)
            seeds = np.uint64(self._seed) + rows  # wraps modulo 2^64
            keys = rng.keys(seeds, START_STREAM, self.drawn[rows])
            self.drawn[rows] += np.uint64(1)
            self._place(sim, todo, keys, randomize)
            todo = todo[self._settle(sim, todo)]
            if todo.size == 0:
                return
        cfg = self.config
        causes = (
            f"start-pose noise randomize={randomize}, tilt_noise={cfg.tilt_noise}, "
            f"yaw_noise={cfg.yaw_noise}, position_noise={cfg.position_noise}"
        )
        if cfg.randomization is not None and sim is self.sim:
            causes += f"; the envs' randomised physics {cfg.randomization}"
        raise SettleError(
            f"{todo.size} of {ids.size} starts fell or diverged while settling, in each of "
            f"{SETTLE_ATTEMPTS} attempts: the starts are too hard for the base gait "
            f"({causes}; world {cfg.model_path}); reduce the noise or the randomisation"
        )

    def _place(self, sim: BatchedSim, ids: np.ndarray, keys: np.ndarray, randomize: bool) -> None:
        """Write fresh starts (standing in the phase-0 gait pose) into rows ``ids``."""
        cfg, world = self.config, self.world
        m = ids.size
        if randomize:
            u = 2.0 * rng.uniform(keys, 5) - 1.0
            dx, dy = u[:, 0] * cfg.position_noise[0], u[:, 1] * cfg.position_noise[1]
            roll, pitch, yaw = (
                u[:, 2] * cfg.tilt_noise,
                u[:, 3] * cfg.tilt_noise,
                u[:, 4] * cfg.yaw_noise,
            )
        else:
            dx = dy = roll = pitch = yaw = np.zeros(m)
        origin = self.origins(ids if sim is self.sim else None)
        x = origin[..., 0] + dx
        y = origin[..., 1] + dy
        ground = world.terrain.max_height(x, y, FOOTPRINT_RADIUS)
        foot_bottom = world.controller.stance_z - world.geometry.foot_radius
        z = ground + START_CLEARANCE - foot_bottom
        sim.reset(ids)
        qpos = sim.qpos
        qpos[ids, 0] = x
        qpos[ids, 1] = y
        qpos[ids, 2] = z
        qpos[ids, 3:7] = rpy_to_quat(roll, pitch, yaw).numpy()
        qpos[ids, world.joint_qpos] = self._stand_joints

    def _settle(self, sim: BatchedSim, ids: np.ndarray) -> np.ndarray:
        """Run the zero-residual gait on rows ``ids`` for settle_steps env steps.

        Returns:
            Rows that fell or diverged. Shape: (M,) bool.
        """
        failed = np.zeros(ids.size, dtype=bool)
        total = self.settle_ctrl.shape[0]
        if total == 0:
            failed |= sim.forward(ids)
        else:
            chunk = max(1, SETTLE_CTRL_BUDGET // (ids.size * self.settle_ctrl.shape[1]))
            report = self.progress or (lambda done, total: None)
            report(0, ids.size * total)
            for start in range(0, total, chunk):
                piece = self.settle_ctrl[start : start + chunk]
                ctrl = np.broadcast_to(piece, (ids.size, *piece.shape))
                failed |= sim.rollout(np.ascontiguousarray(ctrl), ids)
                self.physics_steps["settle"] += ids.size * piece.shape[0]
                report(ids.size * (start + piece.shape[0]), ids.size * total)
        quat = torch.from_numpy(np.asarray(sim.sensordata[ids, OBS_QUAT]))
        failed |= fallen(quat_to_rpy(quat)).numpy()
        return failed

    def set_model(self, model) -> None:
        """Settle on a changed model from now on; pooled starts settled on the old one
        are dropped."""
        if self.pool is not None:
            self.pool.set_model(model)

    @property
    def rollout_seconds(self) -> float:
        """Wall time the pool's rollouts took. Seconds."""
        return self.pool.sim.rollout_seconds if self.pool is not None else 0.0

    def state(self) -> dict:
        """What to keep when the core is pickled: the counters and the pool."""
        state: dict = {"drawn": self.drawn.copy()}
        pool = self.pool
        if pool is not None:
            state["pool"] = (pool.sim.state.copy(), pool.obs.clone(), pool.uses_left.copy(),
                             pool.next)  # fmt: skip
        return state

    def load_state(self, state: dict) -> None:
        self.drawn[:] = state["drawn"]
        if self.pool is not None:
            self.pool.sim.state[:], self.pool.obs, self.pool.uses_left, self.pool.next = state[
                "pool"
            ]


class _StartPool:
    """Settled starts kept ready in a batch of their own.

    Entries are served round-robin, each ``settle_reuse`` times; when fewer are
    left than a reset needs, every used-up entry is replaced by a fresh settle in
    one batched rollout.
    """

    def __init__(self, world: World, config: EnvConfig) -> None:
        self.size = config.settle_pool
        self.reuse = config.settle_reuse
        self.sim = BatchedSim(world.model, self.size, config.num_threads)
        self._sensors = sensor_rows(self.sim)
        self.obs = torch.zeros(self.size, OBS_DIM, dtype=torch.float64)
        """Spec observation of each settled start. Shape: (size, 65)."""
        self.uses_left = np.zeros(self.size, dtype=np.int64)
        self.next = 0

    def take(self, count: int, refill: Callable[[np.ndarray], None]) -> np.ndarray:
        """Indices of ``count`` entries (count <= size); ``refill(stale_ids)`` settles."""
        if int((self.uses_left > 0).sum()) < count:
            stale = np.flatnonzero(self.uses_left == 0).astype(np.int32)
            refill(stale)
            rows = torch.from_numpy(stale.astype(np.int64))
            self.obs[rows] = sensor_observation(self._sensors[rows])
            self.uses_left[stale] = self.reuse
        order = (np.arange(self.size) + self.next) % self.size
        chosen = order[self.uses_left[order] > 0][:count]
        self.next = int(chosen[-1] + 1) % self.size
        self.uses_left[chosen] -= 1
        return chosen

    def set_model(self, model) -> None:
        """Run on a changed model; entries settled on the old one are dropped."""
        self.sim.set_model(model)
        self.uses_left[:] = 0


def rpy_to_quat(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> Tensor:
    """(w, x, y, z) quaternions from ZYX Euler angles, with ``rwalk.exactmath``
    (the same bits on any CPU). Shape: (M,)x3 -> (M, 4) float64."""
    half = [torch.as_tensor(np.asarray(a, dtype=np.float64)) * 0.5 for a in (roll, pitch, yaw)]
    (sr, sp, sy), (cr, cp, cy) = ([f(a) for a in half] for f in (exactmath.sin, exactmath.cos))
    return torch.stack(
        (
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ),
        dim=-1,
    )
