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

import torch
from torch import Tensor

from rwalk import arrayops, exactmath
from rwalk.constants import OBS_CONTACT, OBS_JOINT_VEL
from rwalk.kinematics import LegGeometry
from rwalk.observations import HEIGHT_OFFSETS, foot_clearances, foot_velocities

#: Largest size of a weight (the spec's are at most 300 a step; a weight of 1e308 made the
#: reward infinite and PPO's loss NaN).
MAX_WEIGHT = 1e6


def _require_finite_numbers(config: object) -> None:
    """Raise ValueError naming ``Class.field`` for a field that is not a finite number
    within ±MAX_WEIGHT (fields declared as tuples are checked by their class)."""
    for f in fields(config):
        if str(f.type).startswith("tuple"):
            continue
        value = getattr(config, f.name)
        if (
            not isinstance(value, (int, float))
            or isinstance(value, bool)
            or not abs(value) <= MAX_WEIGHT
        ):
            raise ValueError(
                f"{type(config).__name__}.{f.name} must be a finite number within "
                f"±{MAX_WEIGHT:g}, got {value!r}"
            )


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
        _require_finite_numbers(self)


#: Fraction of a swing, from its lift-off (0) to its touch-down (1), over which the
#: clearance term asks for ``clearance_target``: the middle half, where the swing curve is
#: above 5/6 of the step height (at its ends the foot must meet the ground).
MID_SWING = (0.25, 0.75)


@dataclass(frozen=True)
class GaitCosts:
    """Costs of how the robot walks: clearance, slip, effort (none in the spec's reward).

    Each weight is a cost's size (>= 0); the reward adds ``-weight * term``. The sizes
    were set against the spec's velocity term (300 x (1 - |v_x - v*|): 1 mm/s of
    velocity error costs 0.3 per step) on the base gait's figures in docs/adaptive.md.
    """

    clearance: float = 1500.0
    """Per metre that a mid-swing foot (MID_SWING) passes below ``clearance_target`` above
    the ground under it or 3 cm ahead of it, summed over feet."""
    clearance_target: float = 0.015
    """Clearance asked of the bottom of a mid-swing foot above that ground. Metres."""
    clearance_target_per_speed: float = 0.0
    """The clearance asked grows with the target speed: max(clearance_target, this x v*),
    seconds (metres per m/s; 0: clearance_target at every target)."""
    slip: float = 20.0
    """Per m/s of horizontal world speed of each foot touching the ground, summed over feet."""
    power: float = 1.0
    """Per watt of mechanical servo power, sum over joints of |torque x joint speed|."""
    power_per_metre_above: float = 0.0
    """Above this target speed (m/s) a watt is priced per metre walked, as the cost of
    transport prices it: the power term is scaled by this / |v*| (half its weight at twice
    this speed); at and below it, per watt. 0: every watt the same at every target."""
    stumble: float = 0.0
    """Per foot touching something in mid swing (MID_SWING), where the swing curve is
    highest: it hit the ground or an obstacle's face (legged_gym's stumble term reads
    contact forces, which these sensors do not give). 0: off, and no term."""

    def __post_init__(self) -> None:
        _require_finite_numbers(self)
        for name in ("clearance", "slip", "power", "stumble"):
            if getattr(self, name) < 0:
                raise ValueError(
                    f"GaitCosts.{name} is the size of a cost and must be >= 0, "
                    f"got {getattr(self, name)!r}"
                )
        if self.power_per_metre_above < 0:
            raise ValueError(
                f"GaitCosts.power_per_metre_above is a speed in m/s and must be >= 0 (0: off), "
                f"got {self.power_per_metre_above!r}"
            )
        if self.clearance_target_per_speed < 0:
            raise ValueError(
                f"GaitCosts.clearance_target_per_speed is seconds (metres per m/s) and must be "
                f">= 0, got {self.clearance_target_per_speed!r}"
            )
        self.check_reach(LegGeometry())

    def check_reach(self, geometry: LegGeometry, top_speed: float = 0.0) -> None:
        """Raise ValueError naming ``clearance_target`` unless it is > 0 and within the
        leg's reach (thigh + shin), or naming ``clearance_target_per_speed`` where the
        target it asks at ``top_speed`` (m/s, the fastest v*) is beyond that reach."""
        reach = geometry.thigh_length + geometry.shin_length
        if not 0.0 < self.clearance_target <= reach:
            raise ValueError(
                f"GaitCosts.clearance_target must be > 0 and within the leg's reach "
                f"({reach:g} m), got {self.clearance_target!r}"
            )
        if self.clearance_target_per_speed * top_speed > reach:
            raise ValueError(
                f"GaitCosts.clearance_target_per_speed {self.clearance_target_per_speed!r} s "
                f"asks {self.clearance_target_per_speed * top_speed:g} m at {top_speed:g} m/s, "
                f"beyond the leg's reach ({reach:g} m)"
            )


@dataclass(frozen=True)
class Shaping:
    """Training-only reward terms beside the spec's (none in the spec's reward; the
    evaluations measure the spec's terms): a kernel on the speed error that pays most near
    v*, and a separate reward for staying up (legged_gym and Isaac Lab track velocity with
    a kernel; the spec's 300 x (1 - |v_x - v*|) is mostly a survival reward, 1 mm/s of
    error costing 0.3 of ~300 per step)."""

    tracking: float = 0.0
    """Weight of the kernel 1 / (1 + ((v_x - v*) / sigma)^2) per step (1 at v*, 1/2 at
    sigma off)."""
    sigma: float = 0.02
    """The kernel's half-width. m/s."""
    sigma_per_speed: float = 0.0
    """The half-width grows with the target speed: max(sigma, sigma_per_speed x v*), a share
    of v* where that is wider (0: sigma at every target)."""
    alive: float = 0.0
    """Reward per step."""
    action_rate: float = 0.0
    """Cost per unit of the action's squared change since the last step, summed over its
    values (legged_gym's ``action_rate``; an episode's first step counts from the zero
    action, the base gait). A size >= 0; 0: the term at weight 0 (exact zeros), so that a
    late stage can raise it (--late-action-rate)."""
    latency_action_rate: float = 0.0
    """Cost per unit of the action's squared change (``action_rate``'s quantity) per
    substep of each env's servo delay (``PhysicsRandomizer.lag``: its drawn latency, 0
    where no delay applies), under the name ``latency_action_rate``: 70
    costs 70 x that change where the servos lag one substep, 210 at three, nothing without
    a lag. A size >= 0; 0: the term at weight 0 (exact zeros)."""
    kind_tracking: float = 0.0
    """Weight added to the spec's velocity tracking term 1 - |v_x - v*| on the envs of
    ``tracking_kinds`` of tile (a terrain-levels map's), under the name ``kind_tracking``:
    -270 makes that term's weight 30 there instead of the spec's 300, so that a robot
    standing in the stepping stones' gaps earns a tenth of what it does elsewhere."""
    tracking_kinds: tuple[str, ...] = ("stones",)
    """The kinds of tile of ``kind_tracking``."""

    def __post_init__(self) -> None:
        _require_finite_numbers(self)
        if not isinstance(self.tracking_kinds, tuple) or not all(
            isinstance(kind, str) for kind in self.tracking_kinds
        ):
            raise ValueError(f"Shaping.tracking_kinds must be a tuple of kinds of tile, "
                             f"got {self.tracking_kinds!r}")  # fmt: skip
        if not self.sigma > 0:
            raise ValueError(f"Shaping.sigma must be > 0 m/s, got {self.sigma!r}")
        if self.sigma_per_speed < 0:
            raise ValueError(f"Shaping.sigma_per_speed is a share of v* and must be >= 0, "
                             f"got {self.sigma_per_speed!r}")  # fmt: skip
        for name in ("action_rate", "latency_action_rate"):
            if getattr(self, name) < 0:
                raise ValueError(f"Shaping.{name} is the size of a cost and must be >= 0, "
                                 f"got {getattr(self, name)!r}")  # fmt: skip


def tracking_kernel(
    forward_velocity: Tensor, target: Tensor | float, sigma: Tensor | float
) -> Tensor:
    """1 / (1 + ((v_x - v*) / sigma)^2): a rational kernel (correctly rounded operations
    only: the same bits in any batch). Shape: (N,) -> (N,)."""
    error = (forward_velocity - target) / sigma
    return 1.0 / (1.0 + error * error)


def grown_with_speed(floor: float, per_speed: float, target: Tensor | float) -> Tensor | float:
    """max(floor, per_speed x v*) at each target (one product and a maximum: the same bits
    in any batch); ``floor`` itself where ``per_speed`` is 0. Shape: (N,) -> (N,)."""
    if not per_speed:
        return floor
    if isinstance(target, Tensor):
        return torch.clamp(target * per_speed, min=floor)
    return max(floor, target * per_speed)


def per_metre_above(speed: float, target: Tensor | float) -> Tensor | float:
    """speed / max(speed, |v*|) at each target: 1 at and below ``speed``, the price per
    metre above it (one maximum and one division: the same bits in any batch); 1 where
    ``speed`` is 0. Shape: (N,) -> (N,)."""
    if not speed:
        return 1.0
    if isinstance(target, Tensor):
        return speed / torch.clamp(target.abs(), min=speed)
    return speed / max(speed, abs(target))


def kernel_width(shaping: Shaping, target: Tensor | float) -> Tensor | float:
    """The kernel's half-width at each target: max(sigma, sigma_per_speed x v*). m/s."""
    return grown_with_speed(shaping.sigma, shaping.sigma_per_speed, target)


def action_rate(action: Tensor, last_action: Tensor) -> Tensor:
    """Sum over the action's values of (a - a_last)^2, added column by column (the same bits
    in any batch). Shape: (N, D), (N, D) -> (N,)."""
    change = action - last_action
    total = change[:, 0] * change[:, 0]
    for j in range(1, change.shape[1]):
        total = total + change[:, j] * change[:, j]
    return total


def shaping_terms(shaping: Shaping, map_kinds: tuple[str, ...] = ()) -> tuple[RewardTerm, ...]:
    """The terms of ``shaping``: ``tracking_kernel``, ``alive``, ``action_rate`` (minus
    its size times ``action_rate`` of the task's last two actions),
    ``latency_action_rate`` (the same change times each env's servo delay in substeps,
    ``PhysicsRandomizer.lag``) and ``kind_tracking``
    (the spec's tracking term on the envs whose kind of tile, an index into ``map_kinds``,
    is one of ``shaping.tracking_kinds``; 0 without a map), each at its weight, 0
    included: the same terms whatever the values, so that ``Core.set_reward`` can move any
    of them."""
    chosen = torch.tensor([i for i, kind in enumerate(map_kinds) if kind in shaping.tracking_kinds],
                          dtype=torch.long)  # fmt: skip

    def kind_tracking(s: StepState) -> Tensor:
        if not shaping.kind_tracking or s.terrain_kind is None:  # weight 0: nothing per step
            return s.forward_velocity * 0.0
        on = torch.isin(s.terrain_kind, chosen).to(torch.float64)
        return velocity_tracking(s.forward_velocity, s.v_target) * on

    def latency_action_rate(s: StepState) -> Tensor:
        if not shaping.latency_action_rate:  # weight 0: nothing per step
            return s.forward_velocity * 0.0
        task = s.sources.task
        return action_rate(task.action, task.last_action) * s.sources.physics.lag()

    return (
        RewardTerm("tracking_kernel", shaping.tracking,
                   lambda s: tracking_kernel(s.forward_velocity, s.v_target,
                                             kernel_width(shaping, s.v_target))),
        RewardTerm("alive", shaping.alive, lambda s: s.forward_velocity * 0.0 + 1.0),
        RewardTerm("action_rate", -shaping.action_rate,
                   lambda s: action_rate(s.sources.task.action, s.sources.task.last_action)),
        RewardTerm("latency_action_rate", -shaping.latency_action_rate, latency_action_rate),
        RewardTerm("kind_tracking", shaping.kind_tracking, kind_tracking),
    )  # fmt: skip


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


def _legs(per_leg: Tensor) -> Tensor:
    """Sum over the last dimension (4 legs or 12 joints), left to right. (N, L) -> (N,)."""
    values = per_leg.unbind(-1)
    total = values[0]
    for value in values[1:]:
        total = total + value
    return total


def _mid_swing(swing_progress: Tensor) -> Tensor:
    """Legs whose swing progress is within MID_SWING. (N, 4) -> (N, 4) bool."""
    low, high = MID_SWING
    return (swing_progress >= low) & (swing_progress <= high)


def clearance_shortfall(
    clearance: Tensor, swing_progress: Tensor, target: Tensor | float
) -> Tensor:
    """Sum over feet in mid swing (progress within MID_SWING) of max(0, target - clearance).

    Args:
        clearance: height of each foot's bottom above the ground it is passing. Shape:
            (N, 4). Metres.
        swing_progress: each leg's progress through its swing, 0 at lift-off, 1 at
            touch-down; outside [0, 1] in stance. Shape: (N, 4).
        target: the clearance asked, one for all or one per env. Shape: () or (N,). Metres.
    """
    if isinstance(target, Tensor) and target.dim():
        target = target.unsqueeze(-1)
    return _legs(torch.clamp(target - clearance, min=0.0) * _mid_swing(swing_progress))


def mid_swing_contacts(contact: Tensor, swing_progress: Tensor) -> Tensor:
    """How many feet touch something while in mid swing (progress within MID_SWING).

    Args:
        contact: foot contact flags. Shape: (N, 4) bool.
        swing_progress: as ``clearance_shortfall``'s. Shape: (N, 4).
    """
    return _legs((contact & _mid_swing(swing_progress)).to(swing_progress.dtype))


def foot_slip(contact: Tensor, foot_velocity: Tensor) -> Tensor:
    """Sum over feet touching the ground of their horizontal world speed.

    Args:
        contact: foot-ground contact flags. Shape: (N, 4) bool.
        foot_velocity: each foot's world velocity. Shape: (N, 4, 3). m/s.
    """
    vx, vy = foot_velocity[..., 0], foot_velocity[..., 1]
    return _legs(torch.sqrt(vx * vx + vy * vy) * contact)


def servo_power(torque: Tensor, joint_velocity: Tensor) -> Tensor:
    """Mechanical power of the servos: sum over joints of |torque x joint speed|.
    Shapes: (N, 12), (N, 12) -> (N,). Watts."""
    return _legs(abs(torque * joint_velocity))


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
    terrain_kind: Tensor | None = None
    """Each env's kind of tile, an index into its terrain-levels map's kinds (None without
    a map). Shape: (N,) int64."""
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


def cost_terms(costs: GaitCosts, world) -> tuple[RewardTerm, ...]:
    """The terms of ``costs``, each weighted by minus its size, for the tasks of ``world``
    (``rwalk.world.World``: leg geometry, gait controller): swing clearance (each leg's
    swing progress at the sensed substep, from the task's ``sensed_phase``), foot slip and
    servo power (the last substep's torques, computed with its sensors; per metre above
    ``power_per_metre_above``)."""
    radius = world.geometry.foot_radius
    controller = world.controller
    duty = controller.params.duty_factor
    samples = len(HEIGHT_OFFSETS)

    def swing_progress(s: StepState) -> Tensor:
        return (controller.leg_phases(s.sources.task.sensed_phase) - duty) / (1.0 - duty)

    def clearance(s: StepState) -> Tensor:
        heights = foot_clearances(s.sources.sensors, s.sources.terrain).view(-1, 4, samples)
        passing = torch.minimum(heights[..., 0], heights[..., 1]) - radius  # under, ahead
        target = grown_with_speed(costs.clearance_target, costs.clearance_target_per_speed,
                                  s.v_target)  # fmt: skip
        return clearance_shortfall(passing, swing_progress(s), target)

    def slip(s: StepState) -> Tensor:
        contact = s.sources.sensors[:, OBS_CONTACT] > 0.5
        return foot_slip(contact, foot_velocities(s.sources.sensors))

    def power(s: StepState) -> Tensor:
        torque = torch.from_numpy(s.sources.sim.actuator_force)
        watts = servo_power(torque, s.sources.sensors[:, OBS_JOINT_VEL])
        return watts * per_metre_above(costs.power_per_metre_above, s.v_target)

    def stumble(s: StepState) -> Tensor:
        return mid_swing_contacts(s.sources.sensors[:, OBS_CONTACT] > 0.5, swing_progress(s))

    terms = (
        RewardTerm("clearance", -costs.clearance, clearance),
        RewardTerm("slip", -costs.slip, slip),
        RewardTerm("power", -costs.power, power),
    )
    return terms + ((RewardTerm("stumble", -costs.stumble, stumble),) if costs.stumble else ())


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
