"""The core's step for one env, near the cost of its physics alone (the Gymnasium view's).

``Core.step`` spends most of a one-env step in the fixed cost of
some 150 small torch calls (~1.4 µs each), against ~100 µs of physics for five
4 ms substeps. ``SingleStep`` runs the same pipeline with the same functions
(``leg_ik``, ``quat_to_rpy``, the declared reward terms, ``fallen``: each written once
for tensors, arrays and floats, see ``rwalk.arrayops``) on numpy arrays for the
K x 4 legs' inverse kinematics and on Python floats for the observation's
handful of values, and calls MuJoCo directly. Same operations in the same
order, so the same bits as env 0 of the batched step (tests/test_single.py).

It reads and writes the core's own state (tick, counters, observation, episode
sums) through numpy views of its tensors, so the two steps can be mixed freely.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from rwalk.constants import ACTION_DIM, OBS_CONTACT
from rwalk.core import Core
from rwalk.kinematics import leg_ik
from rwalk.rewards import StepState, evaluate, fallen, quat_to_rpy

#: Action dtypes taken without conversion checks (torch's step accepts these too).
_FAST_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))


class SingleStepResult(NamedTuple):
    """What one step of a one-env core returns, as numpy and Python values."""

    obs: np.ndarray
    """Spec observation: a live view of the core's, valid until its next step or
    reset (copy it to keep it). Shape: (65,) float64."""
    reward: float
    """Sum of the weighted terms."""
    terms: dict[str, float]
    """Weighted reward terms by name."""
    terminated: bool
    """Fell (|roll| or |pitch| > π/3) or diverged."""
    truncated: bool
    """Reached max_episode_steps without terminating."""
    diverged: bool
    """The simulation blew up this step (MuJoCo reset it)."""
    phase: float
    """Gait phase in [0, 1) at the start of the next step (``core.phase[0]``)."""
    lateral_offset: float
    """Torso y - y0, metres."""


class SingleStep:
    """``Core.step`` for a core of one env, on numpy and floats.

    Args:
        core: a core that ``SingleStep.supports``.
    """

    @staticmethod
    def supports(core: Core) -> bool:
        """Whether ``SingleStep`` can step ``core``: one env of a task with a float
        pipeline (``Task.single_step``: the residual task), without velocity commands."""
        return core.num_envs == 1 and core.task.single_step and core.config.command_range is None

    def __init__(self, core: Core) -> None:
        if core.num_envs != 1:
            raise ValueError(f"SingleStep needs a core of 1 env, got num_envs={core.num_envs}")
        self.core = core
        controller = core.controller
        k = core.decimation
        # Base targets of ticks t .. t+K-1 as one slice: the table continued periodically.
        ticks = np.arange(controller.period + k) % controller.period
        self._targets = controller.target_table.numpy()[ticks]
        self._swing = tuple(tuple(row) for row in controller.swing_table.tolist())
        self._sensors = core.sim.sensordata[0]
        self._bind()

    def __getstate__(self) -> dict:
        """Only the core: the views of its arrays are rebuilt on unpickling."""
        return {"core": self.core}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["core"])

    def _bind(self) -> None:
        """Numpy views of the core's state tensors (they share memory)."""
        core = self.core
        self._tensors = (core.tick, core.episode_step, core.walked_steps, core.y0, core.obs,
                         core.episode_distance, core.episode_speed_error,
                         *core.episode_sums.values())  # fmt: skip
        self._action = core.task.action.numpy()[0]  # Task.remember's, for the action rate
        self._last_action = core.task.last_action.numpy()[0]
        (self._tick, self._episode_step, self._walked, self._y0, obs, self._distance,
         self._speed_error) = (t.numpy() for t in self._tensors[:7])  # fmt: skip
        self._obs = obs[0]
        self._sums = {name: total.numpy() for name, total in core.episode_sums.items()}
        episodes = core.episodes
        self._recent, self._recent_sum = episodes.recent.numpy()[0], episodes.recent_sum.numpy()
        self._slot = episodes.slot.numpy()

    def step(self, action: np.ndarray) -> SingleStepResult:
        """Advance the env by one control period, like ``core.step(action[None])``.

        Args:
            action: residuals in [-1, 1] (clipped). Shape: (12,).

        Raises:
            ValueError: wrong shape or dtype, or a non-finite value (naming it).
            RuntimeError: before the first reset.
        """
        core = self.core
        if not core.started:
            raise RuntimeError("call reset() on all envs before step()")
        if self._tensors[4] is not core.obs or self._tensors[0] is not core.tick:
            self._bind()  # the core's tensors were replaced (e.g. by unpickling)
        cfg = core.config
        checked = self._check_action(action)
        self._last_action[:] = self._action  # Task.remember
        self._action[:] = checked
        residuals = checked.reshape(4, 3) * cfg.residual_scale
        k = core.decimation
        tick = int(self._tick[0])
        period = core.controller.period
        joints, _ = leg_ik(
            self._targets[tick : tick + k] + residuals, core.geometry, flag_unreachable=False
        )
        diverged = core.sim.rollout_all(joints.reshape(1, k, ACTION_DIM))
        core.physics_steps["step"] += k
        # Sensors are those of the last substep's start.
        swing = self._swing[(tick + k - 1) % period]
        next_tick = (tick + k) % period
        self._tick[0] = next_tick
        self._episode_step[0] += 1
        self._walked[0] += 1

        obs = self._obs
        obs[:] = self._sensors
        obs[OBS_CONTACT] = self._sensors[OBS_CONTACT] > 0
        values = obs.tolist()
        rpy = quat_to_rpy(tuple(values[3:7]))
        y0 = float(self._y0[0])
        forward_velocity = values[7]
        state = StepState(
            forward_velocity=forward_velocity,
            v_target=cfg.expected_velocity,
            swing=swing,
            contact=tuple(v > 0.5 for v in values[OBS_CONTACT]),
            rpy=rpy,
            y=values[1],
            y0=y0,
            weights=cfg.reward_weights,
            terrain_kind=core.curriculum.terrain_kind,
            sources=core.observations.sources,
        )
        # A term reading the core's parts (state.sources) gives a tensor of one env.
        terms = {
            name: term if isinstance(term, float) else float(term[0])
            for name, term in evaluate(core.terms, state).items()
        }
        if diverged:
            terms = dict.fromkeys(terms, 0.0)
            forward_velocity = 0.0
        reward = sum(terms.values(), 0.0)  # left to right, as the batched step
        terminated = bool(fallen(rpy)) or diverged
        truncated = int(self._episode_step[0]) >= cfg.max_episode_steps and not terminated
        for name, term in terms.items():
            self._sums[name][0] += term
        self._distance[0] += forward_velocity * core.control_dt
        self._speed_error[0] += abs(forward_velocity - cfg.expected_velocity)
        slot = int(self._slot)  # the last cycle's velocities, as Episodes.record keeps them
        self._recent_sum[0] += forward_velocity - self._recent[slot]
        self._recent[slot] = forward_velocity
        self._slot[...] = (slot + 1) % self._recent.size
        return SingleStepResult(
            obs, reward, terms, terminated, truncated, diverged,
            phase=float(next_tick) / period, lateral_offset=values[1] - y0,
        )  # fmt: skip

    def _check_action(self, action: np.ndarray) -> np.ndarray:
        """Float64 action clipped to [-1, 1]; anything unusual goes through the core's
        check, which names the problem. Shape: (12,)."""
        if (
            type(action) is np.ndarray
            and action.shape == (ACTION_DIM,)
            and action.dtype in _FAST_DTYPES
        ):
            action = action.astype(np.float64)
            if np.isfinite(action).all():
                return np.minimum(np.maximum(action, -1.0), 1.0)
        checked = self.core.check_action(torch.as_tensor(action).reshape(1, -1))
        return checked[0].numpy()
