"""Episodes: per-env counters, truncation, term sums, metrics, and the one auto-reset step.

``Episodes`` keeps what the current episode of each env has done: its steps
(toward truncation, and actually walked), where it started, whether it fell,
the sum of each reward term, the distance walked and the summed velocity
error. ``log`` reads an ending episode's statistics before its reset.

``step(core, action)`` steps a core and, for the envs whose episodes ended,
returns their statistics (read before the reset) and resets them. The rsl-rl
adapter and the evaluation both go through it, so an episode's return,
length, fall, speed and velocity error mean the same everywhere.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple, Protocol

import torch
from torch import Tensor


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


class Episodes:
    """The current episode of each of N envs.

    Args:
        num_envs: N.
        terms: names of the reward terms, in the order they are summed.
        control_dt: duration of one env step. Seconds.
        max_steps: env steps before truncation.
        cycle_steps: env steps of one gait cycle (the window of ``cycle_speed``).
    """

    def __init__(
        self,
        num_envs: int,
        terms: Sequence[str],
        control_dt: float,
        max_steps: int,
        cycle_steps: int = 1,
    ) -> None:
        n = num_envs
        self.control_dt = control_dt
        self.max_steps = max_steps
        self.episode_step = torch.zeros(n, dtype=torch.long)
        """Env steps counted towards truncation at max_steps. Shape: (N,). Starts at 0,
        but a trainer may set it (rsl-rl's init_at_random_ep_len spreads the first
        truncations out), so statistics count ``walked_steps`` instead."""
        self.walked_steps = torch.zeros(n, dtype=torch.long)
        """Env steps actually taken in the current episode. Shape: (N,)."""
        self.x0 = torch.zeros(n, dtype=torch.float64)
        """Torso x at the episode's start. Shape: (N,)."""
        self.y0 = torch.zeros(n, dtype=torch.float64)
        """Torso y at the episode's start. Shape: (N,)."""
        self.fell = torch.zeros(n, dtype=torch.bool)
        """Whether the current (or just ended) episode terminated. Shape: (N,)."""
        self.sums = {name: torch.zeros(n, dtype=torch.float64) for name in terms}
        """Per-term sums over the current episode. Each shape: (N,)."""
        self.distance = torch.zeros(n, dtype=torch.float64)
        """Sum of forward velocity x control dt over the current episode. Shape: (N,). m."""
        self.speed_error = torch.zeros(n, dtype=torch.float64)
        """Sum of |v_x - v*| over the current episode's steps. Shape: (N,). m/s."""
        self.recent = torch.zeros(n, max(1, cycle_steps), dtype=torch.float64)
        """The forward velocities of the last gait cycle's steps, a ring (the episode's
        first velocity before it has walked a cycle). Shape: (N, cycle steps). m/s."""
        self.recent_sum = torch.zeros(n, dtype=torch.float64)
        """The running sum of ``recent``. Shape: (N,). m/s."""
        self.ripple = torch.zeros(n, dtype=torch.float64)
        """Sum of |v_x - its mean over the last gait cycle| over the current episode's steps:
        the speed's ripple within the stride, which a per-step error cannot drop below.
        Shape: (N,). m/s."""
        self.slot = torch.zeros((), dtype=torch.long)
        """The ring's slot the next step writes (the same for every env)."""

    def start(self, rows: Tensor, x0: Tensor, y0: Tensor, v0: Tensor) -> None:
        """Begin the episodes of ``rows`` at torso positions (x0, y0), forward velocity v0.
        Shapes: (M,)."""
        window = self.recent.shape[1]
        self.recent[rows] = v0.unsqueeze(-1)
        self.recent_sum[rows] = v0 * window
        self.episode_step[rows] = 0
        self.walked_steps[rows] = 0
        self.x0[rows] = x0
        self.y0[rows] = y0
        self.fell[rows] = False
        for total in (*self.sums.values(), self.distance, self.speed_error, self.ripple):
            total[rows] = 0.0

    def count(self) -> None:
        """One more env step in every episode (in place: callers step inside
        torch.inference_mode, as rsl-rl does, and reset outside it)."""
        self.episode_step += 1
        self.walked_steps += 1

    def record(
        self,
        terms: dict[str, Tensor],
        velocity: Tensor,
        target: Tensor | float,
        terminated: Tensor,
    ) -> Tensor:
        """Add a step's terms, distance and velocity error; note falls.

        Args:
            terms: weighted reward terms by name. Each shape: (N,).
            velocity: forward velocity, 0 where the simulation diverged. Shape: (N,). m/s.
            target: the velocity the reward tracks. (N,) or a float. m/s.
            terminated: fell or diverged. Shape: (N,) bool.

        Returns:
            truncated: reached max_steps without terminating. Shape: (N,) bool.
        """
        self.fell.copy_(terminated)
        truncated = (self.episode_step >= self.max_steps) & ~terminated
        for name, term in terms.items():
            self.sums[name] += term
        self.distance += velocity * self.control_dt
        self.speed_error += (velocity - target).abs()
        slot = int(self.slot)
        self.recent_sum += velocity - self.recent[:, slot]  # elementwise: batch-independent
        self.recent[:, slot] = velocity
        self.slot.fill_((slot + 1) % self.recent.shape[1])
        self.ripple += (velocity - self.recent_sum / self.recent.shape[1]).abs()
        return truncated

    def cycle_speed(self) -> Tensor:
        """Each env's forward velocity averaged over the last gait cycle's steps. Shape:
        (N,). m/s."""
        return self.recent_sum / self.recent.shape[1]

    def log(self, env_ids: Tensor, target: Tensor | float) -> dict[str, Tensor]:
        """Per-env statistics of the episodes ending in ``env_ids`` (call before reset).

        Args:
            target: the velocity each env tracked (m/s): a float, or per env (N,).

        Returns:
            Per-term episode sums (``"sum/<term>"``), ``"length"`` (steps actually
            walked, whatever ``episode_step`` was set to), ``"forward_velocity"``
            (mean over the episode, m/s), ``"target_velocity"`` (what the reward
            tracked, m/s), ``"velocity_error"`` (mean |v_x - v*| per step, m/s),
            ``"velocity_bias"`` (forward_velocity - target_velocity, m/s) and
            ``"velocity_ripple"`` (mean |v_x - its last gait cycle's mean| per step,
            m/s). Each shape: (M,).
        """
        length = self.walked_steps[env_ids].to(torch.float64)
        log = {f"sum/{name}": total[env_ids] for name, total in self.sums.items()}
        log["length"] = length
        log["forward_velocity"] = self.distance[env_ids] / (length.clamp(min=1.0) * self.control_dt)
        log["target_velocity"] = (
            target[env_ids] if isinstance(target, Tensor) else torch.full_like(length, target)
        )
        log["velocity_error"] = self.speed_error[env_ids] / length.clamp(min=1.0)
        log["velocity_bias"] = log["forward_velocity"] - log["target_velocity"]
        log["velocity_ripple"] = self.ripple[env_ids] / length.clamp(min=1.0)
        return log

    def state(self) -> dict[str, Tensor]:
        """Per-env tensors to keep when the core is pickled."""
        return {
            "episode_step": self.episode_step, "walked_steps": self.walked_steps,
            "x0": self.x0, "y0": self.y0, "fell": self.fell, "distance": self.distance,
            "speed_error": self.speed_error, "recent": self.recent,
            "recent_sum": self.recent_sum, "slot": self.slot, "ripple": self.ripple,
            **{f"sum/{name}": total for name, total in self.sums.items()},
        }  # fmt: skip


class EpisodeEnd(NamedTuple):
    """The episodes that ended in one step."""

    ids: Tensor
    """Their envs, sorted. Shape: (M,)."""
    stats: dict[str, Tensor]
    """Per episode, each (M,): ``Episodes.log``'s ``"sum/<term>"``, ``"length"``,
    ``"forward_velocity"``, ``"target_velocity"`` and ``"velocity_error"`` (mean
    |v_x - v*| per step), plus ``"return"`` (the sum of the term sums),
    ``"terminated"`` (fell or diverged) and ``"diverged"``."""


class Steppable(Protocol):
    """What ``step`` needs of a core."""

    def step(self, action: Tensor) -> StepResult: ...
    def episode_log(self, env_ids: Tensor) -> dict[str, Tensor]: ...
    def reset(self, env_ids: Tensor | None = None) -> None: ...


def step(
    core: Steppable, action: Tensor, auto_reset: bool = True
) -> tuple[StepResult, EpisodeEnd | None]:
    """``core.step(action)``, then the statistics of the episodes that ended and,
    with ``auto_reset``, their resets (rsl-rl's convention: the returned result
    still shows the last step of the ended episodes, the core the new ones).

    Returns:
        The step's result, and None where no episode ended.
    """
    result = core.step(action)
    done = result.terminated | result.truncated
    if not bool(done.any()):
        return result, None
    ids = done.nonzero().squeeze(-1)
    stats = core.episode_log(ids)
    sums = [value for key, value in stats.items() if key.startswith("sum/")]
    stats["return"] = sum(sums, torch.zeros_like(stats["length"]))
    stats["terminated"] = result.terminated[ids]
    stats["diverged"] = result.diverged[ids]
    if auto_reset:
        core.reset(ids)
    return result, EpisodeEnd(ids, stats)
