"""The adaptive-gait task (spec: AdaptiveGaitEnv.md) and the task registry."""

import dataclasses
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

from rwalk import (
    ADAPTIVE_GYM_ID,
    AdaptiveGaitConfig,
    AdaptiveGaitEnv,
    AdaptiveGaitVecEnv,
    Core,
    EnvConfig,
    GaitBounds,
    GaitParameters,
    ResidualWalkVecEnv,
)
from rwalk.gait import advance_phase
from rwalk.tasks import TASKS, get_task
from rwalk.tasks.adaptive_gait import ADAPTED
from rwalk.wrappers import RslRlVecEnv

FLAT = "model/world_flat.xml"
FAST = AdaptiveGaitConfig(model_path=FLAT, settle_steps=10)
F64 = torch.float64


def core(n=2, seed=0, **changes):
    return Core(dataclasses.replace(FAST, **changes), n, seed=seed)


def test_check_env_passes_and_make_builds_the_contract_spaces():
    env = gym.make(ADAPTIVE_GYM_ID, settle_steps=5)
    assert env.observation_space.shape == (69,) and env.action_space.shape == (16,)
    assert env.spec.max_episode_steps == 1000
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=True)
    assert all("infinity" in str(w.message) for w in caught), [str(w.message) for w in caught]


def test_observation_is_the_65_values_then_the_normalised_parameters():
    env = AdaptiveGaitEnv(model_path=FLAT, settle_steps=10, seed=1)
    obs, info = env.reset()
    assert obs.shape == (69,)
    np.testing.assert_array_equal(obs[:65], env.core.obs[0].numpy().astype(np.float32))
    assert obs[65:].tolist() == [0.0, 0.0, 0.0, 0.0]  # the default start is each range's centre
    action = np.zeros(16, dtype=np.float32)
    action[0] = 1.0  # step height up by one delta
    obs, _, _, _, info = env.step(action)
    b = env.config.bounds
    height = 0.025 + b.step_height.delta
    assert info["gait_params"]["step_height"] == pytest.approx(height, abs=1e-15)
    centre = 0.5 * (b.step_height.low + b.step_height.high)
    half = 0.5 * (b.step_height.high - b.step_height.low)
    assert obs[65] == pytest.approx((height - centre) / half, rel=1e-6)
    assert set(info) >= {"reward_components", "body_height", "gait_params", "diverged"}
    assert list(info["gait_params"]) == list(ADAPTED)


def test_deltas_accumulate_and_clip_to_the_ranges():
    c = core(1)
    c.reset()
    action = torch.zeros(1, 16, dtype=F64)
    action[0, :4] = torch.tensor([1.0, -1.0, 1.0, -1.0])
    for _ in range(60):  # 20 steps sweep a whole range; 60 must end at the bounds
        c.step(action)
    b = c.config.bounds
    expected = [b.step_height.high, b.step_length.low, b.cycle_time.high, b.body_height.low]
    assert c.task.params[0].tolist() == expected
    c.reset()
    assert c.task.params[0].tolist() == [0.025, 0.08, 0.6, 0.07]  # back to gait_params


def test_a_full_sweep_takes_a_fraction_of_a_second():
    b = GaitBounds()
    for name in ADAPTED:
        low, high, delta = getattr(b, name)
        seconds = (high - low) / delta * 0.02
        assert 0.1 <= seconds <= 1.0, (name, seconds)


def test_phase_is_continuous_when_the_cycle_time_changes():
    c = core(1)
    c.reset()
    before = float(c.task.gait_phase[0])
    action = torch.zeros(1, 16, dtype=F64)
    action[0, 2] = -1.0  # shorter cycle: faster phase
    c.step(action)
    cycle = 0.6 - c.config.bounds.cycle_time.delta
    expected = (before + c.decimation * c.dt / cycle) % 1.0
    assert float(c.task.gait_phase[0]) == pytest.approx(expected, abs=1e-12)


def test_advance_phase_hand_computed():
    phases = advance_phase(torch.tensor([0.9], dtype=F64), torch.tensor([0.5], dtype=F64), 0.1, 3)
    torch.testing.assert_close(phases[0], torch.tensor([0.9, 0.1, 0.3, 0.5], dtype=F64))


def test_swing_follows_each_envs_phase_and_the_duty_factor():
    c = core(1)
    controller = c.controller  # duty 0.65, trot offsets (0, 0.5, 0.5, 0)
    swing = controller.swing_at(torch.tensor([0.6, 0.7, 0.2], dtype=F64))
    assert swing.tolist() == [
        [False, False, False, False],
        [True, False, False, True],
        [False, True, True, False],
    ]


def test_zero_action_walks_the_starting_gait_of_the_residual_task():
    """The continuous-phase path and the residual task's table give the same targets."""
    adaptive = core(1, seed=3)
    residual = Core(EnvConfig(model_path=FLAT, settle_steps=10), 1, seed=3)
    adaptive.reset()
    residual.reset()
    ctrl_a, swing_a = adaptive.task.act(torch.zeros(1, 16, dtype=F64))
    ctrl_r, swing_r = residual.task.act(torch.zeros(1, 12, dtype=F64))
    np.testing.assert_allclose(ctrl_a, ctrl_r, rtol=0, atol=1e-12)
    assert torch.equal(swing_a, swing_r)


def test_each_env_of_a_batch_steps_like_a_single_env_bit_for_bit():
    batch, single = core(3, seed=7), core(1, seed=8)
    batch.reset()
    single.reset()
    g = torch.Generator().manual_seed(0)
    for _ in range(15):
        actions = torch.rand(3, 16, generator=g, dtype=F64) * 2 - 1
        a = batch.step(actions)
        b = single.step(actions[1:2])
        assert torch.equal(a.obs[1], b.obs[0]) and torch.equal(a.reward[1], b.reward[0])
    assert torch.equal(batch.task.params[1], single.task.params[0])
    assert not torch.equal(batch.task.params[0], batch.task.params[1])  # per-env parameters


def test_velocity_commands_are_drawn_per_episode_and_exposed():
    cfg = dataclasses.replace(FAST, command_range=(0.05, 0.25))
    env = AdaptiveGaitVecEnv(4, cfg, seed=5)
    td = env.reset()
    first = td["command"].squeeze(-1)
    assert ((first >= 0.05) & (first <= 0.25)).all() and len(set(first.tolist())) == 4
    assert torch.equal(env.core.task.v_target.float(), first)
    env.core.reset(np.array([0]))
    assert env.core.task.target[0] != first[0]  # a new episode, a new draw
    again = AdaptiveGaitVecEnv(4, cfg, seed=5).reset()["command"]
    assert torch.equal(again, td["command"])  # a pure function of the seed
    adapter = RslRlVecEnv(env)
    assert adapter.get_observations()["policy"].shape == (4, 69 + 2 + 1 + 1)
    assert "command" not in AdaptiveGaitVecEnv(2, FAST, seed=0).reset()


def test_velocity_term_tracks_the_episodes_target():
    cfg = dataclasses.replace(FAST, command_range=(0.2, 0.2))
    c = Core(cfg, 2, seed=0)
    c.reset()
    r = c.step(torch.zeros(2, 16))
    v = c.obs[:, 7]
    torch.testing.assert_close(r.terms["velocity_tracking"], 300.0 * (1.0 - (v - 0.2).abs()))


def test_torchrl_view_passes_check_env_specs():
    from torchrl.envs.utils import check_env_specs

    env = AdaptiveGaitVecEnv(2, dataclasses.replace(FAST, command_range=(0.1, 0.2)), seed=0)
    check_env_specs(env)
    assert env.action_spec.shape == (2, 16) and env.observation_spec["observation"].shape == (2, 69)


def test_pickle_keeps_the_gait_state():
    c = core(2, seed=1)
    c.reset()
    c.step(torch.ones(2, 16))
    copy = pickle.loads(pickle.dumps(c))
    for name in ("params", "gait_phase", "target"):
        assert torch.equal(getattr(copy.task, name), getattr(c.task, name)), name
    a, b = c.step(torch.zeros(2, 16)), copy.step(torch.zeros(2, 16))
    assert torch.equal(a.obs, b.obs)


@pytest.mark.parametrize(
    ("bounds", "field"),
    [
        ({"step_height": (0.04, 0.01, 0.001)}, "GaitBounds.step_height"),
        ({"cycle_time": (0.3, 0.9, 0.0)}, "GaitBounds.cycle_time"),
        ({"step_height": (0.01, 0.06, 0.001)}, "GaitBounds.step_height"),  # reaches the body
        ({"step_length": (0.1, 0.2, 0.01)}, "GaitBounds.step_length"),  # start 0.08 outside
        ({"step_length": (-0.1, 0.2, 0.01)}, "GaitBounds.step_length"),
        ({"body_height": (float("nan"), 0.09, 0.001)}, "GaitBounds.body_height"),
    ],
)
def test_invalid_bounds_name_the_field(bounds, field):
    with pytest.raises(ValueError, match=field):
        AdaptiveGaitConfig(bounds=GaitBounds(**bounds))


def test_a_body_height_the_legs_cannot_reach_is_refused():
    bounds = GaitBounds(body_height=(0.05, 0.12, 0.002))
    with pytest.raises(ValueError, match=r"GaitBounds.body_height.*cannot reach"):
        AdaptiveGaitEnv(model_path=FLAT, settle_steps=5, bounds=bounds)


def test_a_starting_gait_outside_the_ranges_is_refused():
    with pytest.raises(ValueError, match=r"GaitBounds\.cycle_time"):
        AdaptiveGaitEnv(gait_params=GaitParameters(cycle_time=1.0), settle_steps=5)


def test_bad_command_ranges_are_refused():
    with pytest.raises(ValueError, match="command_range"):
        AdaptiveGaitConfig(command_range=(0.3, 0.1))


def test_actions_of_the_other_task_are_refused_naming_the_layout():
    adaptive = AdaptiveGaitEnv(model_path=FLAT, settle_steps=5)
    adaptive.reset(seed=0)
    with pytest.raises(ValueError, match=r"\(16,\).*4 gait deltas.*got \(12,\)"):
        adaptive.step(np.zeros(12, dtype=np.float32))
    residual = ResidualWalkVecEnv(2, EnvConfig(model_path=FLAT, settle_steps=5), seed=0)
    residual.reset()
    with pytest.raises(ValueError, match=r"\(2, 12\).*'residual_walk'.*got \(2, 16\)"):
        residual.core.step(torch.zeros(2, 16))


def test_unknown_tasks_list_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown task 'walk'.*adaptive_gait.*residual_walk"):
        get_task("walk")
    with pytest.raises(ValueError, match="unknown task"):
        ResidualWalkVecEnv(2, task="walk")
    with pytest.raises(ValueError, match=r"takes a AdaptiveGaitConfig, got a EnvConfig"):
        Core(EnvConfig(), 1, task="adaptive_gait")


def test_a_new_term_is_one_function_and_one_line(monkeypatch):
    """A task with one more term, registered by one line: every view reports it."""
    from rwalk.tasks.residual_walk import ResidualWalk

    def upright(state):  # the function
        return state.rpy[:, 0] * state.rpy[:, 0]

    class Upright(ResidualWalk):
        name = "upright_walk"

        def reward_terms(self):
            from rwalk.rewards import RewardTerm

            return (*super().reward_terms(), RewardTerm("upright", -2.0, upright))  # the line

    monkeypatch.setitem(TASKS, "upright_walk", Upright)
    config = EnvConfig(model_path=FLAT, settle_steps=5)
    env = ResidualWalkVecEnv(2, config, seed=0, task="upright_walk")
    td = env.rand_step(env.reset())
    terms = td["next", "reward_terms"]
    assert "upright" in terms
    rpy = env.core.obs[:, 3:7]  # the term is -2 roll², and the reward sums every term
    from rwalk.rewards import quat_to_rpy

    roll = quat_to_rpy(rpy)[:, 0]
    torch.testing.assert_close(terms["upright"].squeeze(-1), (-2.0 * roll * roll).float())
    total = sum(terms[name] for name in terms.keys())  # noqa: SIM118 (TensorDict)
    torch.testing.assert_close(total, td["next", "reward"])
    assert "upright" in env.core.episode_sums
    assert "sum/upright" in env.core.episode_log(torch.tensor([0]))


def test_start_spread_draws_parameters_across_the_ranges_per_episode():
    c = core(64, seed=2, start_spread=0.5)
    c.reset()
    params = c.task.params.clone()
    b = c.config.bounds
    low = torch.tensor([getattr(b, n).low for n in ADAPTED], dtype=F64)
    high = torch.tensor([getattr(b, n).high for n in ADAPTED], dtype=F64)
    assert ((params >= low) & (params <= high)).all()
    spread = params.max(0).values - params.min(0).values
    assert (spread > 0.8 * (high - low)).all()  # 0.5 around the centred start: the whole range
    again = core(64, seed=2, start_spread=0.5)
    again.reset()
    assert torch.equal(again.task.params, params)  # a pure function of the seed
    c.reset(np.array([0]))
    assert not torch.equal(c.task.params[0], params[0])  # each episode draws anew


def test_without_start_spread_every_episode_starts_from_gait_params():
    c = core(3, seed=2)
    c.reset()
    assert (c.task.params == c.task.start).all()


def test_start_spread_outside_zero_one_is_refused():
    with pytest.raises(ValueError, match=r"start_spread must be in \[0, 1\], got 1.5"):
        AdaptiveGaitConfig(start_spread=1.5)
