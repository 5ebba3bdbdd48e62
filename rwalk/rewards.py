"""Reward terms and termination as pure functions of batched tensors.

Each function also takes numpy arrays, or floats for one env (a tuple of floats
for a vector), with the same operations and so the same bits (``rwalk.arrayops``);
the single Gymnasium env computes its reward on floats. Each term returns its
unweighted value; ``RewardWeights`` holds the spec's weights, and the reward is
exactly the sum of the weighted terms. A task declares its terms as
``RewardTerm``s (name, weight, function of a ``StepState``); specs, episode
sums, logs and docs take their names from that declaration. Only elementwise IEEE arithmetic and
``rwalk.exactmath`` (no reductions over a dimension, whose summation order
depends on the tensor's length), so each env's terms are the same bits whatever
the batch size and CPU.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

from torch import Tensor

from rwalk import arrayops, exactmath


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
    xp = arrayops.of(quat)
    w, x, y, z = xp.unstack(xp.as_f64(quat))
    sin_pitch = xp.clamp(2.0 * (w * y - z * x), -1.0, 1.0)
    # roll, asin(sin_pitch) (as exactmath.asin computes it) and yaw in one atan2 call.
    numerators = (2.0 * (w * x + y * z), sin_pitch, 2.0 * (w * z + x * y))
    denominators = (
        1.0 - 2.0 * (x * x + y * y),
        xp.sqrt((1.0 - sin_pitch) * (1.0 + sin_pitch)),
        1.0 - 2.0 * (y * y + z * z),
    )
    return exactmath.atan2(xp.stack(numerators), xp.stack(denominators))


def velocity_tracking(forward_velocity: Tensor, expected_velocity: float) -> Tensor:
    """1 - |v_x - v*|. Shape: (N,) -> (N,)."""
    return 1.0 - abs(forward_velocity - expected_velocity)


def contact_pattern(swing: Tensor, contact: Tensor, match: float, mismatch: float) -> Tensor:
    """Sum over legs of ``match`` where the foot does what its phase asks, else ``mismatch``.

    A swing foot should be in the air, a stance foot on the ground.

    Args:
        swing: swing flags. Shape: (N, 4) bool.
        contact: foot-ground contact flags. Shape: (N, 4) bool.
    """
    xp = arrayops.of(swing, contact)
    ok = xp.not_equal(swing, contact)
    leg = xp.unstack(xp.select(ok, match, mismatch))
    return leg[0] + leg[1] + leg[2] + leg[3]  # left to right, not a length-dependent .sum


def stability(rpy: Tensor) -> Tensor:
    """roll² + pitch² + yaw², added left to right. Shape: (N, 3) -> (N,)."""
    roll, pitch, yaw = arrayops.of(rpy).unstack(rpy)
    return roll * roll + pitch * pitch + yaw * yaw


def lateral(y: Tensor, y0: Tensor) -> Tensor:
    """|y - y0|: sideways drift from the episode's start. Shape: (N,) -> (N,)."""
    return abs(y - y0)


class StepState(NamedTuple):
    """What reward terms read after a step: a batch of tensors, or floats for one env."""

    forward_velocity: Tensor
    """Torso v_x, world frame. Shape: (N,). m/s."""
    v_target: Tensor | float
    """Velocity the gait should walk at. Shape: (N,) or a float. m/s."""
    swing: Tensor
    """Swing flags of the gait at the sensed substep. Shape: (N, 4) bool."""
    contact: Tensor
    """Foot-ground contact flags. Shape: (N, 4) bool."""
    rpy: Tensor
    """Roll, pitch, yaw. Shape: (N, 3). Radians."""
    y: Tensor
    """Torso y. Shape: (N,). Metres."""
    y0: Tensor
    """Torso y at the episode's start. Shape: (N,). Metres."""
    weights: RewardWeights
    """The config's weights (for the contact scores)."""
    sources: Any = None
    """Everything else a term may read: the core's parts (``rwalk.observations.Sources``:
    sensors, episodes, drawn physics, terrain, task, simulation), as batched tensors
    (N = 1 in the one-env float pipeline). A term that needs new data reads it here."""


@dataclass(frozen=True)
class RewardTerm:
    """One reward term: the reward adds ``weight * fn(state)`` under ``name``."""

    name: str
    weight: float
    fn: Callable[[StepState], Tensor]
    """Unweighted value from a ``StepState``. Shape: (N,) (a float for one env)."""


def spec_terms(weights: RewardWeights) -> tuple[RewardTerm, ...]:
    """The spec's four terms, in the order they are reported and added."""
    return (
        RewardTerm("velocity_tracking", weights.velocity_tracking,
                   lambda s: velocity_tracking(s.forward_velocity, s.v_target)),
        RewardTerm("contact_pattern", weights.contact_pattern,
                   lambda s: contact_pattern(s.swing, s.contact, s.weights.contact_match,
                                             s.weights.contact_mismatch)),
        RewardTerm("stability", weights.stability, lambda s: stability(s.rpy)),
        RewardTerm("lateral", weights.lateral, lambda s: lateral(s.y, s.y0)),
    )  # fmt: skip


#: Names of the spec's reward terms, in the order they are reported.
TERM_NAMES: tuple[str, ...] = tuple(term.name for term in spec_terms(RewardWeights()))


def evaluate(terms: tuple[RewardTerm, ...], state: StepState) -> dict[str, Tensor]:
    """Each weighted term by name (each shape (N,), or a float for one env)."""
    return {term.name: term.weight * term.fn(state) for term in terms}


#: Roll or pitch beyond this ends the episode (the robot fell). Radians.
TILT_LIMIT = math.pi / 3


def fallen(rpy: Tensor) -> Tensor:
    """|roll| > π/3 or |pitch| > π/3. Shape: (N, 3) -> (N,) bool."""
    roll, pitch, _ = arrayops.of(rpy).unstack(rpy)
    return (abs(roll) > TILT_LIMIT) | (abs(pitch) > TILT_LIMIT)
