"""Measurements of how the robot walks, shared by tests, runners and docs."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from rwalk.constants import OBS_CONTACT, OBS_FOOT_POS, OBS_LINVEL, OBS_POS, OBS_QUAT
from rwalk.core import ResidualWalkCore
from rwalk.rewards import quat_to_rpy


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
