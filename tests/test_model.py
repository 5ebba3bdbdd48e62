import shutil

import mujoco
import numpy as np
import pytest

from rwalk.assets import load_model, resolve_model_path
from rwalk.constants import (
    FOOT_GEOMS,
    GROUND_GEOM,
    JOINT_NAMES,
    MODEL_DIR,
    OBS_CONTACT,
    OBS_DIM,
    TORSO_BODY,
)
from rwalk.terrain import TERRAIN_SEED, Terrain, generate_heightmap, quantize


def test_robot_matches_the_design(flat_model):
    m = flat_model
    assert sum(m.body_mass) == pytest.approx(0.8, abs=0.01)
    assert m.nu == 12 and m.nsensordata == OBS_DIM
    hips = np.array([m.body(f"{leg}_hip_link").pos for leg in ("FL", "FR", "RL", "RR")])
    assert hips[0, 0] - hips[2, 0] == pytest.approx(0.15)
    assert hips[0, 1] - hips[1, 1] == pytest.approx(0.08)
    assert m.opt.timestep == 0.004 and m.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    for name in JOINT_NAMES:
        actuator = m.actuator(name)
        assert actuator.forcerange[1] == pytest.approx(0.3)  # hobby-servo stall torque
        assert m.joint(name).armature[0] > 0 and m.joint(name).limited[0]


def test_only_feet_and_torso_touch_the_ground(flat_model):
    m = flat_model
    ground = m.geom(GROUND_GEOM)
    touching = set()
    for i in range(m.ngeom):
        if i == ground.id:
            continue
        collide = (m.geom_contype[i] & ground.conaffinity[0]) or (
            ground.contype[0] & m.geom_conaffinity[i]
        )
        if collide:
            touching.add((m.geom(i).name, m.body(m.geom_bodyid[i]).name))
        # robot geoms never collide with each other
        assert not (m.geom_contype[i] & m.geom_conaffinity[i])
    assert {name for name, _ in touching} == {*FOOT_GEOMS, "torso_collision"}


def test_stand_keyframe_is_stable(flat_model):
    m = flat_model
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("stand").id)
    for _ in range(1000):  # 4 s at 4 ms
        mujoco.mj_step(m, d)
    assert d.qpos[2] == pytest.approx(0.075, abs=0.003)
    assert abs(d.qpos[4]) < 1e-3 and abs(d.qpos[5]) < 1e-3
    np.testing.assert_array_equal(d.sensordata[OBS_CONTACT], [1, 1, 1, 1])


def test_contact_sensor_reports_only_ground_contact(flat_model):
    m = flat_model
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("stand").id)
    d.qpos[2] += 0.05  # lifted: no foot touches anything
    mujoco.mj_forward(m, d)
    np.testing.assert_array_equal(d.sensordata[OBS_CONTACT], [0, 0, 0, 0])


def test_missing_model_file_names_the_path(tmp_path):
    missing = tmp_path / "nowhere" / "robot_world.xml"
    with pytest.raises(FileNotFoundError, match=r"robot_world\.xml"):
        load_model(missing)


def test_model_lacking_parts_lists_them(tmp_path):
    for name in ("robot.xml", "world_flat.xml"):
        shutil.copy(MODEL_DIR / name, tmp_path / name)
    robot = (tmp_path / "robot.xml").read_text()
    robot = robot.replace(
        '<contact name="RL_contact" geom1="RL_foot" body2="world" data="found" num="1"/>', ""
    )
    robot = robot.replace('<position name="FR_knee"', '<position name="FR_knee_servo"')
    (tmp_path / "robot.xml").write_text(robot)
    with pytest.raises(ValueError) as info:
        load_model(tmp_path / "world_flat.xml")
    assert "actuator 'FR_knee'" in str(info.value) and "sensor 'RL_contact'" in str(info.value)


def test_packaged_models_resolve_from_any_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve_model_path("model/world_train.xml") == (MODEL_DIR / "world_train.xml").resolve()
    assert resolve_model_path("world_flat.xml") == (MODEL_DIR / "world_flat.xml").resolve()


def test_committed_terrain_is_the_seeded_generator_output(train_model):
    m = train_model
    terrain = Terrain(m)
    expected = quantize(generate_heightmap(TERRAIN_SEED)) / 255.0
    np.testing.assert_allclose(terrain.base, expected, atol=1e-6)
    # Mean ground height sits at z = 0.
    assert terrain.origin[2] + terrain.size[2] * terrain.base.mean() == pytest.approx(0, abs=1e-3)


def test_terrain_is_reproducible_per_seed():
    a, b, c = generate_heightmap(1), generate_heightmap(1), generate_heightmap(2)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0.1
    assert a.min() == 0.0 and a.max() == 1.0


def test_terrain_scale_really_scales_the_roughness():
    m = load_model("model/world_train.xml")
    terrain = Terrain(m)
    base_std = terrain.base.std()
    terrain.set_scale(m, 0.5)
    assert m.hfield_data.std() == pytest.approx(0.5 * base_std, rel=1e-5)
    terrain.set_scale(m, 0.0)
    assert np.ptp(m.hfield_data) < 1e-6
    with pytest.raises(ValueError, match=r"1\.5"):
        terrain.set_scale(m, 1.5)


def test_max_height_bounds_the_ground_under_a_square(train_model):
    terrain = Terrain(train_model)
    rows, cols = terrain.base.shape
    sx, sy, sz = terrain.size[:3]
    xc = -sx + 2 * sx * np.arange(cols) / (cols - 1) + terrain.origin[0]
    yc = -sy + 2 * sy * np.arange(rows) / (rows - 1) + terrain.origin[1]
    cell = 2 * sx / (cols - 1)
    heights = terrain.origin[2] + sz * terrain.heights
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-4.5, 4.5, 50), rng.uniform(-1.8, 1.8, 50)
    got = terrain.max_height(x, y, 0.1)
    for i in range(50):

        def brute(reach, i=i):
            cols_in = np.abs(xc - x[i]) <= reach
            rows_in = np.abs(yc - y[i]) <= reach
            return heights[np.ix_(rows_in, cols_in)].max()

        assert brute(0.1) <= got[i] <= brute(0.1 + 2 * cell)
    flat = Terrain(load_model("model/world_flat.xml"))
    assert flat.max_height(np.array([1.0]), np.array([2.0]), 0.1)[0] == 0.0


def test_world_train_places_torso_in_worldbody(train_model):
    assert train_model.body(TORSO_BODY).parentid[0] == 0
