"""Reward terms and termination as pure torch functions of batched tensors.

Each term returns its unweighted value; ``RewardWeights`` holds the spec's
weights, and the reward is exactly the sum of the weighted terms. Only
elementwise IEEE arithmetic and ``rwalk.exactmath`` (no reductions over a
dimension, whose summation order depends on the tensor's length), so each env's
terms are the same bits whatever the batch size and CPU.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch
from torch import Tensor

from rwalk import exactmath

#: Names of the reward terms, in the order they are reported.
TERM_NAMES: tuple[str, ...] = ("velocity_tracking", "contact_pattern", "stability", "lateral")


@dataclass(frozen=True)
class RewardWeights:
    """Weights of the spec's reward terms."""

    velocity_tracking: float = 300.0
    """Times (1 - |v_x - v*|)."""
    contact_pattern: float = 1.0
    """Times the per-leg contact score summed over legs."""
    stability: float = -3.0
    """Times roll² + pitch² + yaw² (radians)."""
    lateral: float = -1.0
    """Times |y - y0| (metres)."""
    contact_match: float = 0.05
    """Per-leg score when a swing foot is in the air or a stance foot is down."""
    contact_mismatch: float = -0.2
    """Per-leg score otherwise."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if (
                not isinstance(value, (int, float))
                or isinstance(value, bool)
                or not math.isfinite(value)
            ):
                raise ValueError(f"RewardWeights.{f.name} must be a finite number, got {value!r}")


def quat_to_rpy(quat: Tensor) -> Tensor:
    """Roll, pitch, yaw (ZYX Euler angles) from unit quaternions.

    Args:
        quat: (w, x, y, z). Shape: (..., 4).

    Returns:
        (roll, pitch, yaw) in radians, float64, from ``rwalk.exactmath`` (the same
        bits on any CPU and in any batch). Shape: (..., 3).
    """
    w, x, y, z = quat.to(torch.float64).unbind(-1)
    sin_pitch = torch.clamp(2.0 * (w * y - z * x), -1.0, 1.0)
    # roll, asin(sin_pitch) (as exactmath.asin computes it) and yaw in one atan2 call.
    numerators = (2.0 * (w * x + y * z), sin_pitch, 2.0 * (w * z + x * y))
    denominators = (
        1.0 - 2.0 * (x * x + y * y),
        torch.sqrt((1.0 - sin_pitch) * (1.0 + sin_pitch)),
        1.0 - 2.0 * (y * y + z * z),
    )
    return exactmath.atan2(torch.stack(numerators, -1), torch.stack(denominators, -1))


def velocity_tracking(forward_velocity: Tensor, expected_velocity: float) -> Tensor:
    """1 - |v_x - v*|. Shape: (N,) -> (N,)."""
    return 1.0 - (forward_velocity - expected_velocity).abs()


def contact_pattern(swing: Tensor, contact: Tensor, match: float, mismatch: float) -> Tensor:
    """Sum over legs of ``match`` where the foot does what its phase asks, else ``mismatch``.

    A swing foot should be in the air, a stance foot on the ground.

    Args:
        swing: swing flags. Shape: (N, 4) bool.
        contact: foot-ground contact flags. Shape: (N, 4) bool.
    """
    ok = swing != contact
    scores = torch.tensor([mismatch, match], dtype=torch.float64, device=ok.device)
    leg = scores[ok.long()].unbind(-1)
    return leg[0] + leg[1] + leg[2] + leg[3]  # left to right, not a length-dependent .sum


def stability(rpy: Tensor) -> Tensor:
    """roll² + pitch² + yaw², added left to right. Shape: (N, 3) -> (N,)."""
    roll, pitch, yaw = rpy.unbind(-1)
    return roll * roll + pitch * pitch + yaw * yaw


def lateral(y: Tensor, y0: Tensor) -> Tensor:
    """|y - y0|: sideways drift from the episode's start. Shape: (N,) -> (N,)."""
    return (y - y0).abs()


def compute_terms(
    *,
    forward_velocity: Tensor,
    expected_velocity: float,
    swing: Tensor,
    contact: Tensor,
    rpy: Tensor,
    y: Tensor,
    y0: Tensor,
    weights: RewardWeights,
) -> dict[str, Tensor]:
    """All weighted terms by name (each shape (N,)); the reward is their sum."""
    return {
        "velocity_tracking": weights.velocity_tracking
        * velocity_tracking(forward_velocity, expected_velocity),
        "contact_pattern": weights.contact_pattern
        * contact_pattern(swing, contact, weights.contact_match, weights.contact_mismatch),
        "stability": weights.stability * stability(rpy),
        "lateral": weights.lateral * lateral(y, y0),
    }


#: Roll or pitch beyond this ends the episode (the robot fell). Radians.
TILT_LIMIT = math.pi / 3


def fallen(rpy: Tensor) -> Tensor:
    """|roll| > π/3 or |pitch| > π/3. Shape: (N, 3) -> (N,) bool."""
    return (rpy[..., 0].abs() > TILT_LIMIT) | (rpy[..., 1].abs() > TILT_LIMIT)
