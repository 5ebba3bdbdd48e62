"""The speed error's parts (rwalk.analysis.speed_parts): hand-computed splits, and the
trace of paired episodes they are read from."""

import math

import torch

from rwalk import EnvConfig
from rwalk.analysis import SpeedTrace, speed_parts, speed_trace
from rwalk.envs.torchrl_env import BatchedEnv

V = 0.125  # a target that is exact in binary


def test_a_bias_and_a_profile_by_hand():
    # two envs, phase alternating between two bins; env 0 is 0.125 m/s fast, both swing
    # +-0.03125 with the phase: bias 0.0625 over envs, profile 0.03125, no rest
    phase = torch.tensor([0.25, 0.75] * 4, dtype=torch.float64)[:, None].expand(8, 2)
    swing = torch.tensor([0.03125, -0.03125] * 4, dtype=torch.float64)[:, None]
    velocity = V + swing + torch.tensor([[0.125, 0.0]], dtype=torch.float64)
    # env 0's first action value alternates 0, 0.5 (a change of 0.25 every step), env 1's
    # stays: 0.125 a step on average
    action = torch.zeros(8, 2, 12, dtype=torch.float64)
    action[1::2, 0, 0] = 0.5
    walked = torch.ones(8, 2, dtype=torch.bool)
    parts = speed_parts(SpeedTrace(velocity, phase, walked, action), V, 0.02, bins=2)
    assert parts.error == (0.15625 + 0.09375 + 2 * 0.03125) / 4
    assert (parts.bias, parts.profile, parts.rest) == (0.0625, 0.03125, 0.0)
    assert math.isnan(parts.rest_autocorrelation) and math.isnan(parts.rest_high_frequency)
    assert parts.action_change == 0.125


def test_a_rest_that_is_no_profile_by_hand():
    # +e, +e, -e, -e, ... over a phase of two bins: each bin meets +e and -e, so no
    # profile; a period of 4 steps of 20 ms is 12.5 Hz (all its power above 6 Hz);
    # one step later it keeps its sign 4 times in 7 and flips 3: (4 - 3) / 8
    e = 0.0625
    rest = torch.tensor([e, e, -e, -e] * 2, dtype=torch.float64)[:, None]
    phase = torch.tensor([0.25, 0.75] * 4, dtype=torch.float64)[:, None]
    walked = torch.ones(8, 1, dtype=torch.bool)
    still = torch.zeros(8, 1, 12, dtype=torch.float64)
    parts = speed_parts(SpeedTrace(V + rest, phase, walked, still), V, 0.02, bins=2)
    assert (parts.error, parts.bias, parts.profile, parts.rest) == (e, 0.0, 0.0, e)
    assert parts.rest_autocorrelation == 1 / 8
    assert abs(parts.rest_high_frequency - 1.0) < 1e-12
    # steps not walked do not count: the same steps padded with a wild one
    wild = torch.cat([V + rest, torch.tensor([[9.0]], dtype=torch.float64)])
    padded = torch.cat([walked, torch.zeros(1, 1, dtype=torch.bool)])
    moved = torch.cat([still, torch.ones(1, 1, 12, dtype=torch.float64)])  # not counted
    again = speed_parts(SpeedTrace(wild, torch.cat([phase, phase[:1]]), padded, moved), V, 0.02,
                        bins=2)  # fmt: skip
    assert again.action_change == 0.0
    assert (again.error, again.bias, again.rest) == (e, 0.0, e)


def test_the_trace_counts_each_envs_first_episode_after_its_start():
    config = EnvConfig(model_path="model/world_flat.xml", settle_steps=5, max_episode_steps=12)
    env = BatchedEnv(3, config, seed=0)
    trace = speed_trace(env, seed=1000, skip=4)
    velocity, phase, walked, action = trace
    assert velocity.shape == phase.shape == walked.shape == (12, 3)
    assert action.shape == (12, 3, 12) and not action.any()  # the base gait
    assert not walked[:4].any() and walked[4:].all()  # nobody falls on flat ground
    assert bool(((phase >= 0) & (phase < 1)).all())
    assert torch.equal(speed_trace(env, seed=1000, skip=4).velocity, velocity)  # paired
    # a low-pass sends half of each action and half of the last one sent: a constant 0.5
    # reaches 0.5 * (1 - 2^-t) after t steps
    half = torch.full((3, 12), 0.5, dtype=torch.float64)
    sent = speed_trace(env, lambda: half, seed=1000, skip=4, low_pass=0.5).action
    assert bool((sent[-1] == 0.5 - 2.0**-13).all()) and bool((sent[0] == 0.25).all())
    parts = speed_parts(trace, config.expected_velocity, 0.02)
    by_hand = (velocity - config.expected_velocity)[walked].abs().mean()
    assert abs(parts.error - float(by_hand)) < 1e-15 and parts.action_change == 0.0
