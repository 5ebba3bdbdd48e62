import dataclasses
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

from rwalk import GYM_ID, EnvConfig, GaitParameters, ResidualWalkEnv, ResidualWalkVecEnv
from rwalk.constants import MODEL_DIR

# The spec's [-inf, inf] observation Box makes Gymnasium's checker say these two
# things; anything else it says is a failure.
INFINITE_BOX_WARNINGS = (
    "A Box observation space minimum value is -infinity",
    "A Box observation space maximum value is infinity",
)


def test_check_env_passes_with_only_the_spec_box_warnings():
    env = gym.make(GYM_ID, settle_steps=5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=True)
    other = [
        str(w.message)
        for w in caught
        if not any(s in str(w.message) for s in INFINITE_BOX_WARNINGS)
    ]
    assert other == []


def test_spaces_and_defaults_are_the_spec():
    env = ResidualWalkEnv()
    assert env.observation_space.shape == (65,) and env.action_space.shape == (12,)
    assert env.action_space.low.min() == -1.0 and env.action_space.high.max() == 1.0
    assert env.config.residual_scale == 0.02 and env.config.max_episode_steps == 1000
    assert env.config.settle_steps == 500 and env.config.model_path == "model/world_train.xml"
    assert env.expected_velocity == pytest.approx(0.08 / 0.6)


def test_spec_example_basic_training_setup(capsys):
    # Create environment
    env = ResidualWalkEnv(
        model_path="model/world_train.xml",
        residual_scale=0.02,
        max_episode_steps=1000,
        settle_steps=500,
    )

    # Reset and run episode
    obs, info = env.reset(seed=42)
    total_reward = 0.0

    for _ in range(1000):
        # Random policy (replace with trained policy)
        action = env.action_space.sample()

        obs, reward, terminated, truncated, info = env.step(action)
        total_reward += reward

        if terminated or truncated:
            print(f"Episode finished with reward: {total_reward}")
            print(f"Reward breakdown: {info['reward_components']}")
            print(f"Final body height: {info['body_height']:.3f}m")
            break

    out = capsys.readouterr().out
    assert "Episode finished with reward" in out and "Final body height" in out
    assert set(info) >= {"reward_components", "body_height"}


def test_spec_example_custom_gait(capsys):
    # Define custom gait (these remain fixed during training)
    custom_gait = GaitParameters(
        step_height=0.05, step_length=0.10, cycle_time=0.8, body_height=0.06
    )

    env = ResidualWalkEnv(gait_params=custom_gait, residual_scale=0.025)

    obs, info = env.reset()
    print(f"Expected velocity: {env.expected_velocity:.3f} m/s")

    assert capsys.readouterr().out.strip() == "Expected velocity: 0.125 m/s"
    assert obs.shape == (65,) and set(info) == {"phase", "lateral_offset", "start_position"}


def test_spec_example_training_with_ppo(tmp_path, monkeypatch):
    from stable_baselines3 import PPO

    monkeypatch.chdir(tmp_path)
    # Create environment
    env = ResidualWalkEnv(residual_scale=0.02, max_episode_steps=1000)

    # Train PPO agent
    model = PPO("MlpPolicy", env, learning_rate=3e-4, n_steps=2048, batch_size=64, verbose=1)

    model.learn(total_timesteps=2048)  # the spec trains for 1_000_000
    model.save("residual_walk_policy")
    assert (tmp_path / "residual_walk_policy.zip").is_file()


def test_spec_example_with_randomization():
    env = ResidualWalkEnv()

    # Reset with randomized initial conditions for robustness
    obs, info = env.reset(seed=123, options={"randomize": True})

    plain, _ = env.reset(seed=123)
    again, _ = env.reset(seed=123, options={"randomize": True})
    np.testing.assert_array_equal(obs, again)  # same seed, same perturbation
    assert not np.array_equal(obs, plain)


def test_info_and_reward_components_sum_exactly():
    env = ResidualWalkEnv(settle_steps=20)
    env.reset(seed=0)
    for _ in range(30):
        _, reward, _, _, info = env.step(env.action_space.sample())
        assert set(info["reward_components"]) == {
            "velocity_tracking",
            "contact_pattern",
            "stability",
            "lateral",
        }
        assert reward == sum(info["reward_components"].values())
        assert info["body_height"] == pytest.approx(env.core.obs[0, 2].item())


def test_single_env_is_env_i_of_the_batch():
    seed, n, i = 11, 3, 1
    config = EnvConfig(randomize=True)
    batched = ResidualWalkVecEnv(n, config, seed=seed)
    single = ResidualWalkEnv(config=config, seed=seed + i)
    td = batched.reset()
    obs, _ = single.reset()
    np.testing.assert_array_equal(obs, td["observation"][i].numpy())
    gen = torch.Generator().manual_seed(0)
    for _ in range(200):
        actions = torch.rand(n, 12, generator=gen) * 2 - 1
        td = batched.step(td.set("action", actions))["next"]
        obs, reward, terminated, _, _ = single.step(actions[i].numpy())
        np.testing.assert_array_equal(obs, td["observation"][i].numpy())
        assert np.float32(reward) == td["reward"][i].item()  # the vec env reports float32
        assert terminated == td["terminated"][i].item()


def test_bad_actions_name_the_problem():
    env = ResidualWalkEnv(settle_steps=0)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(12,\)"):
        env.step(np.zeros(13))
    bad = np.zeros(12)
    bad[7] = np.nan
    with pytest.raises(ValueError, match="index 7"):
        env.step(bad)
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(options={"randomise": True})


def test_truncates_at_max_episode_steps():
    env = ResidualWalkEnv(model_path="model/world_flat.xml", max_episode_steps=12, settle_steps=5)
    env.reset(seed=0)
    flags = [env.step(np.zeros(12))[3] for _ in range(12)]
    assert flags == [False] * 11 + [True]


def test_set_terrain_scale_really_flattens_the_ground():
    env = ResidualWalkEnv(settle_steps=0)
    rough = env.core.model.hfield_data.copy()
    env.set_terrain_scale(0.0)
    assert np.ptp(env.core.model.hfield_data) < 1e-6 < np.ptp(rough)
    assert env.terrain_scale == 0.0
    # The simulation runs on the new ground: the start is placed on the flat mean height.
    obs, _ = env.reset(seed=0)
    assert obs[2] == pytest.approx(0.075 + 0.004 + 0.0, abs=0.002)
    with pytest.raises(ValueError, match="terrain scale"):
        env.set_terrain_scale(-0.5)


def test_default_model_resolves_from_any_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    env = ResidualWalkEnv(settle_steps=0)
    assert env.core.model.nu == 12
    with pytest.raises(FileNotFoundError, match="no_such_world"):
        ResidualWalkEnv(model_path="no_such_world.xml")
    assert (MODEL_DIR / "world_train.xml").is_file()


def test_config_and_spec_arguments_do_not_mix():
    with pytest.raises(ValueError, match="either config"):
        ResidualWalkEnv(residual_scale=0.05, config=EnvConfig())
    env = ResidualWalkEnv(config=dataclasses.replace(EnvConfig(), residual_scale=0.05))
    assert env.config.residual_scale == 0.05


def test_divergence_ends_the_episode_and_reset_recovers(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs the divergence to ./MUJOCO_LOG.TXT
    env = ResidualWalkEnv(settle_steps=5)
    env.reset(seed=0)
    env.core.sim.qvel[0, :] = 1e12
    obs, reward, terminated, _, info = env.step(np.zeros(12))
    assert terminated and info["diverged"] and reward == 0.0 and np.isfinite(obs).all()
    env.reset()
    _, _, terminated, _, info = env.step(np.zeros(12))
    assert not terminated and not info["diverged"]


def test_info_has_the_phase_and_lateral_offset_on_reset_and_step():
    env = ResidualWalkEnv(settle_steps=5)
    _, info = env.reset(seed=0)
    core = env.core
    assert info["phase"] == core.phase[0].item() and 0.0 <= info["phase"] < 1.0
    assert info["lateral_offset"] == 0.0  # y0 is where the episode starts
    for _ in range(5):
        obs, _, _, _, info = env.step(np.full(12, 0.5, dtype=np.float32))
    assert info["phase"] == core.phase[0].item()
    assert info["lateral_offset"] == (core.obs[0, 1] - core.y0[0]).item() != 0.0


@pytest.mark.parametrize("limit", [None, 30])
def test_gym_make_has_one_episode_length(limit):
    kwargs = {} if limit is None else {"max_episode_steps": limit}
    env = gym.make(GYM_ID, model_path="model/world_flat.xml", settle_steps=2, **kwargs)
    expected = 1000 if limit is None else limit
    assert env.spec.max_episode_steps == expected
    env.reset(seed=0)
    zeros = np.zeros(12, dtype=np.float32)
    for step in range(1, expected + 1):
        _, _, terminated, truncated, _ = env.step(zeros)
        assert not terminated and truncated == (step == expected), step


def test_gym_make_refuses_a_config_episode_length_it_would_ignore():
    from rwalk import EnvConfig

    with pytest.raises(ValueError, match=r"gymnasium.make\(\.\.\., max_episode_steps=30\)"):
        gym.make(GYM_ID, config=EnvConfig(max_episode_steps=30))


def test_pickle_and_deepcopy_continue_exactly_where_the_env_was():
    import copy
    import pickle

    env = ResidualWalkEnv(settle_steps=5)
    env.reset(seed=3, options={"randomize": True})
    actions = np.random.default_rng(0).uniform(-1, 1, (40, 12)).astype(np.float32)
    for action in actions[:10]:
        env.step(action)
    copies = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    try:
        import cloudpickle

        copies.append(cloudpickle.loads(cloudpickle.dumps(env)))
    except ImportError:
        pass
    for action in actions[10:]:
        expected = env.step(action)
        for other in copies:
            got = other.step(action)
            np.testing.assert_array_equal(got[0], expected[0])
            assert got[1:4] == expected[1:4] and got[4] == expected[4]
    obs, info = env.reset(seed=7)
    for other in copies:
        again, again_info = other.reset(seed=7)
        np.testing.assert_array_equal(again, obs)
        assert again_info == info
