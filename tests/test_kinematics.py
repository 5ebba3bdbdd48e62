import math

import mujoco
import numpy as np
import pytest
import torch
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from rwalk.constants import OBS_FOOT_POS
from rwalk.kinematics import LegGeometry, leg_fk, leg_ik

F64 = torch.float64
G = LegGeometry()


def test_geometry_read_from_the_model_matches_the_defaults(flat_model):
    assert LegGeometry.from_model(flat_model) == G


def test_fk_hand_computed():
    d, l1, l2 = 0.012, 0.05, 0.06
    q = torch.tensor(
        [
            [0.0, 0.0, 0.0],  # FL straight down
            [0.0, 0.0, -math.pi / 2],  # FR shin horizontal, pointing forward
            [0.0, math.pi / 2, -math.pi / 2],  # RL thigh backward, shin down
            [math.pi / 2, 0.0, 0.0],  # RR leg swung sideways to the left
        ],
        dtype=F64,
    )
    feet = leg_fk(q, G)
    # Left legs have the hip joint d to the left of the abduction axis, right legs d to the right.
    expected = torch.tensor(
        [
            [0.0, d, -(l1 + l2)],
            [l2, -d, -l1],
            [-l1, d, -l2],
            [0.0, l1 + l2, -d],
        ],
        dtype=F64,
    )
    torch.testing.assert_close(feet, expected, atol=1e-12, rtol=0)


def test_fk_matches_mujoco(flat_model):
    model = flat_model
    data = mujoco.MjData(model)
    gen = torch.Generator().manual_seed(0)
    lower, upper = torch.tensor(G.joint_lower, dtype=F64), torch.tensor(G.joint_upper, dtype=F64)
    hips = G.hip_tensor()
    for _ in range(20):
        q = lower + (upper - lower) * torch.rand(4, 3, generator=gen, dtype=F64)
        data.qpos[7:] = q.flatten().numpy()
        mujoco.mj_forward(model, data)
        mujoco_feet = data.sensordata[OBS_FOOT_POS].reshape(4, 3)
        np.testing.assert_allclose((leg_fk(q, G) + hips).numpy(), mujoco_feet, atol=1e-12)


angles = st.tuples(
    st.floats(G.joint_lower[0], G.joint_upper[0]),
    st.floats(G.joint_lower[1], G.joint_upper[1]),
    st.floats(G.joint_lower[2], G.joint_upper[2]),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(angles, min_size=4, max_size=4))
def test_ik_inverts_fk_over_the_workspace(qs):
    q = torch.tensor(qs, dtype=F64)
    planar_z = -G.thigh_length * torch.cos(q[:, 1]) - G.shin_length * torch.cos(q[:, 1] + q[:, 2])
    assume(bool((planar_z < -1e-3).all()))  # the workspace below the hip (knee-back branch)
    feet = leg_fk(q, G)
    solved, ok = leg_ik(feet, G)
    assert ok.all()
    assert (leg_fk(solved, G) - feet).abs().max() < 1e-6


@pytest.mark.parametrize(
    "target",
    [[0.0, 0.0, 0.0], [0.3, 0.2, -0.4], [0.0, 0.012, -0.5], [0.0, 0.0, 0.2], [0.0, 0.001, -0.01]],
)
def test_unreachable_targets_are_projected_and_flagged(target):
    feet = torch.tensor([target] * 4, dtype=F64)
    joints, ok = leg_ik(feet, G)
    assert torch.isfinite(joints).all()
    assert not ok.any()
    lower, upper = torch.tensor(G.joint_lower, dtype=F64), torch.tensor(G.joint_upper, dtype=F64)
    assert ((joints >= lower) & (joints <= upper)).all()


def test_too_far_is_projected_onto_the_reach_boundary():
    feet = torch.tensor([[0.0, 0.012, -0.5]] * 4, dtype=F64)
    joints, _ = leg_ik(feet, G)
    reached = leg_fk(joints, G)
    offset = torch.tensor(G.abduction_offsets, dtype=F64)
    # Hip-to-foot distance within each leg's plane.
    planar = torch.sqrt(reached[:, 0] ** 2 + reached[:, 1] ** 2 + reached[:, 2] ** 2 - offset**2)
    torch.testing.assert_close(planar, torch.full_like(planar, G.max_knee_reach))
    assert torch.allclose(reached[:, 0], torch.zeros(4, dtype=F64), atol=1e-12)


def test_ik_is_batched():
    feet = torch.tensor([0.01, 0.012, -0.06], dtype=F64).expand(5, 7, 4, 3)
    joints, ok = leg_ik(feet, G)
    assert joints.shape == (5, 7, 4, 3) and ok.shape == (5, 7, 4)
