import dataclasses

import pytest
import torch
from rsl_rl.runners import OnPolicyRunner

from rwalk import EnvConfig, ResidualWalkVecEnv
from rwalk.wrappers import RslRlVecEnv

QUICK = dataclasses.replace(EnvConfig(), settle_steps=5, max_episode_steps=12)


def _train_cfg():
    mlp = {"class_name": "MLPModel", "hidden_dims": [32, 32], "activation": "elu"}
    return {
        "num_steps_per_env": 8,
        "save_interval": 1,
        "obs_groups": {"actor": ["policy"], "critic": ["critic"]},
        "algorithm": {"class_name": "PPO", "num_mini_batches": 2, "num_learning_epochs": 2},
        "actor": {
            **mlp,
            "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": 0.5},
        },
        "critic": mlp,
    }


def test_observation_groups_and_step_contract():
    env = RslRlVecEnv(ResidualWalkVecEnv(3, QUICK, seed=0), critic_obs=("observation",))
    obs = env.get_observations()
    assert obs["policy"].shape == (3, 68) and obs["critic"].shape == (3, 65)
    assert obs["policy"].dtype == torch.float32
    obs, reward, done, extras = env.step(torch.zeros(3, 12))
    assert reward.shape == (3,) and done.shape == (3,) and extras["time_outs"].shape == (3,)
    assert env.num_actions == 12 and env.max_episode_length == 12


def test_auto_reset_and_episode_log():
    env = RslRlVecEnv(ResidualWalkVecEnv(2, QUICK, seed=0), reward_scale=0.5)
    for step in range(12):
        obs, reward, done, extras = env.step(torch.zeros(2, 12))
        if step < 11:
            assert not done.any() and "log" not in extras
    assert done.all() and extras["time_outs"].all()
    assert env.episode_length_buf.tolist() == [0, 0]  # reset inside step
    log = extras["log"]
    assert {
        "Episode_Reward/velocity_tracking",
        "Episode_Reward/contact_pattern",
        "Episode_Reward/stability",
        "Episode_Reward/lateral",
        "Episode/length",
        "Episode/fall_rate",
        "Episode/forward_velocity",
        "Episode/velocity_error",
        "Perf/settle_share",
    } <= set(log)
    assert log["Episode/length"].item() == 12 and log["Episode/fall_rate"].item() == 0


def test_reward_scale_applies_to_what_rsl_rl_sees():
    plain = RslRlVecEnv(ResidualWalkVecEnv(2, QUICK, seed=0))
    scaled = RslRlVecEnv(ResidualWalkVecEnv(2, QUICK, seed=0), reward_scale=0.01)
    _, r1, _, _ = plain.step(torch.zeros(2, 12))
    _, r2, _, _ = scaled.step(torch.zeros(2, 12))
    torch.testing.assert_close(r2, r1 * 0.01)
    with pytest.raises(ValueError, match="observation piece"):
        RslRlVecEnv(ResidualWalkVecEnv(2, QUICK, seed=0), policy_obs=("height_scan",))


def test_random_episode_lengths_reach_the_core():
    env = RslRlVecEnv(ResidualWalkVecEnv(3, QUICK, seed=0))
    env.episode_length_buf = torch.tensor([3, 7, 11])
    _, _, done, extras = env.step(torch.zeros(3, 12))
    assert done.tolist() == [0, 0, 1] and extras["time_outs"].tolist() == [False, False, True]


def test_on_policy_runner_trains_two_iterations(tmp_path):
    env = RslRlVecEnv(ResidualWalkVecEnv(8, QUICK, seed=0), reward_scale=0.01)
    runner = OnPolicyRunner(env, _train_cfg(), log_dir=str(tmp_path), device="cpu")
    before = [p.clone() for p in runner.alg.get_policy().parameters()]
    runner.learn(num_learning_iterations=2)
    after = list(runner.alg.get_policy().parameters())
    assert any(not torch.equal(a, b) for a, b in zip(after, before, strict=True))
    assert (tmp_path / "model_1.pt").is_file()


def test_episode_statistics_count_the_steps_actually_walked():
    # rsl-rl's init_at_random_ep_len moves the truncation counter: an env set to
    # max - 10 walks 10 steps, and its episode must be logged as 10 steps long.
    env = RslRlVecEnv(ResidualWalkVecEnv(2, QUICK, seed=0))
    env.episode_length_buf = torch.tensor([QUICK.max_episode_steps - 10, 0])
    rewards = []
    for _ in range(10):
        _, reward, done, extras = env.step(torch.zeros(2, 12))
        rewards.append(reward[0].item())
    assert done.tolist() == [1, 0]
    log = extras["log"]
    assert log["Episode/length"].item() == 10
    per_step = sum(rewards) / 10
    assert log["Episode_Reward/velocity_tracking"].item() == pytest.approx(per_step, rel=0.05)
    assert per_step > 100  # a walking step earns ~290, so a mean over 12 steps would show
    assert env.core.walked_steps.tolist() == [0, 10] and env.episode_length_buf.tolist() == [0, 10]
