"""N envs of a task over one batched simulation: a fixed step pipeline and batched resets.

The core owns what every task shares: the simulation, seeding, resets and
settling, termination and episode bookkeeping. A task (``rwalk.tasks``) says
how an action becomes servo targets, which observation pieces it offers and
which reward terms it adds up.

Step: check action -> task: servo targets for K substeps (and the gait's swing
flags) -> one batched MuJoCo rollout -> counters -> observation -> the task's
declared reward terms -> terminations. The core never resets on its own: the
TorchRL, Gymnasium and rsl-rl views each apply their own reset convention on
top of it (``rwalk.episodes`` is the auto-reset they share).

Reset: each start is drawn from its own counter-based key, placed above the
ground, then settled with zero residuals for ``settle_steps`` env steps while
the gait phase advances, all resetting envs in one batched rollout. A start
that falls or diverges while settling is redrawn.

Seeds: env i of a core seeded s draws its k-th start (redraws included) from the
key (s + i mod 2^64, "start_pose", k) of ``rwalk.rng``; the k-th refill of
settled-start pool entry j draws like an env N + j would. So env i starts
exactly like a single env seeded s + i at every reset settled in place (a
partial reset served from the pool takes the pool's next entry instead), and
different seeds draw independent starts.

Worlds that vary per env (``config.terrain_levels``, ``randomization``, ``pushes``,
``observation_noise``): at a reset the terrain curriculum moves the env's level
(``rwalk.levels``) and ``core.perturb`` (``rwalk.randomization``) draws its physics
and first kick, before the start is placed on its tile's pad and settled in its
own physics (pool starts settle on the pad of tile (0, 0) with the model's physics
and move to the env's pad). Env i's k-th draw of each comes from the key
(s + i, stream, k) of its own stream ("physics", "push", "terrain_level").

Exactness: gait, IK, observation, reward and termination use only elementwise
IEEE arithmetic and ``rwalk.exactmath``, so env i of a batch steps bit for bit
like a single env with the same state and actions, on any x86-64 CPU; the
physics is MuJoCo's, deterministic per simulation (see ``rwalk.exactmath`` for
what lies outside our control).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from typing import NamedTuple

import mujoco
import numpy as np
import torch
from torch import Tensor

from rwalk import exactmath, rng
from rwalk.assets import load_model
from rwalk.config import EnvConfig
from rwalk.constants import (
    JOINT_NAMES,
    OBS_CONTACT,
    OBS_DIM,
    OBS_LINVEL,
    OBS_POS,
    OBS_QUAT,
)
from rwalk.gait import BezierGaitController
from rwalk.kinematics import LegGeometry
from rwalk.levels import build_model, update_levels
from rwalk.randomization import Perturbations
from rwalk.rewards import StepState, evaluate, fallen, quat_to_rpy
from rwalk.sim import BatchedSim
from rwalk.single import SingleStep, SingleStepResult
from rwalk.tasks import Task, get_task, task_for_config
from rwalk.terrain import Terrain

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
#: Random stream of the levels of envs that pass the top of a terrain map.
LEVEL_STREAM = "terrain_level"


class StepResult(NamedTuple):
    """What one core step returns; every tensor has the batch as first dimension."""

    obs: Tensor
    """The task's spec observation. Shape: (N, D) float64 (65 for residual_walk)."""
    reward: Tensor
    """Sum of the weighted terms. Shape: (N,)."""
    terms: dict[str, Tensor]
    """Weighted reward terms by name. Each shape: (N,)."""
    terminated: Tensor
    """Fell (|roll| or |pitch| > π/3) or diverged. Shape: (N,) bool."""
    truncated: Tensor
    """Reached max_episode_steps without terminating. Shape: (N,) bool."""
    diverged: Tensor
    """The simulation blew up this step (MuJoCo reset it). Shape: (N,) bool."""


class Core:
    """N envs of one task over one batched simulation.

    Args:
        config: the task's config (an ``EnvConfig``, or the task's own subclass).
        num_envs: N.
        seed: base seed in [0, 2^64); env i's k-th start uses the key
            (seed + i mod 2^64, START_STREAM, k), the same as a single env seeded
            seed + i. None draws a seed from the OS.
        task: registry name (``rwalk.tasks.TASKS``); None picks the task whose
            config class ``config`` is.

    Raises:
        ValueError: an unknown task (listing the known ones), or a config of
            another task.
    """

    def __init__(
        self, config: EnvConfig, num_envs: int, seed: int | None = None, task: str | None = None
    ) -> None:
        if not isinstance(num_envs, int) or isinstance(num_envs, bool) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        if not isinstance(config, EnvConfig):
            raise TypeError(f"config must be an EnvConfig, got {type(config).__name__}")
        task_type = task_for_config(config) if task is None else get_task(task)
        if type(config) is not task_type.config_type:
            raise ValueError(
                f"task {task_type.name!r} takes a {task_type.config_type.__name__}, got a "
                f"{type(config).__name__}"
            )
        self.config = config
        self.num_envs = num_envs
        levels = config.terrain_levels
        if levels is None:
            self.model, self.terrain_map = load_model(config.model_path), None
        else:
            self.model, self.terrain_map = build_model(config.model_path, levels)
        config.physics.apply(self.model)
        self.terrain = Terrain(self.model)
        if self.terrain.is_heightfield and levels is None:
            self.terrain.set_scale(self.model, config.terrain_scale)
        self.geometry = LegGeometry.from_model(self.model)
        self.dt = float(self.model.opt.timestep)
        if not (self.dt > 0 and np.isfinite(self.dt)):
            raise ValueError(f"{config.model_path}: option timestep must be > 0, got {self.dt!r}")
        self.decimation = config.substeps(self.dt)
        """Physics substeps per env step."""
        self.control_dt = self.dt * self.decimation
        self.controller = BezierGaitController(config.gait, self.geometry, dt=self.dt)
        if self.controller.period < 2 * self.decimation:
            raise ValueError(
                f"GaitParameters.cycle_time ({config.gait.cycle_time!r} s) must span at least 2 "
                f"control steps ({2 * self.control_dt:g} s at decimation {self.decimation} x "
                f"timestep {self.dt:g} s): the controller could not follow swing and stance"
            )
        _check_memory(self.model, config, num_envs, self.decimation)
        self.sim = BatchedSim(self.model, num_envs, config.num_threads)
        joint_adr = [int(self.model.joint(name).qposadr[0]) for name in JOINT_NAMES]
        self._joint_qpos = slice(joint_adr[0], joint_adr[0] + len(joint_adr))
        if joint_adr != list(range(joint_adr[0], joint_adr[0] + len(joint_adr))):
            raise ValueError(f"joints {JOINT_NAMES} must be consecutive in qpos")

        n = num_envs
        self.episode_step = torch.zeros(n, dtype=torch.long)
        """Env steps counted towards truncation at max_episode_steps. Shape: (N,). Starts
        at 0, but a trainer may set it (rsl-rl's init_at_random_ep_len spreads the
        first truncations out), so statistics count ``walked_steps`` instead."""
        self.walked_steps = torch.zeros(n, dtype=torch.long)
        """Env steps actually taken in the current episode. Shape: (N,)."""
        self.y0 = torch.zeros(n, dtype=torch.float64)
        """Torso y at the episode's start. Shape: (N,)."""
        self.x0 = torch.zeros(n, dtype=torch.float64)
        """Torso x at the episode's start. Shape: (N,)."""
        self.fell = torch.zeros(n, dtype=torch.bool)
        """Whether the current (or just ended) episode terminated. Shape: (N,)."""
        kinds = len(levels.kinds) if levels is not None else 1
        self.terrain_level = torch.full(
            (n,), levels.start_level if levels is not None else 0, dtype=torch.long
        )
        """Each env's terrain level (0 without terrain_levels). Shape: (N,)."""
        self.terrain_kind = torch.arange(n, dtype=torch.long) % kinds
        """Each env's kind of tile, an index into ``terrain_levels.kinds``. Shape: (N,)."""
        self.obs = torch.zeros(n, OBS_DIM, dtype=torch.float64)
        """Current sensor observation (the spec's 65 values). Shape: (N, 65)."""
        self.task: Task = task_type(self)
        """The task: actions, observation pieces, reward terms."""
        self.terms = self.task.reward_terms()
        """The task's declared reward terms, in the order they are added."""
        self.episode_sums = {term.name: torch.zeros(n, dtype=torch.float64) for term in self.terms}
        """Per-term sums over the current episode. Each shape: (N,)."""
        self.episode_distance = torch.zeros(n, dtype=torch.float64)
        """Sum of forward velocity x control dt over the current episode. Shape: (N,)."""
        self.episode_speed_error = torch.zeros(n, dtype=torch.float64)
        """Sum of |v_x - v*| over the current episode's steps. Shape: (N,). m/s."""
        with warnings.catch_warnings():  # sensordata is a read-only output; we only read it
            warnings.simplefilter("ignore", UserWarning)
            self._sensors = torch.from_numpy(self.sim.sensordata)
        self._settle_ctrl = self._base_gait_ctrl(config.settle_steps * self.decimation)
        self._stand_joints = self._base_gait_ctrl(1)[0]
        self.settled_tick = config.settle_steps * self.decimation % self.controller.period
        """Gait tick (substeps from phase 0, modulo the cycle) where settling leaves a start."""
        self._pool = _StartPool(self, config.settle_pool) if config.settle_pool else None
        tail = self._settle_ctrl[-self.decimation :]
        self._settle_tail = (
            tail if len(tail) == self.decimation else self._base_gait_ctrl(self.decimation)
        )
        self.perturb = Perturbations(self)
        """The config's randomised physics, pushes, latency and observation noise."""
        self.physics_steps = {"step": 0, "settle": 0}
        """Physics substeps run so far: stepping the envs, and settling starts."""
        self.resets = 0
        """Env resets so far (each start an env received)."""
        self.settle_progress: Callable[[int, int], None] | None = None
        """Called with (physics steps done, total) of each settle: 0 first, then per chunk."""
        self._started = False
        self.seed(seed)
        self._single = (
            SingleStep(self)
            if n == 1 and task_type.single_step and config.command_range is None
            else None
        )

    #: Attributes rebuilt from the config when a core is unpickled or deep-copied.
    _REBUILT = (
        "model", "terrain", "geometry", "controller", "sim", "_sensors", "_settle_ctrl",
        "_stand_joints", "_pool", "settle_progress", "_single", "task", "terms",
        "_settle_tail", "perturb", "terrain_map",
    )  # fmt: skip

    def __getstate__(self) -> dict:
        """Config, counters and buffers, plus each simulation's integration state:
        enough to rebuild the core and continue exactly where it was."""
        state = {k: v for k, v in self.__dict__.items() if k not in self._REBUILT}
        state["sim_state"] = self.sim.state.copy()
        state["terrain_scale"] = self.terrain.scale
        state["task_state"] = {k: v.clone() for k, v in self.task.state().items()}
        state["task_name"] = self.task.name
        state["perturb_state"] = {k: v.clone() for k, v in self.perturb.state().items()}
        pool = self._pool
        if pool is not None:
            state["pool"] = (pool.sim.state.copy(), pool.obs.clone(), pool.uses_left.copy(),
                             pool._next)  # fmt: skip
        return state

    def __setstate__(self, state: dict) -> None:
        state = dict(state)
        sim_state, scale = state.pop("sim_state"), state.pop("terrain_scale")
        pool = state.pop("pool", None)
        task_state = state.pop("task_state")
        perturb_state = state.pop("perturb_state")
        self.__init__(state["config"], state["num_envs"], seed=0, task=state.pop("task_name"))
        if scale != self.terrain.scale:
            self.set_terrain_scale(scale)
        self.__dict__.update(state)
        self.sim.state[:] = sim_state
        for name, value in self.task.state().items():
            value.copy_(task_state[name])
        for name, value in self.perturb.state().items():
            value.copy_(perturb_state[name])
        self.perturb.apply(torch.arange(self.num_envs))
        if pool is not None:
            self._pool.sim.state[:], self._pool.obs, self._pool.uses_left, self._pool._next = pool

    @property
    def tick(self) -> Tensor:
        """The residual task's gait tick per env (see ``ResidualWalk.tick``). Shape: (N,)."""
        return self.task.tick

    @property
    def seed_value(self) -> int:
        """The seed the starts are keyed by."""
        return self._seed

    @property
    def started(self) -> bool:
        """Whether every env has been reset at least once (step() needs it)."""
        return self._started

    # ------------------------------------------------------------------ seeding
    def seed(self, seed: int | None) -> int:
        """Key the starts by ``seed`` and restart every env's start counter.

        Returns:
            The seed used (drawn from the OS for None).

        Raises:
            ValueError: ``seed`` is not an integer in [0, 2^64) (naming it).
        """
        if seed is None:
            seed = int.from_bytes(os.urandom(8), "little")
        if (
            not isinstance(seed, (int, np.integer))
            or isinstance(seed, bool)
            or not 0 <= int(seed) < rng.SEED_LIMIT
        ):
            raise ValueError(f"seed must be an integer in [0, 2**64) or None, got {seed!r}")
        self._seed = int(seed)
        pool_size = self._pool.size if self._pool is not None else 0
        self._starts_drawn = np.zeros(self.num_envs + pool_size, dtype=np.uint64)
        """Starts drawn so far by each env, then by each pool entry. Shape: (N + pool,)."""
        self._level_draws = torch.zeros(self.num_envs, dtype=torch.long)
        self.task.seed()
        self.perturb.seed(self._seed)
        return self._seed

    # ------------------------------------------------------------------ reset
    def reset(
        self, env_ids: np.ndarray | Tensor | None = None, randomize: bool | None = None
    ) -> None:
        """Start new episodes in the given envs (all if None), settled and ready.

        A partial reset takes its starts from the settled-start pool when the
        config has one (``settle_pool > 0``); otherwise, and for full resets, the
        resetting envs are settled in place, all in one batched rollout.

        Args:
            env_ids: sorted unique env indices. Shape: (M,).
            randomize: perturb the starts; None uses ``config.randomize``.
        """
        ids = self._ids(env_ids)
        if ids.size == 0:
            return
        randomize = self.config.randomize if randomize is None else bool(randomize)
        rows = torch.from_numpy(ids.astype(np.int64))
        self._move_levels(rows)
        self.perturb.reset(rows, self._settle_tail)  # before settling: settle in the env's world
        pool = self._pool
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
            self.obs[rows] = pool.obs[torch.from_numpy(entries)]
            if self.terrain_map is not None:
                # Pool starts settle on the pad of tile (0, 0); every pad is flat at height 0.
                shift = self._origins(ids) - self._origins(None)
                self.sim.qpos[ids, 0:2] += shift
                self.obs[rows, OBS_POS.start : OBS_POS.start + 2] += torch.from_numpy(shift)
        else:
            self._settle_fresh(self.sim, ids, randomize)
            self.obs[rows] = _observation(self._sensors[rows])
        self.task.reset(rows)
        self.task.draw_commands(rows)
        self.episode_step[rows] = 0
        self.walked_steps[rows] = 0
        self.x0[rows] = self.obs[rows, OBS_POS.start]
        self.y0[rows] = self.obs[rows, OBS_POS.start + 1]
        self.fell[rows] = False
        totals = (*self.episode_sums.values(), self.episode_distance, self.episode_speed_error)
        for total in totals:
            total[rows] = 0.0
        self.resets += ids.size
        if ids.size == self.num_envs:
            self._started = True

    def _settle_fresh(self, sim: BatchedSim, ids: np.ndarray, randomize: bool) -> None:
        """Place fresh starts in rows ``ids`` of ``sim`` and settle them; redraw
        the ones that fall or diverge (up to SETTLE_ATTEMPTS tries).

        Raises:
            RuntimeError: if some starts still fall or diverge after every attempt.
        """
        # Env i draws as seed + i, pool entry j as seed + N + j (see the module docstring).
        first = 0 if sim is self.sim else self.num_envs
        todo = ids
        for _ in range(SETTLE_ATTEMPTS):
            rows = todo.astype(np.uint64) + np.uint64(first)
            seeds = np.uint64(self._seed) + rows  # wraps modulo 2^64
            keys = rng.keys(seeds, START_STREAM, self._starts_drawn[rows])
            self._starts_drawn[rows] += np.uint64(1)
            self._place_starts(sim, todo, keys, randomize)
            todo = todo[self._settle(sim, todo)]
            if todo.size == 0:
                return
        cfg = self.config
        raise RuntimeError(
            f"{todo.size} of {ids.size} starts fell or diverged while settling, in each of "
            f"{SETTLE_ATTEMPTS} attempts: the starts are too hard for the base gait "
            f"(randomize={randomize}, tilt_noise={cfg.tilt_noise}, yaw_noise={cfg.yaw_noise}, "
            f"position_noise={cfg.position_noise}, world {cfg.model_path}); reduce the noise"
        )

    def _origins(self, ids: np.ndarray | None) -> np.ndarray:
        """Nominal start (x, y) of envs ``ids``: their tiles' pads on a terrain-levels map,
        else ``config.start_position``; None: where the settled-start pool starts (the
        pad of tile (0, 0)). Shape: (M, 2) or (2,). Metres."""
        if self.terrain_map is None:
            return np.asarray(self.config.start_position, dtype=np.float64)
        if ids is None:
            return np.asarray(self.terrain_map.origin(0, 0), dtype=np.float64)
        return self.terrain_map.origins(
            self.terrain_level[ids].numpy(), self.terrain_kind[ids].numpy()
        )

    def _move_levels(self, rows: Tensor) -> None:
        """The terrain curriculum: envs of ``rows`` ending an episode move a level up
        or down by how far they walked against the target (``rwalk.levels``)."""
        levels = self.config.terrain_levels
        if levels is None or not levels.curriculum:
            return
        rows = rows[self.walked_steps[rows] > 0]  # first resets end no episode
        if rows.numel() == 0:
            return
        target = self.task.v_target
        target = target[rows] if isinstance(target, Tensor) else target
        expected = target * self.walked_steps[rows].to(torch.float64) * self.control_dt
        redraw = None
        if levels.recycle:  # env i's k-th draw from the key (seed + i, "terrain_level", k)
            u = rng.uniform_rows(self._seed, rows, LEVEL_STREAM, self._level_draws, 1)[:, 0]
            redraw = torch.floor(u * levels.levels).to(torch.long)
        self.terrain_level[rows] = update_levels(
            self.terrain_level[rows], self.episode_distance[rows], expected, self.fell[rows],
            levels, redraw,
        )  # fmt: skip

    def _ids(self, env_ids: np.ndarray | Tensor | None) -> np.ndarray:
        """Sorted unique int32 row indices from ids or a boolean mask of length N."""
        if env_ids is None:
            return np.arange(self.num_envs, dtype=np.int32)
        if isinstance(env_ids, Tensor):
            env_ids = env_ids.detach().cpu().numpy()
        ids = np.asarray(env_ids)
        if ids.dtype == bool:
            if ids.shape not in ((self.num_envs,), (self.num_envs, 1)):
                raise ValueError(
                    f"a boolean env mask must have shape ({self.num_envs},), got {ids.shape}"
                )
            ids = np.flatnonzero(ids)
        elif not np.issubdtype(ids.dtype, np.integer):
            raise ValueError(
                f"env ids must be integers or a boolean mask, got dtype {ids.dtype} "
                f"({ids.reshape(-1)[:8].tolist()})"
            )
        ids = ids.reshape(-1)
        if ids.size and (ids.min() < 0 or ids.max() >= self.num_envs):
            raise ValueError(f"env ids must be in [0, {self.num_envs}), got {ids.tolist()}")
        if ids.size > 1 and not (np.diff(ids) > 0).all():
            raise ValueError(f"env ids must be sorted and unique, got {ids.tolist()}")
        return np.ascontiguousarray(ids.astype(np.int32))

    def _place_starts(
        self, sim: BatchedSim, ids: np.ndarray, keys: np.ndarray, randomize: bool
    ) -> None:
        """Write fresh starts (standing in the phase-0 gait pose) into rows ``ids``."""
        cfg = self.config
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
        origin = self._origins(ids if sim is self.sim else None)
        x = origin[..., 0] + dx
        y = origin[..., 1] + dy
        ground = self.terrain.max_height(x, y, FOOTPRINT_RADIUS)
        foot_bottom = self.controller.stance_z - self.geometry.foot_radius
        z = ground + START_CLEARANCE - foot_bottom
        sim.reset(ids)
        qpos = sim.qpos
        qpos[ids, 0] = x
        qpos[ids, 1] = y
        qpos[ids, 2] = z
        qpos[ids, 3:7] = _rpy_to_quat(roll, pitch, yaw).numpy()
        qpos[ids, self._joint_qpos] = self._stand_joints

    def _settle(self, sim: BatchedSim, ids: np.ndarray) -> np.ndarray:
        """Run the zero-residual gait on rows ``ids`` for settle_steps env steps.

        Returns:
            Rows that fell or diverged. Shape: (M,) bool.
        """
        failed = np.zeros(ids.size, dtype=bool)
        total = self._settle_ctrl.shape[0]
        if total == 0:
            failed |= sim.forward(ids)
        else:
            chunk = max(1, SETTLE_CTRL_BUDGET // (ids.size * self._settle_ctrl.shape[1]))
            report = self.settle_progress or (lambda done, total: None)
            report(0, ids.size * total)
            for start in range(0, total, chunk):
                piece = self._settle_ctrl[start : start + chunk]
                ctrl = np.broadcast_to(piece, (ids.size, *piece.shape))
                failed |= sim.rollout(np.ascontiguousarray(ctrl), ids)
                self.physics_steps["settle"] += ids.size * piece.shape[0]
                report(ids.size * (start + piece.shape[0]), ids.size * total)
        quat = torch.from_numpy(np.asarray(sim.sensordata[ids, OBS_QUAT]))
        failed |= fallen(quat_to_rpy(quat)).numpy()
        return failed

    def _base_gait_ctrl(self, substeps: int) -> np.ndarray:
        """Zero-residual servo targets from phase 0. Shape: (substeps, 12)."""
        ctrl, _ = self.controller.joint_targets(torch.zeros(1, dtype=torch.long), substeps)
        return np.ascontiguousarray(ctrl[0].numpy())

    # ------------------------------------------------------------------ step
    def step(self, action: Tensor) -> StepResult:
        """Advance every env by one control period (``self.decimation`` substeps).

        Args:
            action: values in [-1, 1] (outside are clipped), as the task lays them
                out. Shape: (N, task.action_dim).

        Raises:
            ValueError: wrong shape or a non-finite value (naming it).
            RuntimeError: before the first full reset.
        """
        if not self._started:
            raise RuntimeError("call reset() on all envs before step()")
        action = self.check_action(action)
        cfg = self.config
        ctrl, swing = self.task.act(action)
        ctrl = self.perturb.delay(ctrl)
        self.perturb.before_step()  # kicks at the control-step boundary
        diverged = torch.from_numpy(self.sim.rollout(ctrl))
        self.physics_steps["step"] += self.num_envs * self.decimation
        # In place, like every state update here: callers step inside torch.inference_mode
        # (rsl-rl does) and reset outside it.
        self.episode_step += 1
        self.walked_steps += 1

        obs = self.obs
        obs.copy_(_observation(self._sensors))
        rpy = quat_to_rpy(obs[:, OBS_QUAT])
        forward_velocity = obs[:, OBS_LINVEL.start]
        state = StepState(
            forward_velocity=forward_velocity,
            v_target=self.task.v_target,
            swing=swing,  # the gait's at the last substep's start, whose sensors these are
            contact=obs[:, OBS_CONTACT] > 0.5,
            rpy=rpy,
            y=obs[:, OBS_POS.start + 1],
            y0=self.y0,
            weights=cfg.reward_weights,
        )
        terms = evaluate(self.terms, state)
        if bool(diverged.any()):
            terms = {name: term.masked_fill(diverged, 0.0) for name, term in terms.items()}
        # Left to right, so that the reward equals sum(terms.values()) to the last bit.
        reward = sum(terms.values(), torch.zeros_like(forward_velocity))
        terminated = fallen(rpy) | diverged
        self.fell.copy_(terminated)
        truncated = (self.episode_step >= cfg.max_episode_steps) & ~terminated
        for name, term in terms.items():
            self.episode_sums[name] += term
        moved = forward_velocity.masked_fill(diverged, 0.0)
        self.episode_distance += moved * self.control_dt
        self.episode_speed_error += (moved - state.v_target).abs()
        return StepResult(
            self.task.spec_observation(), reward, terms, terminated, truncated, diverged
        )

    @property
    def has_single_step(self) -> bool:
        """Whether ``step_single`` runs: one env of a task with a float pipeline
        (``rwalk.single``: the residual task without velocity commands)."""
        return self._single is not None

    def step_single(self, action: np.ndarray) -> SingleStepResult:
        """``step`` for a core of one env, on numpy and Python floats: the same bits,
        at a fraction of the cost (see ``rwalk.single``).

        Args:
            action: residuals in [-1, 1] (values outside are clipped). Shape: (12,).

        Raises:
            ValueError: num_envs is not 1; the action's shape, dtype or a value (naming it).
            RuntimeError: before the first reset.
        """
        if self._single is None:
            raise ValueError(f"step_single needs a core of 1 env, got num_envs={self.num_envs}")
        return self._single.step(action)

    def check_action(self, action: Tensor | np.ndarray) -> Tensor:
        """Validate and clip an action batch. Returns float64 (N, task.action_dim).

        Raises:
            ValueError: naming the action's wrong shape, dtype, device, a
                non-finite value, or that it requires grad.
        """
        if isinstance(action, Tensor):
            if action.requires_grad:
                raise ValueError(
                    "action requires grad: pass action.detach() (the simulation is not "
                    "differentiable), or act under torch.no_grad()"
                )
            if action.device.type != "cpu":
                raise ValueError(f"action must be on the CPU, got device {action.device}")
        action = torch.as_tensor(action)
        expected = (self.num_envs, self.task.action_dim)
        if tuple(action.shape) != expected:
            raise ValueError(
                f"action must have shape {expected} for task {self.task.name!r} "
                f"({self.task.action_layout}), got {tuple(action.shape)}"
            )
        if action.dtype not in (torch.float32, torch.float64, torch.int32, torch.int64):
            raise ValueError(
                f"action must be float32 or float64 (or integer), got dtype {action.dtype}: "
                "convert it with action.float()"
            )
        action = action.to(torch.float64)
        finite = torch.isfinite(action)
        if not bool(finite.all()):
            env, index = (int(v) for v in (~finite).nonzero()[0])
            raise ValueError(
                f"action has a non-finite value {action[env, index].item()} "
                f"(env {env}, index {index})"
            )
        return action.clamp(-1.0, 1.0)

    # ------------------------------------------------------------------ extras
    def set_terrain_scale(self, scale: float) -> None:
        """Scale the heightfield's roughness for all envs (0 flat .. 1 full).

        Takes effect immediately for contacts; new starts are placed on the new ground.

        Raises:
            ValueError: naming the world, if its ground is a plane.
        """
        if self.terrain_map is not None:
            raise ValueError(
                "set_terrain_scale cannot change a terrain-levels map: each env's level "
                "sets its ground (EnvConfig.terrain_levels)"
            )
        if self.config.randomization is not None:
            raise ValueError(
                "set_terrain_scale cannot change the ground of a core with per-env physics "
                "(EnvConfig.randomization): mujoco.batch keeps per-env fields only on one "
                "model; build the core with the terrain_scale you want instead"
            )
        try:
            self.terrain.set_scale(self.model, scale)
        except ValueError as error:
            raise ValueError(f"{self.config.model_path}: {error}") from None
        self.sim.set_model(self.model)
        if self._pool is not None:
            self._pool.set_model(self.model)

    @property
    def phase(self) -> Tensor:
        """Gait phase in [0, 1) at the start of the next step. Shape: (N,)."""
        return self.task.phase

    def phase_features(self) -> Tensor:
        """(sin 2πφ, cos 2πφ) of the gait phase. Shape: (N, 2)."""
        return self.task.phase_features()

    def piece(self, name: str) -> Tensor:
        """A named observation piece of the task: ``"observation"`` is the spec
        observation, ``"observation_from_start"`` the same with the torso's x and y
        taken from the episode's start (x0, y0), so that a policy cannot read where
        on a map it is. Shape: (N, size) float64.

        Raises:
            ValueError: naming the piece and listing the task's pieces.
        """
        if name == "observation":
            return self.task.spec_observation()
        if name == "observation_from_start":
            obs = self.task.spec_observation().clone()
            obs[:, OBS_POS.start] -= self.x0
            obs[:, OBS_POS.start + 1] -= self.y0
            return obs
        pieces = self.task.pieces()
        if name not in pieces:
            raise ValueError(
                f"task {self.task.name!r} has no observation piece {name!r}; choose from "
                f"{('observation', 'observation_from_start', *pieces)}"
            )
        return pieces[name].read(self.task)

    def piece_size(self, name: str) -> int:
        """Width of the piece ``name`` (see ``piece``)."""
        if name in ("observation", "observation_from_start"):
            return self.task.observation_dim
        pieces = self.task.pieces()
        if name not in pieces:
            self.piece(name)  # raises, naming it
        return pieces[name].size

    @property
    def rollout_seconds(self) -> float:
        """Wall time spent in MuJoCo rollouts so far, stepping and settling. Seconds."""
        pool = self._pool.sim.rollout_seconds if self._pool is not None else 0.0
        return self.sim.rollout_seconds + pool

    @property
    def settle_share(self) -> float:
        """Fraction of all physics substeps so far spent settling starts."""
        total = self.physics_steps["step"] + self.physics_steps["settle"]
        return self.physics_steps["settle"] / total if total else 0.0

    def episode_log(self, env_ids: Tensor) -> dict[str, Tensor]:
        """Per-env statistics of the episodes ending in ``env_ids`` (call before reset).

        Returns per-term episode sums (``"sum/<term>"``), ``"length"`` (steps
        actually walked, whatever ``episode_step`` was set to),
        ``"forward_velocity"`` (mean over the episode, m/s),
        ``"target_velocity"`` (what the reward tracked, m/s) and
        ``"velocity_error"`` (mean |v_x - v*| per step, m/s). Each shape: (M,).
        """
        length = self.walked_steps[env_ids].to(torch.float64)
        log = {f"sum/{name}": total[env_ids] for name, total in self.episode_sums.items()}
        log["length"] = length
        log["forward_velocity"] = self.episode_distance[env_ids] / (
            length.clamp(min=1.0) * self.control_dt
        )
        target = self.task.v_target
        log["target_velocity"] = (
            target[env_ids] if isinstance(target, Tensor) else torch.full_like(length, target)
        )
        log["velocity_error"] = self.episode_speed_error[env_ids] / length.clamp(min=1.0)
        return log


def _check_memory(model, config: EnvConfig, num_envs: int, decimation: int) -> None:
    """Raise MemoryError at once if N envs would not fit, instead of failing mid-build.

    A conservative estimate per env: its integration state and sensor rows (in the
    batch, and in the pool), the torch buffers, and ~20 temporaries of each control
    period's (K, 4, 3) targets in the step (measured: ~9 KB per env at K = 10).
    """
    nstate = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_INTEGRATION.value)
    row = 8 * (nstate + model.nsensordata + 4 * OBS_DIM)
    per_env = row + 8 * 20 * decimation * 12
    needed = num_envs * per_env + config.settle_pool * row
    available = _available_memory()
    if available is not None and needed > available:
        raise MemoryError(
            f"num_envs={num_envs} needs about {needed / 2**30:.1f} GiB ({per_env / 1024:.1f} KiB "
            f"per env) but {available / 2**30:.1f} GiB is available"
        )


def _available_memory() -> int | None:
    """MemAvailable from /proc/meminfo, in bytes (None where there is none)."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _observation(sensors: Tensor) -> Tensor:
    """Spec observations from sensor rows: contact counts become 0/1. (M, 65) -> (M, 65)."""
    obs = sensors.clone()
    obs[:, OBS_CONTACT] = (obs[:, OBS_CONTACT] > 0).to(obs.dtype)
    return obs


class _StartPool:
    """Settled starts kept ready in a batch of their own.

    Entries are served round-robin, each ``settle_reuse`` times; when fewer are
    left than a reset needs, every used-up entry is replaced by a fresh settle in
    one batched rollout.
    """

    def __init__(self, core: Core, size: int) -> None:
        self.size = size
        self.reuse = core.config.settle_reuse
        self.sim = BatchedSim(core.model, size, core.config.num_threads)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            self._sensors = torch.from_numpy(self.sim.sensordata)
        self.obs = torch.zeros(size, OBS_DIM, dtype=torch.float64)
        """Spec observation of each settled start. Shape: (size, 65)."""
        self.uses_left = np.zeros(size, dtype=np.int64)
        self._next = 0

    def take(self, count: int, refill) -> np.ndarray:
        """Indices of ``count`` entries (count <= size); ``refill(stale_ids)`` settles."""
        if int((self.uses_left > 0).sum()) < count:
            stale = np.flatnonzero(self.uses_left == 0).astype(np.int32)
            refill(stale)
            rows = torch.from_numpy(stale.astype(np.int64))
            self.obs[rows] = _observation(self._sensors[rows])
            self.uses_left[stale] = self.reuse
        order = (np.arange(self.size) + self._next) % self.size
        chosen = order[self.uses_left[order] > 0][:count]
        self._next = int(chosen[-1] + 1) % self.size
        self.uses_left[chosen] -= 1
        return chosen

    def set_model(self, model) -> None:
        """Run on a changed model; entries settled on the old one are dropped."""
        self.sim.set_model(model)
        self.uses_left[:] = 0


def _rpy_to_quat(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> Tensor:
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


#: The name the core had when it ran one task; the residual task is still its default.
ResidualWalkCore = Core
