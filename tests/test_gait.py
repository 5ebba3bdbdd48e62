import math

import pytest
import torch

from rwalk.gait import (
    BezierGaitController,
    GaitParameters,
    GaitShape,
    bernstein_curve,
    swing_control_points,
)
from rwalk.kinematics import leg_fk

F64 = torch.float64


def test_defaults_give_the_spec_expected_velocity():
    params = GaitParameters()
    assert params.step_length == 0.08 and params.cycle_time == 0.6
    assert params.expected_velocity == pytest.approx(0.08 / 0.6)
    assert params.stance_sweep == pytest.approx(params.duty_factor * 0.08)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("step_height", 0.0),
        ("step_height", -0.01),
        ("step_length", -0.05),
        ("cycle_time", 0.0),
        ("body_height", -0.06),
        ("duty_factor", 0.0),
        ("duty_factor", 1.0),
        ("stance_depth", -0.001),
        ("cycle_time", math.nan),
        ("step_length", math.inf),
    ],
)
def test_impossible_parameter_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        GaitParameters(**{field: value})


def test_swing_higher_than_the_hip_is_rejected():
    with pytest.raises(ValueError, match="step_height"):
        GaitParameters(step_height=0.08, body_height=0.07)


def test_unreachable_stance_line_is_rejected():
    with pytest.raises(ValueError, match="body_height"):
        BezierGaitController(GaitParameters(body_height=0.2, step_height=0.02))


def test_spec_custom_gait_is_accepted():
    # The spec's example: the swing apex is out of reach and gets projected, not rejected.
    params = GaitParameters(step_height=0.05, step_length=0.10, cycle_time=0.8, body_height=0.06)
    controller = BezierGaitController(params)
    ctrl, reachable = controller.joint_targets(torch.zeros(2, dtype=torch.long), 400)
    assert torch.isfinite(ctrl).all()
    assert reachable.float().mean() > 0.5


def test_bezier_hand_computed_points():
    points = swing_control_points(0.5)
    # overshoot = 2 (1 - 0.5) / 0.5 / 6 = 1/3; z-controls 64/50 make the apex 1.
    expected = torch.tensor(
        [[-1, 0], [-4 / 3, 0], [-4 / 3, 1.28], [0, 1.28], [4 / 3, 1.28], [4 / 3, 0], [1, 0]],
        dtype=F64,
    )
    torch.testing.assert_close(points, expected)
    t = torch.tensor([0.0, 0.25, 0.5, 1.0], dtype=F64)
    curve = bernstein_curve(points, t)
    # At t = 1/4 the weights are C(6,i) 3^(6-i) / 4^6 = (729, 1458, 1215, 540, 135, 18, 1) / 4096.
    torch.testing.assert_close(
        curve,
        torch.tensor(
            [[-1.0, 0.0], [-4088 / 4096, 1.28 * 1890 / 4096], [0.0, 1.0], [1.0, 0.0]], dtype=F64
        ),
    )


def _foot_track(controller, phases):
    targets, swing = controller.foot_targets(phases)
    return targets, swing


def test_trot_pairs_diagonals_half_a_cycle_apart():
    controller = BezierGaitController()
    ticks = torch.arange(controller.period)
    swing = controller.is_swing(ticks)
    fl, fr, rl, rr = swing.unbind(-1)
    assert torch.equal(fl, rr) and torch.equal(fr, rl)
    assert not (fl & fr).any()  # diagonal pairs never swing together
    shifted = controller.is_swing(ticks + controller.period // 2)
    assert torch.equal(shifted[:, 0], fr)
    assert swing.float().mean() == pytest.approx(1 - controller.params.duty_factor, abs=0.01)


def test_stance_is_a_straight_sweep_at_the_stride_speed():
    params = GaitParameters()
    controller = BezierGaitController(params)
    phases = torch.linspace(0, params.duty_factor, 200, dtype=F64)[:-1]
    targets, swing = controller.foot_targets(phases)
    fl = targets[:, 0]
    assert not swing[:, 0].any()
    assert fl[0, 0] == pytest.approx(params.stance_sweep / 2)
    assert torch.allclose(fl[:, 2], torch.full_like(fl[:, 2], controller.stance_z))
    # Foot speed relative to the body is the body's no-slip speed, step_length / cycle_time.
    dx = torch.diff(fl[:, 0]) / (torch.diff(phases) * params.cycle_time)
    torch.testing.assert_close(dx, torch.full_like(dx, -params.expected_velocity))


def test_swing_meets_stance_smoothly_and_reaches_step_height():
    params = GaitParameters()
    controller = BezierGaitController(params)
    phases = torch.linspace(0, 1, 6001, dtype=F64)[:-1]
    targets, _ = controller.foot_targets(phases)
    fl = targets[:, 0]
    step = torch.diff(fl, dim=0).norm(dim=-1)
    assert step.max() < 1e-4  # continuous: no jumps between samples 1/6000 cycle apart
    velocity = torch.diff(fl[:, 0]) * 6000 * (1 / params.cycle_time)
    lift_off = int(params.duty_factor * 6000)
    # Horizontal velocity is continuous across lift-off (zero ground speed).
    assert velocity[lift_off - 2].item() == pytest.approx(velocity[lift_off + 1].item(), rel=0.02)
    apex = fl[:, 2].max() - controller.stance_z
    assert apex.item() == pytest.approx(params.step_height, rel=1e-6)
    mid_swing = int((params.duty_factor + (1 - params.duty_factor) / 2) * 6000)
    assert fl[mid_swing, 2] - controller.stance_z == pytest.approx(params.step_height, rel=1e-4)


def test_joint_targets_shapes_and_residuals_move_the_feet():
    controller = BezierGaitController()
    tick = torch.tensor([0, 90, 210])
    base, ok = controller.joint_targets(tick, 10)
    assert base.shape == (3, 10, 12) and ok.shape == (3, 10, 4) and ok.all()
    residuals = torch.zeros(3, 4, 3, dtype=F64)
    residuals[:, 1] = torch.tensor([0.01, -0.005, 0.008], dtype=F64)
    moved, ok = controller.joint_targets(tick, 10, residuals)
    assert ok.all()
    g = controller.geometry
    shift = leg_fk(moved.view(3, 10, 4, 3), g) - leg_fk(base.view(3, 10, 4, 3), g)
    torch.testing.assert_close(shift, residuals.unsqueeze(1).expand(3, 10, 4, 3))


def test_tables_hold_one_cycle_at_every_substep():
    controller = BezierGaitController(dt=0.002)
    assert controller.period == 300  # 0.6 s / 2 ms
    ticks = torch.tensor([0, 1, 299, 300, 451])
    expected_phase = torch.tensor([0, 1, 299, 0, 151], dtype=F64) / 300
    torch.testing.assert_close(controller.phase(ticks), expected_phase)
    targets, swing = controller.foot_targets(expected_phase)
    torch.testing.assert_close(controller.target_table[ticks % 300], targets)
    assert torch.equal(controller.is_swing(ticks), swing)
    ctrl, _ = controller.joint_targets(torch.tensor([298]), 4)
    step_by_step = torch.cat(
        [controller.joint_targets(torch.tensor([t]), 1)[0] for t in (298, 299, 0, 1)], 1
    )
    torch.testing.assert_close(ctrl, step_by_step)


def test_cycle_must_be_a_whole_number_of_physics_steps():
    with pytest.raises(ValueError, match="cycle_time"):
        BezierGaitController(GaitParameters(cycle_time=0.6011), dt=0.002)


def test_the_gait_math_gives_the_same_bits_on_numpy_as_on_torch():
    """rwalk.deploy runs the adaptive gait in numpy: the same bits as the env's torch."""
    import numpy as np

    from rwalk.gaitmath import advance_phase, trot_targets

    rng = np.random.default_rng(0)
    phase = rng.uniform(0.0, 1.0, 64)
    cycle = rng.uniform(0.3, 0.9, 64)
    phases = advance_phase(phase, cycle, 0.004, 5)
    want = advance_phase(torch.from_numpy(phase), torch.from_numpy(cycle), 0.004, 5)
    assert np.array_equal(phases, want.numpy())  # bits, not a tolerance
    assert ((phases >= 0.0) & (phases < 1.0)).all()
    controller = BezierGaitController(dt=0.004)
    height, length, body = (rng.uniform(lo, hi, (64, 1, 1))
                            for lo, hi in ((0.01, 0.04), (0.0, 0.16), (0.05, 0.09)))  # fmt: skip
    stance_z = -body + controller.geometry.foot_radius - controller.params.stance_depth
    targets, swing = trot_targets(
        phases, height, length, stance_z, controller.params.duty_factor,
        controller.leg_offsets.numpy(), controller.swing_points.numpy(), controller.neutral.numpy(),
    )  # fmt: skip
    shape = GaitShape(*(torch.from_numpy(v[:, 0, 0]).unsqueeze(-1) for v in (height, length, body)))
    want_targets, want_swing = controller.foot_targets(torch.from_numpy(phases), shape)
    assert np.array_equal(targets, want_targets.numpy()) and np.array_equal(swing, want_swing)
