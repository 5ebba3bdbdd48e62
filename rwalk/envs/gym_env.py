"""The spec's single environments, Gymnasium views of the core with N=1:
``ResidualWalkEnv`` and ``AdaptiveGaitEnv``."""

from __future__ import annotations

import os
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import torch

from rwalk.config import EnvConfig
from rwalk.constants import OBS_POS
from rwalk.core import Core
from rwalk.envs.single_step import SingleStep
from rwalk.gait import GaitParameters
from rwalk.tasks import AdaptiveGaitConfig, GaitBounds
from rwalk.tasks.adaptive_gait import ADAPTED

_SPEC_DEFAULTS = {
    "model_path": EnvConfig.model_path,
    "gait": GaitParameters(),
    "residual_scale": EnvConfig.residual_scale,
    "max_episode_steps": EnvConfig.max_episode_steps,
    "settle_steps": EnvConfig.settle_steps,
}


class ResidualWalkEnv(gym.Env):
    """Learn per-leg foot residuals on top of a fixed diagonal Bézier trot.

    ## Action Space
    ``Box(-1, 1, (12,), float32)``: (x, y, z) foot offsets for FL, FR, RL, RR in the
    hip frame, times ``residual_scale`` metres. Values outside [-1, 1] are clipped.

    ## Observation Space
    ``Box(-inf, inf, (65,), float32)``: torso position (3), quaternion wxyz (4),
    linear velocity (3) and angular velocity (3) in the world frame; 12 joint
    angles; 12 joint velocities; 4 x 3 foot positions and 4 x 3 foot velocities
    in the torso frame; 4 foot-ground contact flags (FL, FR, RL, RR).

    ## Rewards
    - velocity_tracking: ``300 (1 - |v_x - v*|)``, ``v* = step_length / cycle_time``
    - contact_pattern: per leg ``+0.05`` if a swing foot is up or a stance foot is
      down, else ``-0.2``
    - stability: ``-3 (roll² + pitch² + yaw²)``
    - lateral: ``-|y - y0|``, y0 the torso's y when the episode started

    The reward is exactly the sum; ``info["reward_components"]`` holds each term.

    ## Starting State
    Standing in the gait's phase-0 pose at x = -3.5 m, y = 0 (with
    ``options={"randomize": True}``: ±2 cm in x and y, ±0.1 rad yaw, ±0.02 rad
    roll and pitch), then ``settle_steps`` steps of the zero-residual gait.

    ## Episode End
    Terminated when |roll| or |pitch| > π/3 (or the simulation diverged);
    truncated after ``max_episode_steps`` steps. ``gymnasium.make`` builds it with
    ``max_episode_steps=None`` (no limit of its own) and its ``TimeLimit`` wrapper
    truncates at ``spec.max_episode_steps`` (1000, or ``make``'s argument): one limit.

    ## Info
    On reset and step: ``phase`` (gait phase in [0, 1) at the start of the next
    step), ``lateral_offset`` (torso y − y0, metres) and ``start_position`` (x0,
    y0 of the torso at the episode's start, metres) — with the observation, the
    inputs of an exported policy (``rwalk.export.policy_input``). On step
    also ``reward_components`` (each term by name), ``body_height`` (metres) and
    ``diverged``.

    ## Arguments
    As in the spec. Alternatively ``config`` (an ``EnvConfig``) sets everything,
    e.g. the flat world or start randomisation; then leave the spec's arguments
    at their defaults.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 50}
    #: The core's task.
    task: ClassVar[str] = "residual_walk"

    def __init__(
        self,
        model_path: str | os.PathLike[str] = EnvConfig.model_path,
        gait_params: GaitParameters | None = None,
        residual_scale: float = EnvConfig.residual_scale,
        max_episode_steps: int | None = EnvConfig.max_episode_steps,
        settle_steps: int = EnvConfig.settle_steps,
        seed: int | None = None,
        *,
        config: EnvConfig | None = None,
        render_mode: str | None = None,
    ) -> None:
        # None: no limit of the env's own (gymnasium.make's TimeLimit truncates instead).
        self._truncates = max_episode_steps is not None
        spec_args = {
            "model_path": str(model_path),
            "gait": gait_params if gait_params is not None else GaitParameters(),
            "residual_scale": residual_scale,
            "max_episode_steps": (
                max_episode_steps if self._truncates else EnvConfig.max_episode_steps
            ),
            "settle_steps": settle_steps,
        }
        if config is None:
            config = self._config(spec_args)
        elif spec_args != _SPEC_DEFAULTS:
            raise ValueError("pass either config or the spec's constructor arguments, not both")
        elif (
            not self._truncates and config.max_episode_steps != _SPEC_DEFAULTS["max_episode_steps"]
        ):
            raise ValueError(
                f"config.max_episode_steps={config.max_episode_steps} has no effect under "
                "gymnasium.make, whose TimeLimit ends episodes: pass "
                f"gymnasium.make(..., max_episode_steps={config.max_episode_steps})"
            )
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.core = Core(config, 1, seed=seed, task=self.task)
        self.single_step = SingleStep(self.core) if SingleStep.supports(self.core) else None
        """The core's one-env step on numpy and floats (``rwalk.envs.single_step``), where
        the task has one; None: steps go through the batched pipeline with N = 1."""
        task = self.core.task
        self.observation_space = gym.spaces.Box(
            -np.inf, np.inf, (task.observation_dim,), np.float32
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, (task.action_dim,), np.float32)
        self._renderer = None

    def _config(self, spec_args: dict[str, Any]) -> EnvConfig:
        return EnvConfig(**spec_args)

    @property
    def config(self) -> EnvConfig:
        return self.core.config

    @property
    def expected_velocity(self) -> float:
        """step_length / cycle_time of the fixed gait. m/s."""
        return self.core.config.expected_velocity

    @property
    def terrain_scale(self) -> float:
        return self.core.terrain.scale

    def set_terrain_scale(self, scale: float) -> None:
        """Scale the terrain's roughness (0 flat .. 1 full); takes effect at once."""
        self.core.set_terrain_scale(scale)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        options = dict(options or {})
        randomize = options.pop("randomize", None)
        if options:
            raise ValueError(f"unknown reset options {sorted(options)} (known: 'randomize')")
        if seed is not None:
            self.core.seed(seed)
        self.core.reset(randomize=randomize)
        return self._observation(), self._info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        array = np.asarray(action)
        dim = self.core.task.action_dim
        if array.shape != (dim,):
            raise ValueError(
                f"action must have shape ({dim},) ({self.core.task.action_layout}), got "
                f"{array.shape}"
            )
        if self.single_step is None:
            return self._batched_step(array)
        # The core's one-env step: numpy and floats, the same bits as its batched step.
        result = self.single_step.step(array)
        obs = result.obs
        info = {
            "reward_components": result.terms,
            "body_height": float(obs[OBS_POS.start + 2]),
            "diverged": result.diverged,
            "phase": result.phase,
            "lateral_offset": result.lateral_offset,
            "start_position": (float(self.core.x0[0]), float(self.core.y0[0])),
        }
        return (
            obs.astype(np.float32),
            result.reward,
            result.terminated,
            self._truncates and result.truncated,
            info,
        )

    def _batched_step(self, array: np.ndarray):
        """``step`` through the core's batched pipeline (N = 1)."""
        result = self.core.step(torch.as_tensor(array).reshape(1, -1))
        info = {
            "reward_components": {name: float(term[0]) for name, term in result.terms.items()},
            "body_height": float(self.core.obs[0, OBS_POS.start + 2]),
            "diverged": bool(result.diverged[0]),
            **self._info(),
        }
        return (
            result.obs[0].numpy().astype(np.float32),
            float(result.reward[0]),
            bool(result.terminated[0]),
            self._truncates and bool(result.truncated[0]),
            info,
        )

    def _observation(self) -> np.ndarray:
        return self.core.piece("observation")[0].numpy().astype(np.float32)

    def _info(self) -> dict[str, float]:
        core = self.core
        return {
            "phase": float(core.phase[0]),
            "lateral_offset": float(core.obs[0, OBS_POS.start + 1] - core.y0[0]),
            "start_position": (float(core.x0[0]), float(core.y0[0])),
            **(
                {"target_velocity": float(core.task.target[0])} if core.config.command_range else {}
            ),
        }

    def __getstate__(self) -> dict[str, Any]:
        """Picklable (and deep-copyable): the core pickles its config and state; an
        open renderer is dropped and reopened by the next ``render()``."""
        return {**self.__dict__, "_renderer": None}

    def render(self) -> np.ndarray | None:
        """An RGB frame of the robot (needs an OpenGL backend, e.g. MUJOCO_GL=osmesa)."""
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode='rgb_array'")
            return None
        from rwalk.render import FrameRenderer

        if self._renderer is None:
            self._renderer = FrameRenderer(self.core.model)
        return self._renderer.frame(self.core.sim, 0)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


class AdaptiveGaitEnv(ResidualWalkEnv):
    """Foot residuals on a trot whose gait the policy also changes (AdaptiveGaitEnv.md).

    ## Action Space
    ``Box(-1, 1, (16,), float32)``: ``[0:4]`` deltas of step_height, step_length,
    cycle_time and body_height (``action x delta`` added each step, then clipped
    to the range); ``[4:16]`` the 12 foot residuals of ``ResidualWalkEnv``.

    ## Observation Space
    ``Box(-inf, inf, (69,), float32)``: the 65 values of ``ResidualWalkEnv``, then
    the four current gait parameters, each ``(value - centre) / half_width`` of
    its range.

    ## Rewards, Starting State, Episode End
    As ``ResidualWalkEnv``; the velocity term tracks the episode's target
    velocity: the starting gait's ``step_length / cycle_time``, or a draw from
    ``command_range``. Each reset returns the parameters to ``gait_params``.

    ## Info
    As ``ResidualWalkEnv``, plus ``gait_params`` (the four current values, SI
    units) and, with ``command_range``, ``target_velocity`` (m/s).

    ## Arguments
    Those of ``ResidualWalkEnv`` plus ``bounds`` (a ``GaitBounds``: range and
    delta scale of each parameter) and ``command_range`` (None, or (low, high)
    m/s); or ``config`` (an ``AdaptiveGaitConfig``) for everything.
    """

    task: ClassVar[str] = "adaptive_gait"

    def __init__(
        self,
        model_path: str | os.PathLike[str] = EnvConfig.model_path,
        gait_params: GaitParameters | None = None,
        residual_scale: float = EnvConfig.residual_scale,
        max_episode_steps: int | None = EnvConfig.max_episode_steps,
        settle_steps: int = EnvConfig.settle_steps,
        seed: int | None = None,
        *,
        bounds: GaitBounds | None = None,
        command_range: tuple[float, float] | None = None,
        config: AdaptiveGaitConfig | None = None,
        render_mode: str | None = None,
    ) -> None:
        self._adaptive = {"bounds": bounds or GaitBounds(), "command_range": command_range}
        if config is not None and (bounds is not None or command_range is not None):
            raise ValueError("pass either config or bounds/command_range, not both")
        super().__init__(
            model_path, gait_params, residual_scale, max_episode_steps, settle_steps, seed,
            config=config, render_mode=render_mode,
        )  # fmt: skip

    def _config(self, spec_args: dict[str, Any]) -> EnvConfig:
        return AdaptiveGaitConfig(**spec_args, **self._adaptive)

    def _info(self) -> dict[str, Any]:
        task = self.core.task
        params = task.gait_params()[0].tolist()
        return {
            **super()._info(),
            "gait_params": dict(zip(ADAPTED, params, strict=True)),
        }
