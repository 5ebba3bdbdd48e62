"""N envs of a task over one batched simulation: the step and reset pipelines.

The core holds the order, not the work. Its parts each do one job with narrow
inputs: ``World`` (model, terrain, timing, gait), ``BatchedSim`` (the N
simulations), ``Curriculum`` (terrain levels), ``PhysicsRandomizer`` (each env's
drawn physics and servo latency), ``PushSchedule`` (kicks), ``Starts`` (placing
and settling starts, the pool), ``Episodes`` (counters, sums, the episode log),
``Observations`` (pieces and their noise), ``rwalk.checks`` (inputs), and the
``Task`` (actions, its pieces, reward terms).

Step: check action -> task: servo targets for K substeps (and the gait's swing
flags) -> latency -> kicks -> one batched MuJoCo rollout -> counters ->
observation -> the task's declared reward terms -> terminations -> episode
sums. The core never resets on its own: the TorchRL, Gymnasium and rsl-rl views
each apply their own reset convention on top of it (``rwalk.episodes.step`` is
the auto-reset they share).

Reset of envs ``rows``: curriculum (their levels move) -> physics (new draws)
-> pushes (first kick) -> starts (placed on their origins and settled, or
taken from the pool) -> task (its per-env state; the ended episodes judge their commands
(``rwalk.commands``), new ones are drawn) -> episodes (counters
restart).

Seeds: every random quantity is drawn from a counter-based key (seed + i,
stream, k) of ``rwalk.rng`` for env i (streams "start_pose", "physics", "push",
"terrain_level", "command", ...). So env i of a core seeded s steps exactly like
a single env seeded s + i at every reset settled in place, whatever else the
batch does, at any thread count.

Exactness: gait, IK, observation, reward and termination use only elementwise
IEEE arithmetic and ``rwalk.exactmath``, so env i of a batch steps bit for bit
like a single env with the same state and actions, on any x86-64 CPU; the
physics is MuJoCo's, deterministic per simulation (see ``rwalk.exactmath`` for
what lies outside our control).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

from rwalk import checks
from rwalk.config import EnvConfig
from rwalk.constants import OBS_CONTACT, OBS_DIM, OBS_LINVEL, OBS_POS, OBS_QUAT, TORSO_BODY
from rwalk.curriculum import Curriculum
from rwalk.episodes import Episodes, StepResult
from rwalk.observations import Observations, Sources
from rwalk.perturbations import PushSchedule
from rwalk.randomization import PhysicsRandomizer
from rwalk.rewards import GaitCosts, Shaping, StepState, evaluate, fallen, quat_to_rpy
from rwalk.sim import BatchedSim
from rwalk.starts import START_STREAM, Starts, sensor_observation, sensor_rows
from rwalk.tasks.base import Task
from rwalk.tasks.registry import resolve
from rwalk.world import World

__all__ = ["START_STREAM", "Core", "ResidualWalkCore", "StepResult"]


def _part(part: str, name: str, doc: str) -> property:
    """A read-only attribute of the core that is ``self.<part>.<name>``."""
    return property(lambda self: getattr(getattr(self, part), name), doc=doc)


class Core:
    """N envs of one task over one batched simulation.

    Args:
        config: the task's config (an ``EnvConfig``, or the task's own subclass).
        num_envs: N.
        seed: base seed in [0, 2^64); env i's k-th start uses the key
            (seed + i mod 2^64, START_STREAM, k), the same as a single env seeded
            seed + i. None draws a seed from the OS.
        task: a ``Task`` class or a registry name (``rwalk.tasks.TASKS``); None picks
            the task whose config class ``config`` is.

    Raises:
        ValueError: an unknown task (listing the known ones), a config of another
            task, or a bad value of the config (naming it).
    """

    def __init__(
        self,
        config: EnvConfig,
        num_envs: int,
        seed: int | None = None,
        task: type[Task] | str | None = None,
    ) -> None:
        n = checks.num_envs(num_envs)
        if not isinstance(config, EnvConfig):
            raise TypeError(f"config must be an EnvConfig, got {type(config).__name__}")
        task_type = resolve(task, config)
        self.config, self.num_envs = config, n
        self.world = World(config, n)
        self.sim = BatchedSim(self.world.model, n, config.num_threads)
        self.physics_steps = {"step": 0, "settle": 0}
        """Physics substeps run so far: stepping the envs, and settling starts."""
        self.resets = 0
        """Env resets so far (each start an env received)."""
        self.curriculum = Curriculum(
            config.terrain_levels, self.world.terrain_map, n, config.start_position
        )
        self.task: Task = task_type(config, self.world, n)
        """The task: actions, observation pieces, reward terms."""
        self.terms = self.task.reward_terms()
        """The task's declared reward terms, in the order they are added."""
        cycle = round(config.gait.cycle_time / self.world.control_dt)
        self.episodes = Episodes(n, [t.name for t in self.terms], self.world.control_dt,
                                 config.max_episode_steps, cycle)  # fmt: skip
        self.physics = PhysicsRandomizer(
            config.randomization, self.world.model, self.sim.batch, n, self.world.decimation
        )
        torso = self.world.model.body(TORSO_BODY).id
        self.pushes = PushSchedule(config.pushes, n, self.world.control_dt, self.sim.qvel,
                                   self.sim.applied_force(torso))  # fmt: skip
        self.starts = Starts(config, self.world, self.sim, self.curriculum.origins,
                             self.physics_steps)  # fmt: skip
        self.obs = torch.zeros(n, OBS_DIM, dtype=torch.float64)
        """Current sensor observation (the spec's 65 values). Shape: (N, 65)."""
        self._sensors = sensor_rows(self.sim)
        sources = Sources(self.obs, self.episodes, self.physics, self.world.terrain,
                          self.task, self.sim)  # fmt: skip
        self.observations = Observations(
            self.task.pieces(), self.task.observation, sources, config.observation_noise
        )
        self._started = False
        self.seed(seed)

    # The parts' state, as attributes of the core.
    model = _part("world", "model", "The compiled model.")
    terrain = _part("world", "terrain", "The ground (``rwalk.terrain.Terrain``).")
    terrain_map = _part("world", "terrain_map", "The map of terrain levels, or None.")
    geometry = _part("world", "geometry", "The legs (``LegGeometry``).")
    controller = _part("world", "controller", "The base gait (``BezierGaitController``).")
    dt = _part("world", "dt", "Physics timestep. Seconds.")
    decimation = _part("world", "decimation", "Physics substeps per env step.")
    control_dt = _part("world", "control_dt", "Duration of one env step. Seconds.")
    settled_tick = _part("world", "settled_tick", "Gait tick where settling leaves a start.")
    terrain_level = _part("curriculum", "terrain_level", "Each env's terrain level. (N,).")
    terrain_kind = _part("curriculum", "terrain_kind", "Each env's kind of tile. (N,).")
    episode_step = _part("episodes", "episode_step", "Steps toward truncation. (N,).")
    walked_steps = _part("episodes", "walked_steps", "Steps walked this episode. (N,).")
    x0 = _part("episodes", "x0", "Torso x at the episode's start. (N,). Metres.")
    y0 = _part("episodes", "y0", "Torso y at the episode's start. (N,). Metres.")
    fell = _part("episodes", "fell", "Whether the current episode terminated. (N,) bool.")
    episode_sums = _part("episodes", "sums", "Per-term sums of each episode. Each (N,).")
    episode_distance = _part("episodes", "distance", "Distance walked. (N,). Metres.")
    episode_speed_error = _part("episodes", "speed_error", "Summed |v_x - v*|. (N,). m/s.")
    phase = _part("task", "phase", "Gait phase in [0, 1) at the next step's start. (N,).")
    tick = _part("task", "tick", "The residual task's gait tick per env. (N,).")

    @property
    def seed_value(self) -> int:
        """The seed every draw is keyed by."""
        return self._seed

    @property
    def started(self) -> bool:
        """Whether every env has been reset at least once (step() needs it)."""
        return self._started

    @property
    def settle_progress(self) -> Callable[[int, int], None] | None:
        """Called with (physics steps done, total) of each settle: 0 first, then per chunk."""
        return self.starts.progress

    @settle_progress.setter
    def settle_progress(self, report: Callable[[int, int], None] | None) -> None:
        self.starts.progress = report

    def __getstate__(self) -> dict:
        """Config, seed, counters and every part's per-env state, plus each simulation's
        integration state: enough to rebuild the core and continue exactly where it was."""
        parts = ("episodes", "curriculum", "physics", "pushes", "task", "observations")
        return {
            "config": self.config, "num_envs": self.num_envs, "task": self.task.name,
            "seed": self.seed_value, "started": self._started, "resets": self.resets,
            "physics_steps": dict(self.physics_steps), "obs": self.obs.clone(),
            "sim_state": self.sim.state.copy(), "terrain_scale": self.terrain.scale,
            "starts": self.starts.state(), "pushes_done": self.pushes.done,
            "parts": {p: {k: v.clone() for k, v in getattr(self, p).state().items()}
                      for p in parts},
        }  # fmt: skip

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["config"], state["num_envs"], state["seed"], state["task"])
        if state["terrain_scale"] != self.terrain.scale:
            self.set_terrain_scale(state["terrain_scale"])
        self._started, self.resets = state["started"], state["resets"]
        self.physics_steps.update(state["physics_steps"])
        self.obs.copy_(state["obs"])
        self.sim.state[:] = state["sim_state"]
        self.starts.load_state(state["starts"])
        self.pushes.done = state["pushes_done"]
        for part, saved in state["parts"].items():
            for name, value in getattr(self, part).state().items():
                value.copy_(saved[name])
        self.physics.apply(torch.arange(self.num_envs))

    # ------------------------------------------------------------------ seeding
    def seed(self, seed: int | None) -> int:
        """Key every draw by ``seed`` and restart every env's counters.

        Returns:
            The seed used (drawn from the OS for None).

        Raises:
            ValueError: ``seed`` is not an integer in [0, 2^64) (naming it).
        """
        self._seed = seed = checks.seed(seed)
        for part in (self.starts, self.curriculum, self.task, self.physics, self.pushes,
                     self.observations):  # fmt: skip
            part.seed(seed)
        return seed

    # ------------------------------------------------------------------ reset
    def reset(
        self, env_ids: np.ndarray | Tensor | None = None, randomize: bool | None = None
    ) -> None:
        """Start new episodes in the given envs (all if None), settled and ready.

        A partial reset takes its starts from the settled-start pool when the
        config has one (``settle_pool > 0``); otherwise, and for full resets, the
        resetting envs are settled in place, all in one batched rollout.

        Args:
            env_ids: sorted unique env indices, or a boolean mask. Shape: (M,) or (N,).
            randomize: start-pose noise; None uses ``config.randomize``.
        """
        ids = checks.env_ids(env_ids, self.num_envs)
        if ids.size == 0:
            return
        randomize = self.config.randomize if randomize is None else bool(randomize)
        rows = torch.from_numpy(ids.astype(np.int64))
        ep = self.episodes
        self.curriculum.move(rows, ep.walked_steps, ep.distance, ep.fell, self.task.v_target,
                             self.control_dt)  # fmt: skip
        self.physics.reset(rows, self.starts.settle_tail)  # settle in the env's own world
        self.pushes.reset(rows)
        self.obs[rows] = self.starts.place(ids, randomize)
        self.task.reset(rows)
        self.task.forget_actions(rows)
        self.task.judge_commands(rows, ep.walked_steps, ep.speed_error, ep.fell)
        self.task.draw_commands(rows)
        start = self.obs[rows]
        ep.start(rows, start[:, OBS_POS.start], start[:, OBS_POS.start + 1],
                 start[:, OBS_LINVEL.start])  # fmt: skip
        self.resets += ids.size
        if ids.size == self.num_envs:
            self._started = True

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
        self.task.remember(action)
        ctrl, swing = self.task.act(action)
        ctrl = self.physics.delay(ctrl)
        self.observations.new_step()
        self.pushes.before_step()  # kicks at the control-step boundary
        diverged = torch.from_numpy(self.sim.rollout(ctrl))
        self.physics_steps["step"] += self.num_envs * self.decimation
        self.episodes.count()

        obs = self.obs
        obs.copy_(sensor_observation(self._sensors))
        rpy = quat_to_rpy(obs[:, OBS_QUAT])
        forward_velocity = obs[:, OBS_LINVEL.start]
        state = StepState(
            forward_velocity=forward_velocity,
            v_target=self.task.v_target,
            swing=swing,  # the gait's at the last substep's start, whose sensors these are
            contact=obs[:, OBS_CONTACT] > 0.5,
            rpy=rpy,
            y=obs[:, OBS_POS.start + 1],
            y0=self.episodes.y0,
            weights=self.config.reward_weights,
            terrain_kind=self.curriculum.terrain_kind,
            sources=self.observations.sources,
        )
        terms = evaluate(self.terms, state)
        if bool(diverged.any()):
            terms = {name: term.masked_fill(diverged, 0.0) for name, term in terms.items()}
        # Left to right, so that the reward equals sum(terms.values()) to the last bit.
        reward = sum(terms.values(), torch.zeros_like(forward_velocity))
        terminated = fallen(rpy) | diverged
        moved = forward_velocity.masked_fill(diverged, 0.0)
        truncated = self.episodes.record(terms, moved, state.v_target, terminated)
        self.task.redraw_commands(self.episodes.walked_steps)  # the next step's targets
        return StepResult(self.piece("observation"), reward, terms, terminated, truncated,
                          diverged)  # fmt: skip

    def check_action(self, action: Tensor | np.ndarray) -> Tensor:
        """Validate and clip an action batch (``rwalk.checks.action``). Returns float64
        (N, task.action_dim)."""
        task = self.task
        return checks.action(action, self.num_envs, task.action_dim, task.name,
                             task.action_layout)  # fmt: skip

    # ------------------------------------------------------------------ extras
    def curriculum_state(self) -> dict[str, Tensor]:
        """What a checkpoint keeps of the envs beside the policy: the terrain curriculum's
        levels (``terrain_level``; none without a map) and the command curriculum's weights
        (``command_weights``, where there is one). Empty where neither is."""
        commands = self.task.commands
        weights = {} if commands is None else {"command_weights": commands.weights.clone()}
        return self.curriculum.checkpoint() | weights

    def load_curriculum_state(self, state: dict[str, Tensor]) -> str | None:
        """Go on from a checkpoint's ``curriculum_state()``; returns a line for the log where
        it was of another number of envs (``Curriculum.load_checkpoint``) or of other command
        bins (``CommandWeights.load``), else None.

        Raises:
            ValueError: naming the field, if the state is not what ``curriculum_state``
                writes.
        """
        notes = [self.curriculum.load_checkpoint(state)]
        commands = self.task.commands
        if commands is not None and "command_weights" in state:
            notes.append(commands.load(state["command_weights"]))
        return "; ".join(note for note in notes if note) or None

    def set_terrain_scale(self, scale: float) -> None:
        """Scale the heightfield's roughness for all envs (0 flat .. 1 full) at once; new
        starts are placed on the new ground (``World.set_terrain_scale``).

        Raises:
            ValueError: naming the world or the config field that rules it out.
        """
        self.world.set_terrain_scale(scale, self.config)
        self.sim.set_model(self.model)
        self.starts.set_model(self.model)

    def set_reward(self, costs: GaitCosts | None = None, shaping: Shaping | None = None) -> None:
        """From the next step on, the reward's gait costs and training shaping are these
        (None: as they are), on a config that has them: the same terms with new values
        (rwalk-train's --late-iterations stage), in ``config`` too.

        Raises:
            ValueError: a part the config has not, or values that add or remove a term
                (naming the terms).
        """
        changes = {"costs": costs, "shaping": shaping}
        changes = {name: value for name, value in changes.items() if value is not None}
        for name in changes:
            if getattr(self.config, name) is None:
                raise ValueError(f"set_reward: this env's config has no {name} to change")
        config = dataclasses.replace(self.config, **changes)
        if config.costs is not None:
            config.costs.check_reach(self.world.geometry, config.top_speed)
        old, self.task.config = self.task.config, config
        try:
            terms = self.task.reward_terms()
        finally:
            self.task.config = old
        names, before = [t.name for t in terms], [t.name for t in self.terms]
        if names != before:
            raise ValueError(f"set_reward changes the values of the reward's terms, not which "
                             f"terms there are: {before} would become {names}")  # fmt: skip
        self.config = self.task.config = config
        self.terms = terms

    def phase_features(self) -> Tensor:
        """(sin 2πφ, cos 2πφ) of the gait phase. Shape: (N, 2)."""
        return self.task.phase_features()

    def piece(self, name: str) -> Tensor:
        """A named observation piece of the task (``rwalk.observations``), exact:
        ``"observation"`` is the spec observation. Shape: (N, size) float64.

        Raises:
            ValueError: naming the piece and listing the task's pieces.
        """
        return self.observations.read(name)

    def piece_size(self, name: str) -> int:
        """Width of the piece ``name`` (see ``piece``)."""
        return self.observations.size(name)

    @property
    def rollout_seconds(self) -> float:
        """Wall time spent in MuJoCo rollouts so far, stepping and settling. Seconds."""
        return self.sim.rollout_seconds + self.starts.rollout_seconds

    @property
    def settle_share(self) -> float:
        """Fraction of all physics substeps so far spent settling starts."""
        total = self.physics_steps["step"] + self.physics_steps["settle"]
        return self.physics_steps["settle"] / total if total else 0.0

    def episode_log(self, env_ids: Tensor) -> dict[str, Tensor]:
        """Per-env statistics of the episodes ending in ``env_ids`` (call before reset;
        ``rwalk.episodes.Episodes.log``). Each shape: (M,)."""
        return self.episodes.log(env_ids, self.task.v_target)


#: The name the core had when it ran one task; the residual task is still its default.
ResidualWalkCore = Core
