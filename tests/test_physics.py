"""Physics overrides, the control rate, and the fidelity harness (issue: physics budget)."""

import dataclasses
import json
import math
import shutil

import mujoco
import numpy as np
import pytest

from rwalk import fidelity
from rwalk.analysis import walk
from rwalk.assets import load_model
from rwalk.config import EnvConfig
from rwalk.constants import MODEL_DIR
from rwalk.core import ResidualWalkCore
from rwalk.physics import Physics, describe
from rwalk.presets import base_gait_config
from rwalk.runners import fidelity as fidelity_runner

QUICK = EnvConfig(model_path="model/world_flat.xml", settle_steps=0, max_episode_steps=5)


def test_the_default_physics_is_4_ms_with_5_substeps_at_50_hz():
    core = ResidualWalkCore(QUICK, 1, seed=0)
    assert (core.dt, core.decimation, core.control_dt) == (0.004, 5, 0.02)
    assert core.controller.period == 150  # 0.6 s cycle / 4 ms


def test_overrides_reach_the_compiled_model():
    physics = Physics(
        timestep=0.0025,
        integrator="Euler",
        solver="CG",
        iterations=7,
        ls_iterations=3,
        tolerance=0.0,
        cone="pyramidal",
        foot_condim=3,
        foot_solref=(0.01, 0.5),
    )
    model = load_model("model/world_flat.xml")
    physics.apply(model)
    assert describe(model) == {
        "timestep": 0.0025,
        "integrator": "Euler",
        "solver": "CG",
        "iterations": 7,
        "ls_iterations": 3,
        "tolerance": 0.0,
        "cone": "pyramidal",
        "foot_condim": 3,
        "foot_solref": (0.01, 0.5),
    }
    untouched = load_model("model/world_flat.xml")
    Physics().apply(untouched)
    assert describe(untouched) == describe(load_model("model/world_flat.xml"))


def test_a_core_on_other_physics_keeps_the_control_rate():
    core = ResidualWalkCore(dataclasses.replace(QUICK, physics=Physics(timestep=0.0005)), 2)
    assert (core.decimation, core.control_dt) == (40, 0.02)
    core.reset()
    result = core.step(np.zeros((2, 12)))
    assert core.physics_steps["step"] == 2 * 40
    assert not result.terminated.any()


@pytest.mark.parametrize(
    ("physics", "message"),
    [
        (dict(timestep=0.0), r"Physics.timestep must be a finite number > 0, got 0.0"),
        (dict(timestep=-0.004), r"Physics.timestep .* got -0.004"),
        (dict(timestep=math.nan), r"Physics.timestep .* got nan"),
        (dict(solver="newton"), r"Physics.solver must be one of \['CG', 'Newton', 'PGS'\]"),
        (dict(cone="round"), r"Physics.cone must be one of"),
        (dict(integrator="RK5"), r"Physics.integrator must be one of"),
        (dict(iterations=0), r"Physics.iterations must be an integer >= 1, got 0"),
        (dict(ls_iterations=2.5), r"Physics.ls_iterations must be an integer >= 1, got 2.5"),
        (dict(tolerance=-1e-8), r"Physics.tolerance must be a finite number >= 0"),
        (dict(foot_condim=2), r"Physics.foot_condim must be one of \(1, 3, 4, 6\), got 2"),
        (dict(foot_solref=(0.0, 1.0)), r"Physics.foot_solref must be a pair of positive"),
        (dict(foot_solref=(0.01,)), r"Physics.foot_solref must be a pair of positive"),
    ],
)
def test_bad_physics_settings_are_named(physics, message):
    with pytest.raises(ValueError, match=message):
        Physics(**physics)


def test_substeps_follow_the_control_rate():
    config = EnvConfig()
    assert config.substeps(0.004) == 5
    assert config.substeps(0.002) == 10
    assert config.substeps(0.0005) == 40
    assert EnvConfig(control_dt=None, decimation=3).substeps(0.004) == 3
    assert EnvConfig(decimation=5).substeps(0.004) == 5


@pytest.mark.parametrize(
    ("config", "timestep", "message"),
    [
        (EnvConfig(), 0.003, r"timestep 0.003 s does not divide EnvConfig.control_dt=0.02 s"),
        (EnvConfig(), 0.03, r"timestep 0.03 s does not divide EnvConfig.control_dt=0.02 s"),
        (EnvConfig(decimation=10), 0.004, r"EnvConfig.decimation=10 x timestep 0.004 s = 0.04 s "
         r"misses control_dt=0.02 s: use decimation=5"),
        (EnvConfig(), 0.0, r"timestep must be > 0 seconds, got 0.0"),
        (EnvConfig(), -0.002, r"timestep must be > 0 seconds, got -0.002"),
    ],
)  # fmt: skip
def test_a_timestep_that_misses_the_control_rate_is_named(config, timestep, message):
    with pytest.raises(ValueError, match=message):
        config.substeps(timestep)


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        (dict(control_dt=None, decimation=None), r"needs control_dt or decimation"),
        (dict(control_dt=0.0), r"EnvConfig.control_dt must be a number of seconds > 0, got 0.0"),
        (dict(control_dt=math.inf), r"EnvConfig.control_dt must be finite"),
        (dict(physics="fast"), r"EnvConfig.physics must be a Physics, got str"),
    ],
)
def test_bad_control_settings_are_named(fields, message):
    with pytest.raises((ValueError, TypeError), match=message):
        EnvConfig(**fields)


def test_a_world_whose_timestep_misses_the_control_rate_is_refused(tmp_path):
    robot = (MODEL_DIR / "robot.xml").read_text()
    assert 'timestep="0.004"' in robot
    shutil.copy(MODEL_DIR / "world_flat.xml", tmp_path / "world_flat.xml")
    (tmp_path / "robot.xml").write_text(robot.replace('timestep="0.004"', 'timestep="0.003"'))
    config = dataclasses.replace(QUICK, model_path=str(tmp_path / "world_flat.xml"))
    with pytest.raises(ValueError, match=r"timestep 0.003 s does not divide .*control_dt=0.02"):
        ResidualWalkCore(config, 1)
    # The same world at a control period it divides is fine.
    core = ResidualWalkCore(dataclasses.replace(config, control_dt=0.021), 1)
    assert core.decimation == 7


def test_walk_measures_foot_tracking_contacts_and_torque():
    core = ResidualWalkCore(base_gait_config("model/world_flat.xml"), 2, seed=0)
    report = walk(core, steps=100)
    # The servos follow the gait to a few millimetres, feet touch down on schedule
    # most of the time, and torques stay inside the 0.3 N·m stall limit.
    assert (report.foot_error > 0).all() and (report.foot_error < 0.01).all()
    assert (report.contact_match > 0.6).all() and (report.contact_match <= 1).all()
    assert (report.torque > 0.01).all() and (report.torque < 0.3).all()


def test_faithful_divides_each_difference_by_the_noise_band():
    reference = {name: (1.0, 0.0) for name in fidelity.METRICS}
    reference["speed_ratio"] = (0.9, 0.01)  # band 1.96·√2·0.01 = 0.0277
    row = dict(reference)
    row["speed_ratio"] = (0.9277186, 0.02)
    row["torque"] = (1.004, 0.0)  # band = resolution 0.002
    deviation = fidelity.faithful(row, reference)
    assert deviation["speed_ratio"] == pytest.approx(1.0, abs=1e-5)
    assert deviation["torque"] == pytest.approx(2.0)
    assert deviation["fall_rate"] == 0.0


def test_the_harness_writes_its_table_and_refuses_unknown_candidates(tmp_path, capsys):
    out = tmp_path / "f.json"
    fidelity_runner.fidelity(
        ["--robots", "2", "--seconds", "0.1", "--only", "4ms", "--worlds", "flat",
         "--cost-envs", "2", "--cost-rounds", "1", "--cost-window", "0.01", "--json", str(out)]
    )  # fmt: skip
    saved = json.loads(out.read_text())
    rows = saved["cases"]["flat"]
    assert set(rows) == {"reference", "4ms", f"reference (seed {fidelity.SECOND_SEED})"}
    assert set(rows["4ms"]["deviation"]) == set(fidelity.METRICS)
    assert saved["cost"]["4ms"] > 0 and saved["cost"]["reference"] > 0
    assert "| flat | 4ms |" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        fidelity_runner.parse_args(["--only", "4ms,warp"])
    assert "unknown candidate(s) ['warp']" in capsys.readouterr().err


def test_every_candidate_keeps_50_hz_and_sets_every_field():
    model = load_model("model/world_flat.xml")
    for name, physics in fidelity.CANDIDATES.items():
        assert None not in dataclasses.astuple(physics), name
        assert EnvConfig().substeps(physics.timestep) * physics.timestep == pytest.approx(0.02)
        physics.apply(model)
        assert model.opt.timestep == physics.timestep
    assert mujoco.mjtCone(model.opt.cone).name  # still a valid model


def test_the_standing_robot_is_at_rest_at_4_ms(flat_model):
    m = flat_model
    m_energy = mujoco.MjModel.from_xml_path(str(MODEL_DIR / "world_flat.xml"))
    m_energy.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    d = mujoco.MjData(m_energy)
    mujoco.mj_resetDataKeyframe(m_energy, d, m.key("stand").id)
    heights, kinetic = [], []
    for _ in range(2500):  # 10 s
        mujoco.mj_step(m_energy, d)
        heights.append(d.qpos[2])
        kinetic.append(d.energy[1])
    late = np.array(heights[-500:])
    assert np.ptp(late) < 1e-4  # keeps its height to 0.1 mm over the last 2 s
    assert max(kinetic[-500:]) < 1e-7  # at rest: no energy pumped in by the 4 ms step
    assert not d.warning.number.any()


def test_a_decimation_with_a_timestep_that_misses_the_rate_names_the_timestep():
    with pytest.raises(ValueError, match=r"timestep 0.003 s does not divide"):
        EnvConfig(decimation=10).substeps(0.003)


@pytest.mark.parametrize("flag", ["--robots", "--seconds", "--cost-rounds", "--cost-window"])
def test_the_harness_refuses_a_non_positive_count_naming_it(flag, capsys):
    with pytest.raises(SystemExit) as exit_info:
        fidelity_runner.parse_args([flag, "0"])
    err = capsys.readouterr().err.strip()
    assert exit_info.value.code == 2 and "\n" not in err
    assert f"error: {flag} must be " in err and (">= 1" in err or "> 0" in err)
    assert err.endswith(("got 0", "got 0.0"))
