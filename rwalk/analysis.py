"""Measurements of how the robot walks, shared by tests, runners and docs."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch

from rwalk import episodes
from rwalk.constants import OBS_CONTACT, OBS_FOOT_POS, OBS_LINVEL, OBS_POS, OBS_QUAT
from rwalk.core import ResidualWalkCore
from rwalk.rewards import action_rate, quat_to_rpy


@dataclass(frozen=True)
class WalkReport:
    """Summary of N robots walking for a fixed time. Per-robot arrays have shape (N,)."""

    expected_velocity: float
    """step_length / cycle_time. m/s."""
    fell: np.ndarray
    """Whether |roll| or |pitch| exceeded π/3 at any step."""
    speed: np.ndarray
    """Displacement along the robot's initial heading / time (up to a fall). m/s."""
    heading_change: np.ndarray
    """Final yaw minus initial yaw (unwrapped). Radians."""
    sideways_drift: np.ndarray
    """Displacement perpendicular to the initial heading. Metres."""
    velocity_error: np.ndarray
    """Mean over steps before a fall of |v_x - v*| (the reward's tracking error). m/s."""
    foot_error: np.ndarray
    """Mean over steps before a fall and feet of the distance between each foot and
    its target (base gait + residual, torso frame) at the last substep. Metres."""
    contact_match: np.ndarray
    """Fraction of (step, foot) pairs before a fall where the foot touched the ground
    exactly when its gait phase was stance (the contact-pattern reward's condition)."""
    torque: np.ndarray
    """Mean over steps before a fall and servos of |servo torque| at the last substep. N·m."""
    seconds: float
    """Simulated time walked."""

    @property
    def fall_rate(self) -> float:
        return float(self.fell.mean())

    def summary(self) -> dict[str, float]:
        """Scalar figures: means over robots (speed over robots that did not fall)."""
        ok = ~self.fell
        return {
            "robots": float(self.fell.size),
            "seconds": self.seconds,
            "fall_rate": self.fall_rate,
            "speed": float(self.speed[ok].mean()) if ok.any() else math.nan,
            "expected_velocity": self.expected_velocity,
            "speed_ratio": float(self.speed[ok].mean() / self.expected_velocity)
            if ok.any()
            else math.nan,
            "abs_heading_change": float(np.abs(self.heading_change).mean()),
            "max_abs_heading_change": float(np.abs(self.heading_change).max()),
            "abs_sideways_drift": float(np.abs(self.sideways_drift).mean()),
            "max_abs_sideways_drift": float(np.abs(self.sideways_drift).max()),
            "velocity_error": float(self.velocity_error.mean()),
            "foot_error": float(self.foot_error.mean()),
            "contact_match": float(self.contact_match.mean()),
            "torque": float(self.torque.mean()),
        }


def walk(
    core: ResidualWalkCore,
    steps: int,
    policy=None,
) -> WalkReport:
    """Reset every env of ``core`` and walk ``steps`` env steps, recording the figures.

    Args:
        core: the envs (their config decides world, gait, starts and settling).
        steps: env steps to walk.
        policy: maps the (N, 65) observation to (N, 12) actions; None for the
            base gait (zero residuals).
    """
    core.reset()
    n = core.num_envs
    start_xy = core.obs[:, OBS_POS][:, :2].clone()
    start_yaw = quat_to_rpy(core.obs[:, OBS_QUAT])[:, 2].clone()
    yaw = start_yaw.clone()
    unwrapped = torch.zeros(n, dtype=torch.float64)
    fell = torch.zeros(n, dtype=torch.bool)
    stop_xy = start_xy.clone()
    alive_steps = torch.zeros(n, dtype=torch.float64)
    sums = {key: torch.zeros(n, dtype=torch.float64) for key in ("error", "foot", "contact", "tau")}
    zeros = torch.zeros(n, 12, dtype=torch.float64)
    hips = core.geometry.hip_tensor()
    with warnings.catch_warnings():  # a read-only MuJoCo output: only read here
        warnings.simplefilter("ignore", UserWarning)
        torque = torch.from_numpy(core.sim.actuator_force)
    controller, k = core.controller, core.decimation
    for _ in range(steps):
        action = zeros if policy is None else policy(core.obs)
        # What the servos aim at during the last substep (sensors are read at its start).
        sensed = torch.remainder(core.tick + (k - 1), controller.period)
        target = controller.target_table[sensed] + hips
        target = target + core.check_action(action).view(n, 4, 3) * core.config.residual_scale
        swing = controller.swing_table[sensed]
        result = core.step(action)
        alive = ~fell
        new_yaw = quat_to_rpy(result.obs[:, OBS_QUAT])[:, 2]
        unwrapped += torch.remainder(new_yaw - yaw + math.pi, 2 * math.pi) - math.pi
        yaw = new_yaw
        feet = result.obs[:, OBS_FOOT_POS].view(n, 4, 3)
        contact = result.obs[:, OBS_CONTACT] > 0.5
        per_step = {
            "error": (result.obs[:, OBS_LINVEL.start] - core.config.expected_velocity).abs(),
            "foot": (feet - target).norm(dim=-1).mean(-1),
            "contact": (contact != swing).double().mean(-1),
            "tau": torque.abs().mean(-1),
        }
        for key, value in per_step.items():
            sums[key] += alive * value
        alive_steps += alive
        stop_xy[alive] = result.obs[alive, :2]
        fell |= result.terminated
    seconds = steps * core.control_dt
    heading = torch.stack((torch.cos(start_yaw), torch.sin(start_yaw)), dim=-1)
    left = torch.stack((-torch.sin(start_yaw), torch.cos(start_yaw)), dim=-1)
    moved = stop_xy - start_xy
    walked_time = alive_steps * core.control_dt
    counted = alive_steps.clamp(min=1.0)
    return WalkReport(
        expected_velocity=core.config.expected_velocity,
        fell=fell.numpy(),
        speed=((moved * heading).sum(-1) / walked_time.clamp(min=core.control_dt)).numpy(),
        heading_change=unwrapped.numpy(),
        sideways_drift=(moved * left).sum(-1).numpy(),
        velocity_error=(sums["error"] / counted).numpy(),
        foot_error=(sums["foot"] / counted).numpy(),
        contact_match=(sums["contact"] / counted).numpy(),
        torque=(sums["tau"] / counted).numpy(),
        seconds=seconds,
    )


@dataclass(frozen=True)
class SpeedParts:
    """A policy's per-step speed error split into its parts (docs/learning.md, "What the
    ripple is"): each env's bias, a profile repeated in every gait cycle, and the rest.
    Mean absolute values over the walked steps, m/s, but where said."""

    error: float
    """|v_x - v*|."""
    bias: float
    """|an env's mean v_x - v*|, over envs."""
    profile: float
    """|the mean by gait-phase bin of v_x minus its env's mean|."""
    rest: float
    """|v_x - v* - its env's bias - the profile at its phase|."""
    rest_autocorrelation: float
    """The rest's autocorrelation one step later (nan without any rest)."""
    rest_high_frequency: float
    """Share of the rest's power above ``above`` Hz (nan without any rest)."""
    action_change: float
    """The action's squared change from the step before, summed over its values (the
    action-rate term's quantity, ``rwalk.rewards.action_rate``). Not m/s."""


class SpeedTrace(NamedTuple):
    """Paired episodes step by step (``speed_trace``). Each shape: (T, N), action (T, N, D)."""

    velocity: torch.Tensor
    """Torso v_x. m/s."""
    phase: torch.Tensor
    """Gait phase in [0, 1)."""
    walked: torch.Tensor
    """The steps to count (bool)."""
    action: torch.Tensor
    """The action sent."""


def speed_parts(
    trace: SpeedTrace, target: float, control_dt: float, bins: int = 40, above: float = 6.0
) -> SpeedParts:
    """Split the speed error of the walked steps of ``trace`` (``SpeedParts``).

    Args:
        target: v*. m/s.
        control_dt: seconds per step (for the spectrum).
        bins: gait-phase bins of the profile.
        above: frequency from which the rest's power counts as high. Hz.
    """
    velocity, phase, walked, action = trace
    counted = walked.double()
    error = (velocity - target).masked_fill(~walked, 0.0)
    steps = counted.sum(0)
    bias = error.sum(0) / steps.clamp(min=1.0)
    centred = (error - bias).masked_fill(~walked, 0.0)
    where = (phase * bins).long().clamp(0, bins - 1)
    total = torch.zeros(bins, dtype=torch.float64).index_add_(0, where[walked], centred[walked])
    seen = torch.zeros(bins, dtype=torch.float64).index_add_(0, where[walked], counted[walked])
    profile = (total / seen.clamp(min=1.0))[where].masked_fill(~walked, 0.0)
    rest = centred - profile
    power = (rest * rest).sum()
    spectrum = torch.fft.rfft(rest, dim=0).abs().square().sum(1)
    hertz = torch.fft.rfftfreq(rest.shape[0], d=control_dt)
    n = counted.sum()
    flat = action.flatten(0, 1)
    change = action_rate(flat[action.shape[1] :], flat[: -action.shape[1]])
    both = (walked[1:] & walked[:-1]).flatten()
    return SpeedParts(
        error=float(error.abs().sum() / n),
        bias=float(bias[steps > 0].abs().mean()),
        profile=float(profile.abs().sum() / n),
        rest=float(rest.abs().sum() / n),
        rest_autocorrelation=float((rest[1:] * rest[:-1]).sum() / power) if power else math.nan,
        rest_high_frequency=float(spectrum[hertz > above].sum() / spectrum.sum())
        if power
        else math.nan,
        action_change=float(change[both].mean()) if bool(both.any()) else math.nan,
    )


def speed_trace(
    env, policy=None, seed: int = 1000, skip: int = 50, low_pass: float | None = None
) -> SpeedTrace:
    """Walk one episode in every env of ``env`` (a ``BatchedEnv``; env i starts like a
    single env seeded ``seed + i``, as in ``rwalk.evaluation.evaluate``) and trace it.

    Args:
        policy: callable returning (N, action_dim) actions (``rwalk.evaluation.load_policy``);
            None: the base gait.
        skip: first steps of each episode not counted (the start).
        low_pass: a (0, 1] filter on the actions sent: each step ``low_pass`` of the
            policy's action and the rest of the last one sent (an evaluation-only probe of
            how much of the error is the policy's own jitter); None: as the policy acts.

    Returns:
        The ``SpeedTrace``, for ``speed_parts``.
    """
    core = env.core
    env.set_seed(seed)
    core.reset()
    if policy is not None and hasattr(policy, "reset"):
        policy.reset()
    n = core.num_envs
    sent = torch.zeros(n, core.task.action_dim, dtype=torch.float64)
    ended = torch.zeros(n, dtype=torch.bool)
    velocity, phase, walked, sent_actions = [], [], [], []
    with torch.inference_mode():
        for step in range(core.config.max_episode_steps):
            action = sent if policy is None else policy().double()
            if policy is not None and low_pass is not None:
                action = low_pass * action + (1.0 - low_pass) * sent
            sent = core.check_action(action)  # clipped, as the env acts on it
            sent_actions.append(sent)
            _, end = episodes.step(core, sent, auto_reset=False)
            features = core.phase_features()
            velocity.append(core.obs[:, OBS_LINVEL.start].clone())
            phase.append(torch.atan2(features[:, 0], features[:, 1]) / (2 * math.pi) % 1.0)
            walked.append(~ended if step >= skip else torch.zeros(n, dtype=torch.bool))
            if end is not None:
                ended[end.ids] = True  # its last step counts, the next episode's do not
            if bool(ended.all()):
                break
    return SpeedTrace(torch.stack(velocity), torch.stack(phase), torch.stack(walked),
                      torch.stack(sent_actions))  # fmt: skip
