"""The trot's foot paths as functions of phase and gait parameters, for torch tensors
and numpy arrays alike: the same elementwise operations (``rwalk.arrayops``), so the
same bits. ``rwalk.gait``'s controller evaluates them in torch for the batched core,
``rwalk.deploy`` in numpy on a robot, without torch.
"""

from __future__ import annotations

import itertools

from rwalk import arrayops

#: Steepest rise of a speed schedule's step height (``schedule_step_rise``): 1 m per m/s,
#: 10 mm per 0.01 m/s, far beyond any useful one. Metres per m/s.
MAX_STEP_RISE = 1.0

#: Phase offset of each leg (FL, FR, RL, RR): diagonal pairs in step.
TROT_OFFSETS: tuple[float, ...] = (0.0, 0.5, 0.5, 0.0)


def advance_phase(phase, cycle_time, dt: float, substeps: int):
    """Continuous gait phases over K substeps of ``dt`` at per-env cycle times.

    The phase advances by dt / cycle_time per substep, so a new cycle time changes
    how fast the phase moves, never the phase itself. Elementwise IEEE arithmetic
    only: each env's phases are the same bits in any batch.

    Args:
        phase: phase in [0, 1) at the start of the period. Shape: (N,).
        cycle_time: seconds per cycle. Shape: (N,).

    Returns:
        Phases at the start of substeps 0..K (column K starts the next period),
        each in [0, 1). Shape: (N, K + 1).
    """
    xp = arrayops.of(phase, cycle_time)
    ticks = xp.as_f64([float(tick) for tick in range(substeps + 1)])
    # torch computes float / tensor as tensor.reciprocal() * float (two roundings); numpy
    # divides once. Written as that product, both take the same two roundings.
    rate = (1.0 / cycle_time) * dt
    shifted = phase[..., None] + ticks * rate[..., None]
    return shifted - xp.floor(shifted)


def bernstein_curve(points, t):
    """Evaluate a Bézier curve by de Casteljau's construction.

    Only elementwise multiplies and adds (no pow, no matmul), so every point is
    the same bits on any CPU and for any shape of ``t``.

    Args:
        points: control points, float64. Shape: (n + 1, D).
        t: curve parameters in [0, 1], float64. Shape: (...).

    Returns:
        Points on the curve. Shape: (..., D).
    """
    xp = arrayops.of(points, t)
    tt = t[..., None]
    ut = 1.0 - tt
    level = list(xp.unstack_first(points))
    while len(level) > 1:
        level = [ut * a + tt * b for a, b in itertools.pairwise(level)]
    return xp.expand(level[0], (*t.shape, points.shape[1]))


def leg_phases(phase, offsets):
    """Each leg's phase in [0, 1) from the gait's. (...,) -> (..., 4). Stance is [0, duty)."""
    xp = arrayops.of(phase, offsets)
    shifted = phase[..., None] + offsets
    return shifted - xp.floor(shifted)  # exact, unlike a float remainder kernel


def trot_targets(phase, step_height, step_length, stance_z, duty_factor: float, offsets,
                 swing_points, neutral):  # fmt: skip
    """Base-gait foot targets in the hip frames (``BezierGaitController.foot_targets``).

    Args:
        phase: gait phase in [0, 1). Shape: (...).
        step_height, step_length, stance_z: floats, or arrays broadcastable to the legs'
            phases (..., 4).
        duty_factor: stance share of the cycle.
        offsets: the legs' phase offsets. Shape: (4,).
        swing_points: the swing's control points (``swing_control_points``). Shape: (7, 2).
        neutral: each foot's stance point (x 0, y, the default stance z). Shape: (4, 3).

    Returns:
        targets: foot-centre targets. Shape: (..., 4, 3).
        swing: True for legs in swing. Shape: (..., 4).
    """
    xp = arrayops.of(phase, neutral)
    leg_phase = leg_phases(phase, offsets)
    swing = leg_phase >= duty_factor
    half = 0.5 * (duty_factor * step_length)
    stance_s = leg_phase / duty_factor
    swing_t = xp.clamp((leg_phase - duty_factor) / (1.0 - duty_factor), 0.0, 1.0)
    curve = bernstein_curve(swing_points, swing_t)
    x = xp.where(swing, half * curve[..., 0], half * (1.0 - 2.0 * stance_s))
    z = stance_z + xp.where(swing, step_height * curve[..., 1], 0.0)
    targets = xp.expand(neutral, (*x.shape, 3))
    targets[..., 0] = x
    targets[..., 2] = z
    return targets, swing


def speed_schedule(
    speed, stride: float, low, high, start, rise: float = 0.0, reference: float = 0.0
):
    """The gait a target velocity asks for: the cycle clamp(stride / speed) within its
    range, the stride speed x cycle within its range (so stride / cycle = speed where
    the ranges allow), the body height of the starting gait, and its step height, or with
    a ``rise`` the step height start + (speed - reference) x rise within its range.
    Elementwise IEEE arithmetic on torch tensors or numpy arrays alike
    (``rwalk.arrayops``), so the runtime computes the env's bits.

    Args:
        speed: target velocities, > 0. Shape: (N,).
        stride: the config's ``schedule_stride``, metres.
        low, high, start: the parameters' ranges and starting gait. Shape: (4,).
        rise: the config's ``schedule_step_rise``, metres of step per m/s (0: the
            starting gait's step at every speed).
        reference: the speed at which the step is the starting gait's, m/s.

    Returns:
        step_height, step_length, cycle_time, body_height. Shape: (N, 4).
    """
    xp = arrayops.of(speed, low)
    # (1 / speed) * stride: torch computes float / tensor so; written out, numpy does too.
    cycle = xp.clamp((1.0 / speed) * stride, low[2], high[2])
    length = xp.clamp(speed * cycle, low[1], high[1])
    gait = xp.expand(start, (speed.shape[0], 4))
    gait[:, 1] = length
    gait[:, 2] = cycle
    if rise != 0.0:
        gait[:, 0] = xp.clamp(start[0] + (speed - reference) * rise, low[0], high[0])
    return gait
