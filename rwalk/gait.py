"""The fixed diagonal (trot) Bézier gait, evaluated in torch for many envs at once.

The gait is open loop in its phase: a function of phase alone, so the foot
targets of a whole control period (K physics substeps) for N envs come out of
one vectorised call. Everything is built from elementwise IEEE arithmetic and
``rwalk.exactmath``, so the tables and targets are the same bits on any CPU and
for any batch size. Each leg alternates a straight stance sweep (front to
back, on the stance line) and a Bézier swing (back to front, above it). The
diagonal pairs FL+RR and FR+RL are half a cycle apart.

Stride convention: ``step_length`` is the distance the body advances per gait
cycle when the feet do not slip. A foot is on the ground for
``duty_factor * cycle_time`` and sweeps ``duty_factor * step_length`` in that
time, so the body's speed is ``step_length / cycle_time``, the spec's expected
velocity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import NamedTuple

import torch
from torch import Tensor

from rwalk import exactmath
from rwalk.gaitmath import TROT_OFFSETS, advance_phase, bernstein_curve, leg_phases, trot_targets
from rwalk.kinematics import LegGeometry, leg_ik

__all__ = ["TROT_OFFSETS", "BezierGaitController", "GaitParameters", "GaitShape", "advance_phase",
           "bernstein_curve", "swing_control_points"]  # fmt: skip


class GaitShape(NamedTuple):
    """Per-env gait parameters that change the foot path (the rest stay those of
    the controller's ``GaitParameters``). Each a float64 tensor broadcastable to
    the phase's shape, e.g. (N, 1) against phases (N, K). Metres."""

    step_height: Tensor
    step_length: Tensor
    body_height: Tensor


@dataclass(frozen=True)
class GaitParameters:
    """Parameters of the base trot. Lengths in metres, times in seconds."""

    step_height: float = 0.025
    """Height of the swing apex above the stance line."""
    step_length: float = 0.08
    """Stride: distance the body advances per cycle without slip."""
    cycle_time: float = 0.6
    """Duration of one gait cycle."""
    body_height: float = 0.07
    """Commanded height of the hip points above the ground."""
    duty_factor: float = 0.65
    """Fraction of the cycle a foot spends in stance. Above 0.5 the diagonal pairs
    overlap with all four feet down, which stops the body rocking about the
    diagonal support line (at 0.5 the robot slipped to ~55% of its speed)."""
    stance_depth: float = 0.005
    """How far below the ground surface the stance line is commanded, so the
    position servos press the feet into the ground rather than hover."""
    foot_spread: float = 0.0
    """Extra sideways offset of every foot, outwards positive."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"GaitParameters.{f.name} must be a finite number, got {value!r}")
        positive = ("step_height", "cycle_time", "body_height")
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"GaitParameters.{name} must be > 0, got {getattr(self, name)!r}")
        if self.step_length < 0:
            raise ValueError(f"GaitParameters.step_length must be >= 0, got {self.step_length!r}")
        if not 0.0 < self.duty_factor < 1.0:
            raise ValueError(
                f"GaitParameters.duty_factor must be in (0, 1), got {self.duty_factor!r}"
            )
        if self.stance_depth < 0:
            raise ValueError(f"GaitParameters.stance_depth must be >= 0, got {self.stance_depth!r}")
        if self.step_height >= self.body_height:
            raise ValueError(
                f"GaitParameters.step_height ({self.step_height!r}) must be below "
                f"body_height ({self.body_height!r}): the swing foot would rise above the hip"
            )

    @property
    def expected_velocity(self) -> float:
        """Forward speed of the gait without slip: step_length / cycle_time. m/s."""
        return self.step_length / self.cycle_time

    @property
    def stance_sweep(self) -> float:
        """Distance a stance foot travels relative to the body: duty x stride. Metres."""
        return self.duty_factor * self.step_length


def swing_control_points(duty_factor: float) -> Tensor:
    """Normalised swing curve: x in half-sweeps (-1 -> +1), z in step heights.

    Degree 6. The end tangents match the stance velocity, so a foot leaves and
    meets the ground at zero ground speed (no scuffing, no touchdown slip). The
    vertical velocity is zero at both ends and the apex (t = 0.5) is exactly 1.
    Shape: (7, 2).
    """
    degree = 6
    # Stance speed in half-sweeps per unit of the swing parameter: the stance
    # covers 2 half-sweeps in duty*T, the swing lasts (1-duty)*T.
    overshoot = 2.0 * (1.0 - duty_factor) / duty_factor / degree
    lift = 64.0 / 50.0  # makes z(0.5) = 1 for z-controls (0, 0, h, h, h, 0, 0)
    x = [-1.0, -1.0 - overshoot, -1.0 - overshoot, 0.0, 1.0 + overshoot, 1.0 + overshoot, 1.0]
    z = [0.0, 0.0, lift, lift, lift, 0.0, 0.0]
    return torch.tensor([x, z], dtype=torch.float64).T


class BezierGaitController:
    """Diagonal trot foot targets and joint targets for N envs and K substeps.

    Args:
        params: the gait.
        geometry: the legs (for the hip positions, foot radius and IK).
        dt: physics timestep, seconds.
        dtype: dtype of everything it returns.
    """

    def __init__(
        self,
        params: GaitParameters | None = None,
        geometry: LegGeometry | None = None,
        dt: float = 0.002,
        dtype: torch.dtype = torch.float64,
    ) -> None:
        self.params = params if params is not None else GaitParameters()
        self.geometry = geometry if geometry is not None else LegGeometry()
        if not (dt > 0 and math.isfinite(dt)):
            raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
        self.dt = dt
        self.dtype = dtype
        self.leg_offsets = torch.tensor(TROT_OFFSETS, dtype=dtype)
        self.swing_points = swing_control_points(self.params.duty_factor).to(dtype)
        p, g = self.params, self.geometry
        # Stance line: foot centre one radius above the ground, pressed stance_depth into it.
        self.stance_z = -p.body_height + g.foot_radius - p.stance_depth
        spread = torch.tensor([1.0, -1.0, 1.0, -1.0], dtype=dtype) * p.foot_spread
        self.neutral = torch.stack(
            (
                torch.zeros(4, dtype=dtype),
                torch.tensor(g.abduction_offsets, dtype=dtype) + spread,
                torch.full((4,), self.stance_z, dtype=dtype),
            ),
            dim=-1,
        )
        self._check_reachable()
        self.period = round(self.params.cycle_time / dt)
        if abs(self.period * dt - self.params.cycle_time) > 1e-9:
            raise ValueError(
                f"GaitParameters.cycle_time ({self.params.cycle_time!r} s) must be a whole number "
                f"of physics steps of {dt!r} s"
            )
        # The env only ever evaluates the gait at whole substeps from phase 0, so one
        # cycle of base targets is tabulated once and looked up by integer tick.
        ticks = torch.arange(self.period, dtype=dtype)
        self.target_table, self.swing_table = self.foot_targets(ticks / self.period)
        """Base foot targets and swing flags at each tick. Shapes: (P, 4, 3), (P, 4)."""
        angle = 2.0 * math.pi * self.phase(torch.arange(self.period))
        self.phase_table = torch.stack((exactmath.sin(angle), exactmath.cos(angle)), -1)
        """(sin 2πφ, cos 2πφ) of the phase φ at each tick. Shape: (P, 2) float64."""

    def _check_reachable(self) -> None:
        """Raise ValueError if the stance line cannot be reached (an impossible gait)."""
        p = self.params
        half = 0.5 * p.stance_sweep
        probe = self.neutral.unsqueeze(0).repeat(3, 1, 1)
        probe[0, :, 0] = half
        probe[2, :, 0] = -half
        _, ok = leg_ik(probe, self.geometry)
        if not bool(ok.all()):
            raise ValueError(
                f"GaitParameters(body_height={p.body_height!r}, step_length={p.step_length!r}, "
                f"duty_factor={p.duty_factor!r}, foot_spread={p.foot_spread!r}): the stance "
                f"line is outside the legs' workspace (leg reach "
                f"{self.geometry.min_knee_reach:.3f}..{self.geometry.max_knee_reach:.3f} m)"
            )

    def phase(self, tick: Tensor) -> Tensor:
        """Gait phase in [0, 1) of integer ticks (substeps since phase 0). Same shape."""
        return torch.remainder(tick, self.period).to(self.dtype) / self.period

    def phase_features(self, tick: Tensor) -> Tensor:
        """(sin 2πφ, cos 2πφ) of the gait phase φ at integer ticks. (...,) -> (..., 2)."""
        return self.phase_table[torch.remainder(tick, self.period)]

    def leg_phases(self, phase: Tensor) -> Tensor:
        """Each leg's phase in [0, 1). (...,) -> (..., 4). Stance is [0, duty)."""
        return leg_phases(phase, self.leg_offsets)

    def is_swing(self, tick: Tensor) -> Tensor:
        """Swing flags per leg at integer ticks. (...,) -> (..., 4) bool."""
        return self.swing_table[torch.remainder(tick, self.period)]

    def foot_targets(self, phase: Tensor, shape: GaitShape | None = None) -> tuple[Tensor, Tensor]:
        """Base-gait foot targets in the hip frames.

        Args:
            phase: gait phase in [0, 1). Shape: (...).
            shape: per-env step height, step length and body height, each
                broadcastable to ``phase``; None uses the controller's parameters.

        Returns:
            targets: foot-centre targets. Shape: (..., 4, 3).
            swing: True for legs in swing. Shape: (..., 4).
        """
        p = self.params
        if shape is None:
            step_height, step_length, stance_z = p.step_height, p.step_length, self.stance_z
        else:  # the same operations as the scalar case, per env and leg
            step_height, step_length, body_height = (v.unsqueeze(-1) for v in shape)
            stance_z = -body_height + self.geometry.foot_radius - p.stance_depth
        return trot_targets(phase, step_height, step_length, stance_z, p.duty_factor,
                            self.leg_offsets, self.swing_points, self.neutral)  # fmt: skip

    def swing_at(self, phase: Tensor) -> Tensor:
        """Swing flags per leg at continuous phases. (...,) -> (..., 4) bool."""
        return self.leg_phases(phase) >= self.params.duty_factor

    def phase_features_at(self, phase: Tensor) -> Tensor:
        """(sin 2πφ, cos 2πφ) of continuous phases, with ``rwalk.exactmath``. (...,) -> (..., 2)."""
        angle = 2.0 * math.pi * phase
        return torch.stack((exactmath.sin(angle), exactmath.cos(angle)), -1)

    def joint_targets(
        self, tick: Tensor, substeps: int, residuals: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        """Servo targets for the next K substeps from per-env ticks and foot residuals.

        Args:
            tick: substeps since phase 0 of each env at the start of the period.
                Shape: (N,) int64.
            substeps: K, physics substeps in the control period.
            residuals: foot offsets in metres, hip frame, held over the period.
                Shape: (N, 4, 3); None for the pure base gait.

        Returns:
            ctrl: joint targets in actuator order. Shape: (N, K, 12).
            reachable: False where a foot target had to be projected. Shape: (N, K, 4).
        """
        offsets = torch.arange(substeps, device=tick.device)
        targets = self.target_table[torch.remainder(tick.unsqueeze(-1) + offsets, self.period)]
        if residuals is not None:
            targets = targets + residuals.unsqueeze(1)
        joints, reachable = leg_ik(targets, self.geometry)
        return joints.flatten(-2), reachable

    def joint_targets_at(
        self, phases: Tensor, shape: GaitShape, residuals: Tensor | None = None
    ) -> Tensor:
        """Servo targets at continuous per-env phases and gait parameters.

        Args:
            phases: phase at each substep. Shape: (N, K).
            shape: per-env parameters, each of shape (N,).
            residuals: foot offsets in metres, hip frame, held over the period.
                Shape: (N, 4, 3); None for the pure gait.

        Returns:
            Joint targets in actuator order. Shape: (N, K, 12).
        """
        targets, _ = self.foot_targets(phases, GaitShape(*(v.unsqueeze(-1) for v in shape)))
        if residuals is not None:
            targets = targets + residuals.unsqueeze(1)
        joints, _ = leg_ik(targets, self.geometry, flag_unreachable=False)
        return joints.flatten(-2)
