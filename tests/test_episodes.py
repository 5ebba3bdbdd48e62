"""The one auto-reset and episode-statistics path (rwalk.episodes)."""

import dataclasses

import numpy as np
import torch

from rwalk import Core, EnvConfig, ResidualWalkEnv, ResidualWalkVecEnv, episodes

FAST = EnvConfig(model_path="model/world_flat.xml", settle_steps=5, max_episode_steps=3)


def test_ended_episodes_report_their_statistics_then_reset():
    core = Core(FAST, 2, seed=0)
    core.reset()
    core.episode_step[1] = 1  # env 1's episode ends a step earlier
    zeros = torch.zeros(2, 12)
    _, end = episodes.step(core, zeros)
    assert end is None
    result, end = episodes.step(core, zeros)
    assert end.ids.tolist() == [1] and bool(result.truncated[1])
    stats = end.stats
    terms = [stats[f"sum/{name}"] for name in ("velocity_tracking", "contact_pattern",
                                               "stability", "lateral")]  # fmt: skip
    assert stats["return"][0] == sum(terms, torch.zeros(1))[0]
    assert stats["length"].tolist() == [2.0] and stats["terminated"].tolist() == [False]
    assert core.episode_step[1] == 0 and core.walked_steps[1] == 0  # reset
    assert core.episode_step[0] == 2


def test_without_auto_reset_the_env_runs_on():
    core = Core(FAST, 1, seed=0)
    core.reset()
    for _ in range(3):
        _, end = episodes.step(core, torch.zeros(1, 12), auto_reset=False)
    assert end is not None and core.walked_steps[0] == 3


def test_velocity_error_is_the_mean_per_step_gap_to_the_target():
    core = Core(FAST, 2, seed=0)
    core.reset()
    gaps = []
    for _ in range(2):
        core.step(torch.zeros(2, 12))
        gaps.append((core.obs[:, 7] - FAST.expected_velocity).abs())
    log = core.episode_log(torch.tensor([0, 1]))
    torch.testing.assert_close(log["velocity_error"], (gaps[0] + gaps[1]) / 2)


def test_the_single_env_tallies_the_same_bits():
    env = ResidualWalkEnv(config=FAST, seed=4)
    env.reset()
    batch = Core(FAST, 1, seed=4)
    batch.reset()
    action = np.full(12, 0.3, dtype=np.float32)
    for _ in range(2):
        env.step(action)
        batch.step(torch.from_numpy(action).reshape(1, 12))
    assert torch.equal(env.core.episode_speed_error, batch.episode_speed_error)


def test_any_task_can_be_asked_for_a_speed():
    config = dataclasses.replace(FAST, command_range=(0.2, 0.2))
    vec = ResidualWalkVecEnv(2, config, seed=0)
    td = vec.reset()
    assert torch.equal(td["command"], torch.full((2, 1), 0.2))
    env = ResidualWalkEnv(
        config=config, seed=0
    )  # the batched pipeline: the float one has no command
    _, info = env.reset()
    assert env.single_step is None and info["target_velocity"] == 0.2
    _, _, _, _, info = env.step(np.zeros(12, dtype=np.float32))
    v = env.core.obs[0, 7].item()
    assert info["reward_components"]["velocity_tracking"] == 300.0 * (1.0 - abs(v - 0.2))


def test_the_speed_error_splits_into_bias_and_ripple_by_hand():
    # A 3-step gait cycle; the ring starts at the settled velocity 0. Cycle means after
    # each step: 1/3, 1, 2, 3; |v - mean|: 2/3, 1, 1, 1.
    ep = episodes.Episodes(1, [], control_dt=0.02, max_steps=10, cycle_steps=3)
    zero = torch.zeros(1, dtype=torch.float64)
    ep.start(torch.tensor([0]), zero, zero, zero)
    for v in (1.0, 2.0, 3.0, 4.0):
        ep.count()
        ep.record({}, torch.tensor([v], dtype=torch.float64), 2.0, torch.tensor([False]))
    log = ep.log(torch.tensor([0]), 2.0)
    assert log["forward_velocity"].item() == 2.5 and log["velocity_bias"].item() == 0.5
    assert log["velocity_error"].item() == (1 + 0 + 1 + 2) / 4
    assert abs(log["velocity_ripple"].item() - (2 / 3 + 3) / 4) < 1e-15
