"""Training-only reward shaping and commands drawn within an episode: hand-computed terms,
the spec's env untouched, the values reaching the env from rwalk-train's command line."""

import dataclasses

import pytest
import torch

from rwalk import Core, EnvConfig, ResidualWalkEnv
from rwalk.envs.single_step import SingleStep
from rwalk.levels import TerrainLevels
from rwalk.randomization import Randomization
from rwalk.rewards import (
    TERM_NAMES,
    GaitCosts,
    Shaping,
    action_rate,
    kernel_width,
    tracking_kernel,
)
from rwalk.rl.config import late_reward
from rwalk.runners import train

FLAT = EnvConfig(model_path="model/world_flat.xml", settle_steps=5)


def test_the_tracking_kernel_by_hand():
    v = torch.tensor([0.13, 0.15, 0.11, 0.17], dtype=torch.float64)
    got = tracking_kernel(v, 0.13, 0.02)
    # errors of 0, 1, -1 and 2 half-widths: 1, 1/2, 1/2, 1/5
    torch.testing.assert_close(got, torch.tensor([1.0, 0.5, 0.5, 0.2], dtype=torch.float64))
    assert tracking_kernel(0.13, 0.13, 0.02) == 1.0  # the one-env float pipeline's floats


def test_the_kernel_widens_with_the_target_by_hand():
    shaping = Shaping(tracking=1.0, sigma=0.02, sigma_per_speed=0.16)
    target = torch.tensor([0.05, 0.125, 0.25], dtype=torch.float64)
    # max(0.02, 0.16 v*): 0.008 and 0.02 are not wider than sigma, 0.04 is
    assert kernel_width(shaping, target).tolist() == [0.02, 0.02, 0.04]
    assert kernel_width(shaping, 0.25) == 0.04 and kernel_width(Shaping(), target) == 0.02
    # 40 mm/s over each target: two half-widths at the slow ones (1/5), one at 0.25 (1/2)
    got = tracking_kernel(target + 0.04, target, kernel_width(shaping, target))
    torch.testing.assert_close(got, torch.tensor([0.2, 0.2, 0.5], dtype=torch.float64))


def test_each_env_s_kernel_has_its_own_command_s_width():
    config = dataclasses.replace(FLAT, command_range=(0.05, 0.25),
                                 shaping=Shaping(tracking=10.0, sigma_per_speed=0.16))  # fmt: skip
    core = Core(config, 4, seed=3)
    core.reset()
    terms = core.step(torch.zeros(4, 12)).terms
    target, v = core.task.v_target, core.obs[:, 7]
    width = torch.clamp(0.16 * target, min=0.02)
    assert bool((width > 0.02).any()) and bool((width == 0.02).any())  # both sides drawn
    expected = 10.0 * (1.0 / (1.0 + ((v - target) / width) ** 2))
    torch.testing.assert_close(terms["tracking_kernel"], expected)


def test_shaping_terms_are_added_and_reported_and_the_spec_env_has_none():
    shaped = dataclasses.replace(FLAT, shaping=Shaping(tracking=100.0, sigma=0.02, alive=2.0))
    core = Core(shaped, 2, seed=0)
    core.reset()
    result = core.step(torch.zeros(2, 12))
    assert tuple(result.terms) == (
        *TERM_NAMES,
        "tracking_kernel",
        "alive",
        "action_rate",
        "latency_action_rate",
        "kind_tracking",
    )
    v = core.obs[:, 7]
    expected = 100.0 * tracking_kernel(v, core.task.v_target, 0.02)
    torch.testing.assert_close(result.terms["tracking_kernel"], expected)
    assert result.terms["alive"].tolist() == [2.0, 2.0]
    assert result.terms["action_rate"].tolist() == [0.0, 0.0]  # weight 0: exact zeros
    assert torch.equal(result.reward, sum(result.terms.values(), torch.zeros(2)))
    env = ResidualWalkEnv(seed=0, settle_steps=5)
    env.reset()
    _, _, _, _, info = env.step(env.action_space.sample() * 0)
    assert tuple(info["reward_components"]) == TERM_NAMES


def test_kind_tracking_weighs_the_spec_s_tracking_term_on_its_kinds_only():
    """-270 on the stones envs: their tracking weight is 30 in the training's reward,
    the other kinds' the spec's 300; the spec's own term is unchanged."""
    levels = TerrainLevels(levels=2, tile_length=3.0, pad_length=0.8)
    config = EnvConfig(terrain_levels=levels, settle_steps=5,
                       shaping=Shaping(kind_tracking=-270.0))  # fmt: skip
    core = Core(config, 8, seed=2)
    core.reset()
    result = core.step(torch.zeros(8, 12))
    v, stones = core.obs[:, 7], core.terrain_kind == 3  # rough, slopes, steps, stones
    tracking = 1.0 - (v - core.task.v_target).abs()
    expected = torch.where(stones, -270.0 * tracking, torch.zeros(8, dtype=torch.float64))
    assert torch.equal(result.terms["kind_tracking"], expected)  # the same operations
    torch.testing.assert_close(result.terms["velocity_tracking"], 300.0 * tracking)
    assert stones.tolist() == [False, False, False, True] * 2
    unweighted = Core(dataclasses.replace(config, shaping=Shaping()), 8, seed=2)
    unweighted.reset()
    plain = unweighted.step(torch.zeros(8, 12))  # weight 0: the term adds exact zeros
    assert torch.equal(plain.terms["kind_tracking"], torch.zeros(8, dtype=torch.float64))
    others = [term for name, term in plain.terms.items() if name != "kind_tracking"]
    assert torch.equal(plain.reward, sum(others, torch.zeros(8, dtype=torch.float64)))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"terrain_levels": None}, r"kind_tracking -270.0 .* none, no map"),
        ({"shaping": Shaping(kind_tracking=-270.0, tracking_kinds=("ice",))},
         r"tracking_kinds \('ice',\)"),
        ({"shaping": Shaping(kind_tracking=-270.0, tracking_kinds=())}, r"tracking_kinds \(\)"),
    ],
)  # fmt: skip
def test_kind_tracking_needs_its_kinds_on_the_map(change, message):
    base = dict(terrain_levels=TerrainLevels(), shaping=Shaping(kind_tracking=-270.0))
    with pytest.raises(ValueError, match=message):
        EnvConfig(**(base | change))
    with pytest.raises(ValueError, match=r"Shaping.tracking_kinds must be a tuple.*'stones'"):
        Shaping(tracking_kinds="stones")


def test_set_reward_changes_the_terms_values_from_the_next_step():
    """A core switched to a wider kernel and a higher clearance target after 3 steps
    reports, from then on, the very terms of a core built with them (the terms do not move
    the simulation, so both walk the same steps), and before it those of the old values."""
    old = dataclasses.replace(FLAT, costs=GaitCosts(), shaping=Shaping(tracking=300.0))
    late = {
        "costs": GaitCosts(clearance_target=0.025),
        "shaping": Shaping(tracking=300.0, sigma=0.04),
    }
    switched, before, after = (Core(c, 3, seed=0) for c in
                               (old, old, dataclasses.replace(old, **late)))  # fmt: skip
    for core in (switched, before, after):
        core.reset()
    action, shortfall = torch.zeros(3, 12), []
    for step in range(12):
        if step == 3:
            switched.set_reward(**late)
        got, *theirs = (core.step(action).terms for core in (switched, before, after))
        expected = theirs[0] if step < 3 else theirs[1]
        for name, value in expected.items():
            assert torch.equal(got[name], value), (step, name)
        shortfall.append([float(t["clearance"].sum()) for t in theirs])
    assert switched.config == after.config
    # the two sets of values differ where it shows: the kernel, and the clearance (steps
    # 3-6 here: a foot under 25 mm and over 15 mm in mid swing)
    assert not torch.equal(theirs[0]["tracking_kernel"], theirs[1]["tracking_kernel"])
    assert any(low != high for low, high in shortfall[3:])
    v = switched.obs[:, 7]
    kernel = 300.0 * tracking_kernel(v, switched.task.v_target, 0.04)
    torch.testing.assert_close(got["tracking_kernel"], kernel)


def test_set_reward_refuses_a_missing_part_and_a_change_of_terms():
    core = Core(dataclasses.replace(FLAT, shaping=Shaping(tracking=300.0)), 1, seed=0)
    with pytest.raises(ValueError, match="no costs to change"):
        core.set_reward(costs=GaitCosts())
    assert core.config.shaping == Shaping(tracking=300.0)  # a refusal changes nothing
    assert [t.name for t in core.terms] == [*TERM_NAMES, "tracking_kernel", "alive",
                                            "action_rate", "latency_action_rate",
                                            "kind_tracking"]  # fmt: skip
    costed = Core(dataclasses.replace(FLAT, costs=GaitCosts()), 1, seed=0)
    names = [t.name for t in costed.terms]
    with pytest.raises(ValueError, match=r"not which terms.*'stumble'"):
        costed.set_reward(costs=GaitCosts(stumble=1.0))
    assert costed.config.costs == GaitCosts() and [t.name for t in costed.terms] == names


def test_set_reward_raises_the_action_rate_from_weight_0():
    """A late stage's --late-action-rate: the term is there at weight 0 (exact zeros) and
    costs the action's change from the next step on, as in a core built with it."""
    old = dataclasses.replace(FLAT, shaping=Shaping(tracking=300.0))
    late = Shaping(tracking=300.0, action_rate=20.0)
    switched, built = Core(old, 2, seed=0), Core(dataclasses.replace(old, shaping=late), 2, seed=0)
    for core in (switched, built):
        core.reset()
    gen = torch.Generator().manual_seed(0)
    for step in range(6):
        if step == 3:
            switched.set_reward(shaping=late)
        action = torch.rand(2, 12, generator=gen) * 2 - 1
        got, theirs = (core.step(action).terms for core in (switched, built))
        if step < 3:
            assert torch.equal(got["action_rate"], torch.zeros(2))
        else:
            assert torch.equal(got["action_rate"], theirs["action_rate"])
            assert bool((got["action_rate"] < 0).all())
    assert switched.config == built.config


def test_the_action_rate_by_hand():
    a = torch.tensor([[0.5, -0.25, 0.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
    last = torch.tensor([[0.25, 0.25, 0.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
    # 0.25^2 + 0.5^2 + 0 = 0.3125; no change: 0
    assert action_rate(a, last).tolist() == [0.3125, 0.0]


def test_the_action_rate_costs_each_change_from_the_episodes_zero_start():
    shaped = dataclasses.replace(FLAT, shaping=Shaping(action_rate=2.0))
    core = Core(shaped, 2, seed=0)
    core.reset()
    first = torch.zeros(2, 12)
    first[0, 0], first[1, 5] = 0.5, -2.0  # clipped to -1 before it counts
    second = first.clone()
    second[0, 0], second[0, 1] = 0.25, 0.5
    terms = [core.step(a).terms["action_rate"] for a in (first, second)]
    assert terms[0].tolist() == [-2.0 * 0.25, -2.0 * 1.0]  # from the zero action
    assert terms[1].tolist() == [-2.0 * (0.0625 + 0.25), 0.0]
    core.reset(torch.tensor([1]))  # a new episode starts from the zero action again
    assert core.step(second).terms["action_rate"].tolist() == [0.0, -2.0 * 1.0]
    # the one-env float pipeline counts the same
    single = Core(shaped, 1, seed=0)
    single.reset()
    step = SingleStep(single)
    got = [step.step(a[0].numpy()).terms["action_rate"] for a in (first, second)]
    assert got == [-2.0 * 0.25, -2.0 * (0.0625 + 0.25)]
    assert torch.equal(single.task.last_action[0], first[0].double())


def test_the_latency_action_rate_costs_the_change_per_substep_of_each_env_s_delay():
    """70 per substep: the same change costs 0, 70, 140 and 210 where the servos lag 0-3
    substeps; a latency range of (0, 0) ends every cost at once, as it ends every delay."""
    randomization = Randomization(latency=(0, 3))
    config = dataclasses.replace(FLAT, randomization=randomization,
                                 shaping=Shaping(latency_action_rate=70.0))  # fmt: skip
    core = Core(config, 16, seed=1)
    core.reset()
    lag = core.physics.latency.clone()
    assert sorted(set(lag.tolist())) == [0, 1, 2, 3]  # every delay drawn
    action = torch.zeros(16, 12)
    action[:, 0], action[:, 3] = 0.5, -0.25  # from the zero action: 0.25 + 0.0625
    got = core.step(action).terms["latency_action_rate"]
    assert torch.equal(got, -70.0 * (0.3125 * lag.double()))  # the same operations
    assert got[lag == 3].unique().tolist() == [-70.0 * 3 * 0.3125]  # by hand: -65.625
    assert got[lag == 0].unique().tolist() == [0.0]
    assert core.step(action).terms["latency_action_rate"].abs().sum() == 0  # no change
    core.physics.set_ranges(dataclasses.replace(randomization, latency=(0, 0)))
    action[:, 0] = -0.5
    assert torch.equal(core.step(action).terms["latency_action_rate"], torch.zeros(16).double())
    assert torch.equal(core.physics.latency, lag)  # the draws stay until each env resets
    still = Core(dataclasses.replace(config, randomization=None), 2, seed=1)  # no delay at all
    still.reset()
    assert still.step(action[:2]).terms["latency_action_rate"].tolist() == [0.0, 0.0]
    # the one-env float pipeline counts the same
    single = Core(config, 1, seed=2)
    single.reset()
    assert int(single.physics.latency[0]) == 3  # this seed's draw
    first = torch.zeros(12)
    first[0], first[3] = 0.5, -0.25
    assert SingleStep(single).step(first.numpy()).terms["latency_action_rate"] == -65.625


@pytest.mark.parametrize(
    "bad",
    [
        dict(sigma=0.0),
        dict(tracking=float("nan")),
        dict(alive=1e9),
        dict(action_rate=-1.0),
        dict(latency_action_rate=-70.0),
        dict(latency_action_rate=float("nan")),
        dict(sigma_per_speed=-0.1),
        dict(sigma_per_speed=float("inf")),
    ],
)
def test_bad_shaping_is_named(bad):
    with pytest.raises(ValueError, match=r"Shaping\."):
        Shaping(**bad)


def test_commands_are_drawn_again_every_interval_and_env_i_is_a_single_env():
    config = dataclasses.replace(FLAT, command_range=(0.05, 0.25), command_interval=0.1)
    core = Core(config, 3, seed=4)
    core.reset()
    targets = [core.task.target.clone()]
    for _ in range(10):  # 0.1 s = 5 steps: new draws after steps 5 and 10
        core.step(torch.zeros(3, 12))
        targets.append(core.task.target.clone())
    changes = [i for i in range(1, 11) if not torch.equal(targets[i], targets[i - 1])]
    assert changes == [5, 10]
    assert bool(((targets[-1] >= 0.05) & (targets[-1] <= 0.25)).all())
    single = Core(config, 1, seed=5)
    single.reset()
    for _ in range(10):
        single.step(torch.zeros(1, 12))
    assert single.task.target[0] == targets[-1][1]


@pytest.mark.parametrize("bad", [0.0, -1.0, float("inf"), 1e9])
def test_a_bad_command_interval_is_named(bad):
    with pytest.raises(ValueError, match=r"EnvConfig\.command_interval"):
        EnvConfig(command_interval=bad)


def test_rwalk_train_sets_shaping_and_the_interval_from_its_command_line():
    training = train.parse_args(["--env.shaping.tracking", "300", "--env.shaping.sigma", "0.03",
                                 "--env.shaping.action-rate", "20",
                                 "--command-range", "0.07", "0.2",
                                 "--env.command-interval", "4"])  # fmt: skip
    assert training.env.shaping == Shaping(tracking=300.0, sigma=0.03, action_rate=20.0)
    assert training.env.command_interval == 4.0 and training.env.command_range == (0.07, 0.2)
    assert "command" in training.train.policy_obs  # the policy reads what it is asked


def test_the_action_rate_is_a_late_value_beside_the_default_stage_s_kernel():
    training = train.parse_args(["--recipe", "plain", "--late-action-rate", "20"])
    assert training.train.late_iterations == 50 and training.train.late_tracking == 200.0
    late = late_reward(training.train, training.env)["shaping"]
    assert late == Shaping(tracking=200.0, action_rate=20.0)
    assert training.env.shaping == Shaping()  # every term at weight 0 before the stage


def test_the_kernel_s_growth_with_speed_is_a_flag_and_a_late_value():
    training = train.parse_args(["--env.shaping.tracking", "300",
                                 "--env.shaping.sigma-per-speed", "0.1", "--late-iterations",
                                 "5", "--late-sigma-per-speed", "0.16"])  # fmt: skip
    assert training.env.shaping == Shaping(tracking=300.0, sigma_per_speed=0.1)
    late = late_reward(training.train, training.env)["shaping"]
    assert late == Shaping(tracking=300.0, sigma_per_speed=0.16)
