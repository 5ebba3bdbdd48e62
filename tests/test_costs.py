"""The gait costs (clearance, slip, power), the adaptive task's target action, and their
bad inputs."""

import dataclasses
import math

import mujoco
import numpy as np
import pytest
import torch

from rwalk import AdaptiveGaitConfig, Core, EnvConfig, GaitCosts, GaitParameters
from rwalk.constants import OBS_CONTACT, OBS_JOINT_VEL
from rwalk.gaitmath import speed_schedule
from rwalk.observations import foot_velocities
from rwalk.rewards import (
    MID_SWING,
    clearance_shortfall,
    foot_slip,
    grown_with_speed,
    mid_swing_contacts,
    per_metre_above,
    servo_power,
)
from rwalk.rl.legacy import TrainingEnv

FLAT = "model/world_flat.xml"
F64 = torch.float64
COSTS = GaitCosts(clearance=2.0, slip=3.0, power=5.0, clearance_target=0.01)


# ------------------------------------------------------------------ terms by hand
def test_clearance_shortfall_counts_mid_swing_feet_below_the_target():
    clearance = torch.tensor([[0.005, 0.02, 0.0, -0.01], [0.0, 0.0, 0.0, 0.0]], dtype=F64)
    progress = torch.tensor([[0.5, 0.5, 0.1, 0.75], [-0.3, 0.25, 0.2499, 1.0]], dtype=F64)
    value = clearance_shortfall(clearance, progress, 0.015)
    # row 0: 0.015 - 0.005, nothing (above), not mid swing, 0.015 + 0.01 (0.75 counts)
    # row 1: stance, 0.015 (0.25 counts), not yet mid swing, touching down
    expected = torch.tensor([(0.015 - 0.005) + 0.0 + 0.0 + (0.015 + 0.01), 0.015], dtype=F64)
    assert torch.equal(value, expected)
    assert MID_SWING == (0.25, 0.75)


def test_each_env_s_clearance_target_grows_with_its_target_speed_by_hand():
    # max(0.015, 0.1 s x v*): 0.005 and 0.015 are not above the floor, 0.025 is
    target = torch.tensor([0.05, 0.15, 0.25], dtype=F64)
    assert grown_with_speed(0.015, 0.1, target).tolist() == [0.015, 0.015, 0.025]
    assert grown_with_speed(0.015, 0.1, 0.25) == 0.025
    assert grown_with_speed(0.015, 0.0, 9.0) == 0.015  # 0: the floor at any speed
    clearance = torch.tensor([[0.01, 0.02, 0.0, 0.0], [0.01, 0.02, 0.0, 0.0]], dtype=F64)
    progress = torch.tensor([[0.5, 0.5, 0.1, 0.9], [0.5, 0.5, 0.1, 0.9]], dtype=F64)
    value = clearance_shortfall(clearance, progress, torch.tensor([0.015, 0.025], dtype=F64))
    # row 0: 0.015 - 0.01 and nothing; row 1: 0.025 - 0.01 and 0.025 - 0.02 (the others
    # are not in mid swing)
    expected = torch.tensor([0.015 - 0.01, (0.025 - 0.01) + (0.025 - 0.02)], dtype=F64)
    assert torch.equal(value, expected)


def test_mid_swing_contacts_count_feet_touching_in_the_middle_of_their_swing():
    contact = torch.tensor([[True, True, True, False], [True, True, False, True]])
    progress = torch.tensor([[0.5, 0.1, 0.75, 0.5], [-0.2, 0.25, 0.5, 0.7499]], dtype=F64)
    # row 0: mid swing and touching, early swing, touching at 0.75, mid swing in the air
    # row 1: stance, touching at 0.25, in the air, touching
    assert mid_swing_contacts(contact, progress).tolist() == [2.0, 2.0]


def test_foot_slip_sums_the_horizontal_speed_of_feet_on_the_ground():
    contact = torch.tensor([[True, False, True, True]])
    velocity = torch.tensor([[[3.0, 4.0, 9.0], [10.0, 0.0, 0.0], [0.0, 0.0, 5.0],
                              [-0.6, 0.8, 0.0]]], dtype=F64)  # fmt: skip
    assert foot_slip(contact, velocity).tolist() == [5.0 + 0.0 + 0.0 + 1.0]


def test_servo_power_sums_the_absolute_mechanical_power_of_the_joints():
    torque = torch.tensor([[1.0, -2.0, 0.5] + [0.0] * 9], dtype=F64)
    speed = torch.tensor([[3.0, 4.0, -2.0] + [7.0] * 9], dtype=F64)
    assert servo_power(torque, speed).tolist() == [3.0 + 8.0 + 1.0]


def test_power_is_priced_per_metre_above_its_speed_by_hand():
    # 0.1 / max(0.1, |v*|): a watt costs its full price at and below 0.1 m/s (backwards
    # too), 0.1 / 0.25 = 0.4 of it at 0.25 m/s, half at -0.2 m/s
    target = torch.tensor([0.05, 0.1, 0.25, -0.2, 0.0], dtype=F64)
    assert per_metre_above(0.1, target).tolist() == [1.0, 1.0, 0.1 / 0.25, 0.5, 1.0]
    assert per_metre_above(0.1, 0.25) == 0.1 / 0.25
    assert per_metre_above(0.0, 9.0) == 1.0  # 0: off, every watt the same


def test_foot_velocities_match_mujoco_s_own_site_velocity():
    model = mujoco.MjModel.from_xml_path("rwalk/model/world_flat.xml")
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    rng = np.random.default_rng(0)
    data.qvel[:] = rng.normal(size=model.nv)
    quat = np.array([0.9, 0.1, 0.2, 0.1])
    data.qpos[3:7] = quat / np.linalg.norm(quat)
    mujoco.mj_forward(model, data)
    sensors = torch.tensor(data.sensordata[None, :65].copy())
    ours = foot_velocities(sensors)[0]
    for leg, name in enumerate(("FL", "FR", "RL", "RR")):
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"{name}_foot")
        velocity = np.zeros(6)
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_SITE, site, velocity, 0)
        # Another order of the same products: equal to rounding.
        np.testing.assert_allclose(ours[leg].numpy(), velocity[3:], rtol=0, atol=1e-12)


# ------------------------------------------------------------------ terms in the env
def _core(task="residual_walk", n=3, **changes):
    kind = AdaptiveGaitConfig if task == "adaptive_gait" else EnvConfig
    config = kind(model_path=FLAT, settle_steps=10, **({"costs": COSTS} | changes))
    return Core(config, n, seed=0, task=task)


@pytest.mark.parametrize("task", ["residual_walk", "adaptive_gait"])
def test_the_costs_are_declared_terms_weighted_by_minus_their_size(task):
    core = _core(task)
    assert [t.name for t in core.terms][-3:] == ["clearance", "slip", "power"]
    assert [t.weight for t in core.terms][-3:] == [-2.0, -3.0, -5.0]
    core.reset()
    for _ in range(12):
        result = core.step(torch.zeros(3, core.task.action_dim))
    sensors = core.obs.numpy()
    torque = core.sim.actuator_force
    for i in range(3):
        power = 0.0
        for j in range(12):  # left to right, as the term adds
            power = power + abs(torque[i, j] * sensors[i, OBS_JOINT_VEL.start + j])
        assert result.terms["power"][i].item() == -5.0 * power
    velocity = foot_velocities(core.obs)
    contact = core.obs[:, OBS_CONTACT] > 0.5
    assert torch.equal(result.terms["slip"], -3.0 * foot_slip(contact, velocity))
    assert torch.equal(result.reward, sum(result.terms.values(), torch.zeros(3, dtype=F64)))
    assert (result.terms["power"] < 0).all() and (result.terms["clearance"] <= 0).all()


def test_a_standing_robot_s_swing_feet_fall_short_by_the_target():
    """With a step height of 1 micrometre every foot stays on the ground: each mid-swing
    foot's bottom is at the ground (within the contact's millimetre), so each falls short
    by about the whole target."""
    gait = dataclasses.replace(GaitParameters(), step_height=1e-6)
    core = _core(gait=gait, n=1)
    core.reset()
    duty = gait.duty_factor
    seen = 0
    for _ in range(40):
        result = core.step(torch.zeros(1, 12))
        legs = core.controller.leg_phases(core.task.sensed_phase)[0]
        progress = (legs - duty) / (1 - duty)
        mid = int(((progress >= MID_SWING[0]) & (progress <= MID_SWING[1])).sum())
        shortfall = -result.terms["clearance"].item() / COSTS.clearance
        assert shortfall == pytest.approx(mid * COSTS.clearance_target, abs=mid * 0.002)
        seen += mid
    assert seen > 0


def test_a_standing_robot_falls_short_by_its_own_command_s_target():
    """As above, with commands and a target that grows with them: each env's mid-swing
    feet fall short by about max(0.01, 0.1 s x its v*)."""
    gait = dataclasses.replace(GaitParameters(), step_height=1e-6)
    costs = dataclasses.replace(COSTS, clearance_target_per_speed=0.1)
    core = _core(gait=gait, costs=costs, command_range=(0.05, 0.25))
    core.reset()
    target = torch.clamp(0.1 * core.task.v_target, min=0.01)
    assert bool((target > 0.01).any()) and bool((target == 0.01).any())  # both sides drawn
    duty = gait.duty_factor
    seen = 0
    for _ in range(40):
        result = core.step(torch.zeros(3, 12))
        progress = (core.controller.leg_phases(core.task.sensed_phase) - duty) / (1 - duty)
        mid = ((progress >= MID_SWING[0]) & (progress <= MID_SWING[1])).sum(dim=1)
        shortfall = -result.terms["clearance"] / COSTS.clearance
        torch.testing.assert_close(shortfall, mid * target, rtol=0.0, atol=0.002 * 4)
        seen += int(mid.sum())
    assert seen > 0


def test_each_env_s_power_is_priced_per_metre_above_the_speed_asked():
    """With commands of 0.05-0.25 m/s and the full price up to 0.1 m/s, each env's power
    term is -5 x its watts x 0.1 / max(0.1, its v*), summed by hand as the term adds."""
    costs = dataclasses.replace(COSTS, power_per_metre_above=0.1)
    core = _core(costs=costs, command_range=(0.05, 0.25))
    core.reset()
    v_target = core.task.v_target.tolist()
    assert min(v_target) < 0.1 < max(v_target)  # both prices drawn
    for _ in range(12):
        result = core.step(torch.zeros(3, 12))
    sensors = core.obs.numpy()
    torque = core.sim.actuator_force
    for i in range(3):
        power = 0.0
        for j in range(12):
            power = power + abs(torque[i, j] * sensors[i, OBS_JOINT_VEL.start + j])
        price = 0.1 / max(0.1, abs(v_target[i]))
        assert result.terms["power"][i].item() == -5.0 * (power * price)


def test_stumble_is_a_term_only_when_asked_and_counts_the_shuffling_feet():
    """Off (0), the costs declare no stumble term, so earlier runs keep their reward; on,
    a robot whose swing feet rise 1 micrometre touches the ground with every mid-swing
    foot."""
    assert "stumble" not in [t.name for t in _core().terms]
    gait = dataclasses.replace(GaitParameters(), step_height=1e-6)
    costs = dataclasses.replace(COSTS, stumble=7.0)
    core = _core(gait=gait, n=1, costs=costs)
    assert [(t.name, t.weight) for t in core.terms][-1] == ("stumble", -7.0)
    core.reset()
    duty, seen = gait.duty_factor, 0
    for _ in range(40):
        result = core.step(torch.zeros(1, 12))
        progress = (core.controller.leg_phases(core.task.sensed_phase)[0] - duty) / (1 - duty)
        mid = (progress >= MID_SWING[0]) & (progress <= MID_SWING[1])
        touching = (core.obs[0, OBS_CONTACT] > 0.5) & mid
        assert result.terms["stumble"].item() == -7.0 * int(touching.sum())
        seen += int(touching.sum())
    assert seen > 0


def test_the_sensed_phase_is_the_phase_of_the_reported_swing_flags():
    """The adaptive task's continuous phase, from the nominal gait with zero deltas, agrees
    with the residual task's table at the sensed substep."""
    residual, adaptive = _core(n=1), _core("adaptive_gait", n=1)
    residual.reset(), adaptive.reset()
    for _ in range(45):
        residual.step(torch.zeros(1, 12))
        adaptive.step(torch.zeros(1, 16))
        a, b = residual.task.sensed_phase, adaptive.task.sensed_phase
        assert abs(float(a - b)) < 1e-9 or abs(abs(float(a - b)) - 1.0) < 1e-9


def test_the_spec_s_envs_have_no_costs_and_training_adds_them_on_request():
    assert EnvConfig().costs is None and AdaptiveGaitConfig().costs is None
    assert TrainingEnv().config().costs is None
    assert TrainingEnv(costs=True).config().costs == GaitCosts()
    assert TrainingEnv(costs=True, clearance_weight=6000.0).config().costs == GaitCosts(
        clearance=6000.0
    )
    with pytest.raises(ValueError, match=r"--clearance-weight needs --costs"):
        TrainingEnv(clearance_weight=6000.0)
    with pytest.raises(ValueError, match=r"--clearance-weight: GaitCosts\.clearance .* got -1\.0"):
        TrainingEnv(costs=True, clearance_weight=-1.0)


# ------------------------------------------------------------------ the target action
def test_the_target_action_moves_each_parameter_toward_its_target_at_the_delta_rate():
    core = _core("adaptive_gait", n=3, gait_action="target")
    task = core.task
    core.reset()
    start = task.params.clone()
    assert torch.equal(start, task.centre.expand(3, 4))  # the default gait is the centre
    action = torch.zeros(3, 16, dtype=F64)
    action[0, :4] = 1.0  # every parameter toward its top
    action[1, :4] = 0.0  # hold the centre
    action[2, :4] = torch.tensor([0.5, -0.5, 0.01, -0.01])
    core.step(action)
    assert torch.equal(task.params[0], start[0] + task.delta)
    assert torch.equal(task.params[1], start[1])
    target = task.centre + action[2, :4] * task.half_width
    near = (target - start[2]).abs() <= task.delta
    expected = torch.where(near, target, start[2] + torch.sign(target - start[2]) * task.delta)
    assert torch.equal(task.params[2], expected)
    for _ in range(60):
        core.step(action)
    assert torch.equal(task.params[0], task.high)  # reached its top, and stays in range
    assert torch.equal(task.params[1], start[1])
    assert torch.allclose(task.params[2], target, rtol=0, atol=1e-15)


# ------------------------------------------------------------------ the schedule action
def test_speed_schedule_hand_computed_with_torch_and_numpy_alike():
    low, high = np.array([0.01, 0.04, 0.45, 0.05]), np.array([0.04, 0.16, 0.9, 0.09])
    start = np.array([0.025, 0.08, 0.6, 0.07])
    speed = np.array([0.05, 0.1, 0.25, 0.03])
    got = speed_schedule(speed, 0.06, low, high, start)
    # 0.05: cycle 0.06 / 0.05 = 1.2 -> 0.9 (its top), stride 0.05 x 0.9 = 0.045;
    # 0.1: 0.6 s and 0.06 m; 0.25: 0.24 s -> 0.45 (its floor), stride 0.1125;
    # 0.03: 2 s -> 0.9, stride 0.027 -> 0.04 (its floor). Heights: the start's.
    want = [[0.025, 0.045, 0.9, 0.07], [0.025, 0.06, 0.6, 0.07],
            [0.025, 0.1125, 0.45, 0.07], [0.025, 0.04, 0.9, 0.07]]  # fmt: skip
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
    as_torch = speed_schedule(torch.from_numpy(speed), 0.06,
                              *map(torch.from_numpy, (low, high, start)))  # fmt: skip
    assert np.array_equal(as_torch.numpy(), got)  # the runtime's bits are the env's


def test_a_schedule_s_step_rises_with_the_speed_within_its_range():
    low, high = np.array([0.01, 0.04, 0.45, 0.05]), np.array([0.04, 0.16, 0.9, 0.09])
    start = np.array([0.012, 0.08, 0.6, 0.07])
    speed = np.array([0.05, 0.125, 0.25, 1.0])
    got = speed_schedule(speed, 0.06, low, high, start, 0.04, 0.125)
    # 12 mm + (v - 0.125) x 40 mm per m/s: 0.05 -> 9 mm, below the 10 mm floor; 0.125 ->
    # 12 mm; 0.25 -> 17 mm; 1.0 -> 47 mm, above the 40 mm top. The rest as without a rise.
    np.testing.assert_allclose(got[:, 0], [0.01, 0.012, 0.017, 0.04], rtol=0, atol=1e-15)
    without = speed_schedule(speed, 0.06, low, high, start)
    assert np.array_equal(got[:, 1:], without[:, 1:]) and (without[:, 0] == 0.012).all()
    as_torch = speed_schedule(torch.from_numpy(speed), 0.06,
                              *map(torch.from_numpy, (low, high, start)), 0.04, 0.125)  # fmt: skip
    assert np.array_equal(as_torch.numpy(), got)


def test_the_schedule_action_moves_each_parameter_toward_the_speed_s_gait_and_a_window_of_it():
    core = _core("adaptive_gait", n=3, gait_action="schedule", command_range=(0.05, 0.25))
    task = core.task
    core.reset()
    scheduled = task.scheduled()
    want = speed_schedule(task.target.clone(), 0.06, task.low, task.high, task.start)
    assert torch.equal(scheduled, want)
    assert torch.equal(task.span, torch.tensor([1.0, 0.25, 0.25, 1.0], dtype=F64) * task.half_width)
    action = torch.zeros(3, 16, dtype=F64)
    action[1, :4] = 1.0  # every target a window above the schedule's
    action[2, :4] = torch.tensor([-1.0, -0.5, 0.5, 0.0])
    start = task.params.clone()
    core.step(action)
    step = torch.clamp(scheduled - start, -task.delta, task.delta)
    assert torch.equal(task.params[0], torch.clamp(start[0] + step[0], task.low, task.high))
    for _ in range(80):
        core.step(action)
    target = torch.minimum(torch.maximum(scheduled + action[:, :4] * task.span, task.low),
                           task.high)  # fmt: skip
    assert torch.allclose(task.params, target, rtol=0, atol=1e-15)
    assert task.params[1, 1] > scheduled[1, 1] and task.params[2, 2] > scheduled[2, 2]


def test_the_schedule_follows_a_new_command():
    core = _core("adaptive_gait", n=2, gait_action="schedule", command_range=(0.05, 0.25))
    core.reset()
    core.task.target[:] = torch.tensor([0.05, 0.2], dtype=F64)
    # 0.05 m/s: 1.2 s -> the 0.9 s top, 45 mm; 0.2 m/s: 0.3 s, 60 mm (the contract's ranges)
    want = torch.tensor([[0.025, 0.045, 0.9, 0.07], [0.025, 0.06, 0.3, 0.07]], dtype=F64)
    assert torch.allclose(core.task.scheduled(), want, rtol=0, atol=1e-15)
    risen = _core("adaptive_gait", n=2, gait_action="schedule", command_range=(0.05, 0.25),
                  schedule_step_rise=0.05)  # fmt: skip
    risen.reset()
    risen.task.target[:] = torch.tensor([0.05, 0.2], dtype=F64)
    # from the trot's 25 mm at its 0.08 / 0.6 m/s, 50 mm per m/s: 0.05 -> 25 - 4.17 mm,
    # 0.2 -> 25 + 3.33 mm
    want[:, 0] = torch.tensor([0.025 - 0.25 / 60, 0.025 + 0.2 / 60], dtype=F64)
    assert torch.allclose(risen.task.scheduled(), want, rtol=0, atol=1e-15)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"schedule_stride": 0.0}, r"schedule_stride must be metres in \(0, 0\.16\], got 0\.0"),
        ({"schedule_stride": math.nan}, r"schedule_stride .*, got nan"),
        ({"schedule_stride": 0.2}, r"schedule_stride .* got 0\.2"),
        ({"schedule_window": (1.0, 0.5, 0.5)}, r"schedule_window must be 4 fractions"),
        ({"schedule_window": (1.0, 1.5, 0.5, 0.0)}, r"schedule_window .* got \(1\.0, 1\.5"),
        ({"schedule_window": (1.0, math.nan, 0.5, 0.0)}, r"schedule_window .* nan"),
        ({"schedule_step_rise": -0.01}, r"schedule_step_rise .* per m/s in \[0, 1\], got -0\.01"),
        ({"schedule_step_rise": math.inf}, r"schedule_step_rise .* got inf"),
        ({"schedule_step_rise": math.nan}, r"schedule_step_rise .* got nan"),
        (
            {"gait_action": "schedule", "command_range": (-0.1, 0.2)},
            r"gait_action 'schedule' needs forward target velocities .* asks for -0\.1",
        ),
        ({"gait_action": "schedule", "command_range": (0.0, 0.2)}, r"gait_action .* asks for 0\.0"),
    ],
)
def test_bad_schedules_are_refused_naming_the_field_and_value(changes, message):
    with pytest.raises(ValueError, match=rf"\w*Config\.{message}"):  # NaN: EnvConfig's check
        AdaptiveGaitConfig(**changes)


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"clearance": -1.0}, "clearance"),
        ({"slip": -0.5}, "slip"),
        ({"stumble": -2.0}, "stumble"),
        ({"stumble": math.nan}, "stumble"),
        ({"power": -1e-9}, "power"),
        ({"power": math.nan}, "power"),
        ({"slip": math.inf}, "slip"),
        ({"clearance": "1"}, "clearance"),
        ({"clearance_target": -0.01}, "clearance_target"),
        ({"clearance_target": 0.0}, "clearance_target"),
        ({"clearance_target": 0.2}, "clearance_target"),
        ({"clearance_target": math.nan}, "clearance_target"),
        ({"power_per_metre_above": -0.1}, "power_per_metre_above"),
        ({"power_per_metre_above": math.nan}, "power_per_metre_above"),
        ({"clearance_target_per_speed": -0.1}, "clearance_target_per_speed"),
        ({"clearance_target_per_speed": math.inf}, "clearance_target_per_speed"),
    ],
)
def test_bad_costs_are_refused_naming_the_field(changes, field):
    with pytest.raises(ValueError, match=rf"GaitCosts\.{field}\b"):
        GaitCosts(**changes)


def test_a_clearance_target_beyond_the_model_s_legs_is_refused():
    from rwalk.kinematics import LegGeometry

    short = LegGeometry(thigh_length=0.01, shin_length=0.01)
    with pytest.raises(ValueError, match=r"clearance_target.*0\.02 m"):
        GaitCosts(clearance_target=0.05).check_reach(short)


def test_a_target_that_grows_beyond_the_legs_at_the_fastest_command_is_refused():
    costs = GaitCosts(clearance_target_per_speed=0.5)  # legs reach 0.11 m
    with pytest.raises(ValueError, match=r"clearance_target_per_speed 0\.5 s asks 0\.125 m"):
        _core(costs=costs, command_range=(0.05, 0.25))  # 0.125 m at 0.25 m/s
    assert _core(costs=costs).config.top_speed == pytest.approx(0.08 / 0.6)  # 0.067 m: fits
    with pytest.raises(ValueError, match=r"clearance_target_per_speed"):
        _core(costs=COSTS, command_range=(0.05, 0.25)).set_reward(costs=costs)


def test_costs_of_another_kind_and_unknown_gait_actions_are_refused():
    with pytest.raises(TypeError, match=r"EnvConfig\.costs must be a GaitCosts"):
        EnvConfig(costs={"clearance": 1.0})
    with pytest.raises(ValueError, match=r"AdaptiveGaitConfig\.gait_action.*'absolute'"):
        AdaptiveGaitConfig(gait_action="absolute")
    with pytest.raises(ValueError, match=r"--gait-action.*'absolute'"):
        TrainingEnv(gait_action="absolute")


def test_the_clearance_target_s_growth_with_speed_is_a_flag_and_a_late_value():
    from rwalk.rl.config import late_reward
    from rwalk.runners import train

    training = train.parse_args(["--task", "adaptive_gait", "--costs",
                                 "--env.costs.clearance-target-per-speed", "0.05",
                                 "--late-iterations", "5",
                                 "--late-clearance-target-per-speed", "0.1"])  # fmt: skip
    assert training.env.costs.clearance_target_per_speed == 0.05
    late = late_reward(training.train, training.env)["costs"]
    assert late == dataclasses.replace(training.env.costs, clearance_target_per_speed=0.1)
