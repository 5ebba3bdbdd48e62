import math

import pytest
import torch

from rwalk.rewards import (
    RewardWeights,
    StepState,
    contact_pattern,
    evaluate,
    fallen,
    lateral,
    quat_to_rpy,
    spec_terms,
    stability,
    velocity_tracking,
)

F64 = torch.float64


def test_velocity_tracking_hand_computed():
    v = torch.tensor([0.1, 0.08 / 0.6, 0.0, 1.2], dtype=F64)
    expected = torch.tensor([1 - (0.08 / 0.6 - 0.1), 1.0, 1 - 0.08 / 0.6, 1 - (1.2 - 0.08 / 0.6)])
    torch.testing.assert_close(velocity_tracking(v, 0.08 / 0.6), expected.to(F64))


def test_contact_pattern_all_four_cases_per_leg():
    swing = torch.tensor([[True, True, False, False]])
    contact = torch.tensor([[False, True, True, False]])
    # swing+air +0.05, swing+touch -0.2, stance+touch +0.05, stance+air -0.2
    score = contact_pattern(swing, contact, 0.05, -0.2)
    assert score.dtype == F64
    assert score.item() == pytest.approx(0.05 - 0.2 + 0.05 - 0.2, abs=1e-15)
    perfect = contact_pattern(swing, ~swing, 0.05, -0.2)
    assert perfect.item() == pytest.approx(0.2, abs=1e-15)


def test_stability_and_lateral_hand_computed():
    rpy = torch.tensor([[0.1, -0.2, 0.3]], dtype=F64)
    assert stability(rpy).item() == pytest.approx(0.14)
    y, y0 = torch.tensor([0.3, -0.1], dtype=F64), torch.tensor([0.1, 0.2], dtype=F64)
    torch.testing.assert_close(lateral(y, y0), torch.tensor([0.2, 0.3], dtype=F64))


def _axis_quat(axis: int, angle: float) -> torch.Tensor:
    q = torch.zeros(4, dtype=F64)
    q[0] = math.cos(angle / 2)
    q[1 + axis] = math.sin(angle / 2)
    return q


@pytest.mark.parametrize(("axis", "angle"), [(0, 0.3), (1, -0.4), (2, 2.5), (0, -1.2)])
def test_quat_to_rpy_single_axis(axis, angle):
    rpy = quat_to_rpy(_axis_quat(axis, angle))
    expected = torch.zeros(3, dtype=F64)
    expected[axis] = angle
    torch.testing.assert_close(rpy, expected)


def test_fallen_at_sixty_degrees_of_roll_or_pitch():
    rpy = torch.tensor(
        [[1.05, 0, 0], [1.04, 0, 0], [0, -1.05, 0], [0, 0, 3.0], [-1.1, 0.2, 0]], dtype=F64
    )
    assert fallen(rpy).tolist() == [True, False, True, False, True]


def test_weighted_terms_are_the_spec_formulas():
    weights = RewardWeights()
    state = StepState(
        forward_velocity=torch.tensor([0.1], dtype=F64),
        v_target=0.08 / 0.6,
        swing=torch.tensor([[True, False, False, True]]),
        contact=torch.tensor([[False, True, True, False]]),
        rpy=torch.tensor([[0.1, -0.2, 0.3]], dtype=F64),
        y=torch.tensor([0.3], dtype=F64),
        y0=torch.tensor([0.1], dtype=F64),
        weights=weights,
    )
    terms = evaluate(spec_terms(weights), state)
    assert list(terms) == ["velocity_tracking", "contact_pattern", "stability", "lateral"]
    assert terms["velocity_tracking"].item() == pytest.approx(300 * (1 - (0.08 / 0.6 - 0.1)))
    assert terms["contact_pattern"].item() == pytest.approx(4 * 0.05)
    assert terms["stability"].item() == pytest.approx(-3 * 0.14)
    assert terms["lateral"].item() == pytest.approx(-0.2)
