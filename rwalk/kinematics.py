"""Analytic forward and inverse kinematics of the 3-DOF legs, batched in torch (IK also numpy).

Each leg is a serial chain: an abduction joint about the torso's x axis at the
hip point, a hip joint about y offset sideways from it by ``abduction_offset``,
and a knee joint about y at the end of a thigh of ``thigh_length``. The foot
centre sits ``shin_length`` below the knee. At zero angles the leg hangs
straight down. Positive hip and knee angles swing the foot backwards; the knee
bends backwards (knee angle < 0), as on most small quadrupeds.

Foot positions here are in the *hip frame*: origin at the leg's hip point
(where the abduction axis meets the hip's plane), axes parallel to the torso.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from rwalk import arrayops, exactmath
from rwalk.arrayops import Tensor, torch
from rwalk.constants import LEG_NAMES, TORSO_BODY


@dataclass(frozen=True)
class LegGeometry:
    """Lengths, offsets and joint limits of the four legs."""

    hip_positions: tuple[tuple[float, float, float], ...] = (
        (0.075, 0.04, 0.0),
        (0.075, -0.04, 0.0),
        (-0.075, 0.04, 0.0),
        (-0.075, -0.04, 0.0),
    )
    """Hip points in the torso frame, one per leg (FL, FR, RL, RR). Metres."""
    abduction_offsets: tuple[float, ...] = (0.012, -0.012, 0.012, -0.012)
    """Signed sideways offset of the hip joint from the abduction axis (left +). Metres."""
    thigh_length: float = 0.05
    """Hip joint to knee joint. Metres."""
    shin_length: float = 0.06
    """Knee joint to the foot centre. Metres."""
    foot_radius: float = 0.0075
    """Radius of the spherical foot. Metres."""
    joint_lower: tuple[float, float, float] = (-0.7, -1.0, -2.7)
    """Lower limits of (abduction, hip, knee). Radians."""
    joint_upper: tuple[float, float, float] = (0.7, 2.2, -0.25)
    """Upper limits of (abduction, hip, knee). Radians."""

    @classmethod
    def from_model(cls, model) -> LegGeometry:
        """Read the geometry from a compiled ``mujoco.MjModel`` (robot.xml's naming)."""

        """Read the geometry from a compiled model (robot.xml's naming)."""

        def body_pos(name: str) -> np.ndarray:
            return np.asarray(model.body(name).pos, dtype=float)

        torso = model.body(TORSO_BODY).id
        hips, offsets = [], []
        for leg in LEG_NAMES:
            hip = model.body(f"{leg}_hip_link")
            if hip.parentid[0] != torso:
                raise ValueError(f"body {leg}_hip_link must be a child of {TORSO_BODY!r}")
            hips.append(tuple(float(v) for v in hip.pos))
            offsets.append(float(body_pos(f"{leg}_thigh")[1]))
        thigh = -float(body_pos(f"{LEG_NAMES[0]}_shin")[2])
        shin = -float(model.site(f"{LEG_NAMES[0]}_foot").pos[2])
        foot_radius = float(model.geom(f"{LEG_NAMES[0]}_foot").size[0])
        ranges = [
            model.joint(f"{LEG_NAMES[0]}_{kind}").range for kind in ("abduction", "hip", "knee")
        ]
        return cls(
            hip_positions=tuple(hips),
            abduction_offsets=tuple(offsets),
            thigh_length=thigh,
            shin_length=shin,
            foot_radius=foot_radius,
            joint_lower=tuple(float(r[0]) for r in ranges),
            joint_upper=tuple(float(r[1]) for r in ranges),
        )

    @property
    def max_knee_reach(self) -> float:
        """Hip-to-foot distance in the leg plane at the straightest allowed knee."""
        return _knee_reach(self, self.joint_upper[2])

    @property
    def min_knee_reach(self) -> float:
        """Hip-to-foot distance in the leg plane at the most folded allowed knee."""
        return _knee_reach(self, self.joint_lower[2])

    def hip_tensor(self, dtype=None) -> Tensor:
        """Hip points as a tensor (float64 unless ``dtype``). Shape: (4, 3)."""
        return torch.tensor(self.hip_positions, dtype=dtype or torch.float64)


def _knee_reach(geometry: LegGeometry, knee: float) -> float:
    # exactmath's cos (math.cos is the platform's libm); Python's float + x sqrt are IEEE.
    l1, l2 = geometry.thigh_length, geometry.shin_length
    cos_knee = float(exactmath.cos(np.array(knee)))
    return math.sqrt(l1 * l1 + l2 * l2 + 2.0 * l1 * l2 * cos_knee)


class _Constants(NamedTuple):
    """Per-leg constants of the IK, float64 tensors or arrays. Each shape: (4,) or (3,)."""

    offset: Any
    offset_squared: Any
    min_r: Any
    lower: Any
    upper: Any
    lower_tolerance: Any
    upper_tolerance: Any
    near: float
    """``geometry.min_knee_reach`` (a property that costs two dozen torch calls)."""
    far: float
    """``geometry.max_knee_reach``."""


@functools.lru_cache(maxsize=16)
def _constants(geometry: LegGeometry, kind: str) -> _Constants:
    """The IK's constants as torch tensors or numpy arrays (cached: built once)."""
    offset = np.array(geometry.abduction_offsets, dtype=np.float64)
    lower = np.array(geometry.joint_lower, dtype=np.float64)
    upper = np.array(geometry.joint_upper, dtype=np.float64)
    values = (offset, offset * offset, abs(offset) * (1.0 + 1e-9), lower, upper,
              lower - 1e-9, upper + 1e-9)  # fmt: skip
    if kind == "torch":
        values = tuple(torch.from_numpy(v) for v in values)
    return _Constants(*values, near=geometry.min_knee_reach, far=geometry.max_knee_reach)


def leg_fk(joints: Tensor, geometry: LegGeometry) -> Tensor:
    """Foot centres in the hip frames from joint angles.

    Args:
        joints: (abduction, hip, knee) per leg. Shape: (..., 4, 3).
        geometry: the legs.

    Returns:
        Foot positions in each leg's hip frame, computed in float64 with
        ``rwalk.exactmath`` (the same bits on any CPU). Shape: (..., 4, 3).
    """
    dtype = joints.dtype
    joints = joints.to(torch.float64)
    q1, q2, q3 = joints.unbind(-1)
    l1, l2 = geometry.thigh_length, geometry.shin_length
    offset = _constants(geometry, "torch").offset
    # Foot in the leg plane (hip-joint frame before abduction).
    s2, c2 = exactmath.sin(q2), exactmath.cos(q2)
    s23, c23 = exactmath.sin(q2 + q3), exactmath.cos(q2 + q3)
    x = -l1 * s2 - l2 * s23
    z = -l1 * c2 - l2 * c23
    c, s = exactmath.cos(q1), exactmath.sin(q1)
    y_out = offset * c - z * s
    z_out = offset * s + z * c
    return torch.stack((x, y_out, z_out), dim=-1).to(dtype)


def leg_ik(feet, geometry: LegGeometry, *, flag_unreachable: bool = True):
    """Joint angles that put the feet at the given points, knee bent backwards.

    Targets outside the leg's workspace are projected onto it (nearest
    reachable leg-plane distance, then joint limits) and flagged; the result is
    never NaN.

    Args:
        feet: foot-centre targets in each leg's hip frame, a torch tensor or a
            numpy array (the same operations, so the same bits). Shape: (..., 4, 3).
        geometry: the legs.
        flag_unreachable: compute ``reachable``; False returns None for it, and
            saves its dozen elementwise calls.

    Returns:
        joints: (abduction, hip, knee) per leg, computed in float64: each row
            depends only on its own target, bit for bit, on any CPU. Shape: (..., 4, 3).
        reachable: True where the target was reached exactly. Shape: (..., 4).
    """
    xp = arrayops.of(feet)
    l1, l2 = geometry.thigh_length, geometry.shin_length
    dtype = feet.dtype
    feet = xp.as_f64(feet)
    const = _constants(geometry, "torch" if xp is arrayops.TorchOps else "numpy")
    offset = const.offset
    px, py, pz = feet[..., 0], feet[..., 1], feet[..., 2]
    # Elementwise +, -, x, /, sqrt and exactmath only (one op per call, no reductions):
    # each row's result is the same bits whatever the batch size and CPU.

    # Abduction: the foot lies in the plane swept by the thigh, |offset| from the axis.
    r_yz = xp.sqrt(py * py + pz * pz)
    ok = r_yz >= const.min_r if flag_unreachable else None
    r_yz = xp.maximum(r_yz, const.min_r)
    z_plane = -xp.sqrt(xp.clamp(r_yz * r_yz - const.offset_squared, 0.0))
    # q1 = angle(py, pz) - angle(offset, z_plane), in [-π, π]: the angle of the
    # product of (py + i pz) and the conjugate of (offset + i z_plane).
    q1_y = pz * offset - py * z_plane
    q1_x = py * offset + pz * z_plane

    # Hip and knee: planar two-link problem, distance clamped to what the knee allows.
    dist = xp.sqrt(px * px + z_plane * z_plane)
    near, far = const.near, const.far
    if flag_unreachable:
        ok = ok & (dist >= near * (1.0 - 1e-9)) & (dist <= far * (1.0 + 1e-9))
    dist = xp.clamp(dist, near, far)
    cos_knee = (dist * dist - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    cos_knee = xp.clamp(cos_knee, -1.0, 1.0)
    # q3 = -acos(cos_knee); its sine is -sqrt(1 - cos²), taken as acos takes it.
    sin_knee = xp.sqrt((1.0 - cos_knee) * (1.0 + cos_knee))
    # q2 = (angle of the hip->foot line from straight down, positive backwards)
    #      - (angle of the foot seen from the hip in the thigh's frame).
    # All four angles in one atan2 call (per-call overhead dominates small batches).
    # Stacked along a new first axis: contiguous in numpy, and angles[k] are cheap views.
    angles = exactmath.atan2(
        xp.stack((q1_y, sin_knee, -px, -l2 * sin_knee), axis=0),
        xp.stack((q1_x, cos_knee, -z_plane, l1 + l2 * cos_knee), axis=0),
    )
    q1, q3 = angles[0], -angles[1]
    q2 = angles[2] - angles[3]

    joints = xp.stack((q1, q2, q3))
    if flag_unreachable:
        # Rounding can put a target exactly on a limit a hair outside it: tolerate 1e-9 rad.
        within = (joints >= const.lower_tolerance) & (joints <= const.upper_tolerance)
        ok = ok & xp.all_last(within)
    joints = xp.clamp(joints, const.lower, const.upper)
    if xp is arrayops.TorchOps:
        joints = joints.to(dtype)
    return joints, ok
