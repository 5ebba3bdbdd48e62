"""Bad input gets a clear error naming the bad value; nothing fails silently or late."""

import dataclasses
import logging
import shutil

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from rwalk import EnvConfig, GaitParameters, ResidualWalkCore, ResidualWalkVecEnv, RewardWeights
from rwalk.assets import MODEL_DIR, resolve_model_path, validate_model

QUICK = EnvConfig(settle_steps=2)
FLAT = dataclasses.replace(QUICK, model_path="model/world_flat.xml")


# -- reset masks and ids -------------------------------------------------------------------------
@pytest.mark.parametrize(
    "mask",
    [
        torch.tensor([[0], [0]]),  # int: read as "env 0" before
        torch.tensor([[1.0], [0.0]]),  # float: reset, then crashed
        torch.tensor([[True, False], [False, False]]),  # wrong shape
    ],
)
def test_torchrl_reset_masks_must_be_boolean_of_the_batch_shape(mask):
    env = ResidualWalkVecEnv(2, QUICK, seed=0)
    env.reset()
    before = env.core.resets
    with pytest.raises(ValueError, match='"_reset" must be a boolean mask of shape'):
        env.reset(TensorDict({"_reset": mask}, batch_size=[2]))
    assert env.core.resets == before  # nothing was reset


def test_boolean_masks_of_shape_n_and_n1_reset_what_they_mark():
    env = ResidualWalkVecEnv(3, QUICK, seed=0)
    env.reset()
    for mask in (torch.tensor([True, False, True]), torch.tensor([[False], [True], [False]])):
        before = env.core.resets
        env.reset(TensorDict({"_reset": mask}, batch_size=[3]))
        assert env.core.resets - before == int(mask.sum())


@pytest.mark.parametrize(
    ("ids", "message"),
    [
        (np.array([True, False]), r"boolean env mask must have shape \(3,\), got \(2,\)"),
        (np.array([1.5]), r"env ids must be integers or a boolean mask, got dtype float64"),
        (np.array([1.0]), r"env ids must be integers or a boolean mask, got dtype float64"),
        (np.array([2, 1]), r"sorted and unique"),
        (np.array([3]), r"in \[0, 3\)"),
    ],
)
def test_core_reset_rejects_bad_ids(ids, message):
    core = ResidualWalkCore(QUICK, 3, seed=0)
    with pytest.raises(ValueError, match=message):
        core.reset(ids)


# -- configuration -------------------------------------------------------------------------------
@pytest.mark.parametrize("field", ["velocity_tracking", "stability", "contact_mismatch"])
@pytest.mark.parametrize("value", [float("nan"), float("inf"), "1", True])
def test_reward_weights_must_be_finite_numbers(field, value):
    with pytest.raises(ValueError, match=f"RewardWeights.{field} must be a finite number"):
        RewardWeights(**{field: value})


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"start_position": (float("nan"), 0.0)}, "EnvConfig.start_position must be a pair"),
        ({"start_position": (0.0, float("inf"))}, "EnvConfig.start_position must be a pair"),
        ({"position_noise": (float("inf"), 0.0)}, "EnvConfig.position_noise must be a pair"),
        ({"position_noise": (0.1,)}, "EnvConfig.position_noise must be a pair"),
        ({"decimation": 10**6}, r"EnvConfig.decimation must be <= 1000"),
    ],
)
def test_env_config_rejects_values_that_failed_late(changes, message):
    with pytest.raises(ValueError, match=message):
        EnvConfig(**changes)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"gait": {"step_height": 0.02}}, "EnvConfig.gait must be a GaitParameters, got dict"),
        ({"reward_weights": None}, "EnvConfig.reward_weights must be a RewardWeights"),
    ],
)
def test_env_config_checks_the_types_of_its_parts(changes, message):
    with pytest.raises(TypeError, match=message):
        EnvConfig(**changes)


def test_num_envs_must_be_a_positive_integer_not_a_bool():
    for bad in (True, 0, 2.0):
        with pytest.raises(ValueError, match=f"num_envs must be a positive integer, got {bad}"):
            ResidualWalkCore(QUICK, bad)


def test_a_gait_cycle_shorter_than_two_control_steps_is_refused():
    gait = GaitParameters(cycle_time=0.02, step_height=0.02)
    with pytest.raises(ValueError, match=r"cycle_time \(0.02 s\) must span at least 2 control"):
        ResidualWalkCore(dataclasses.replace(QUICK, gait=gait), 1)


def test_too_many_envs_fail_at_once_with_the_memory_figure():
    with pytest.raises(MemoryError, match=r"num_envs=10000000 needs about \d+\.\d GiB"):
        ResidualWalkCore(QUICK, 10**7)


def test_a_non_positive_timestep_is_named(tmp_path):
    robot = (MODEL_DIR / "robot.xml").read_text()
    assert 'timestep="0.004"' in robot
    shutil.copy(MODEL_DIR / "world_flat.xml", tmp_path / "world_flat.xml")
    (tmp_path / "robot.xml").write_text(robot.replace('timestep="0.004"', 'timestep="0"'))
    config = dataclasses.replace(QUICK, model_path=str(tmp_path / "world_flat.xml"))
    with pytest.raises(ValueError, match=r"timestep must be > 0, got 0\.0"):
        ResidualWalkCore(config, 1)


# -- model files ---------------------------------------------------------------------------------
def test_a_mistyped_folder_never_falls_back_to_a_packaged_model(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(FileNotFoundError, match=r"experiments/typo/world_train\.xml"):
        resolve_model_path("experiments/typo/world_train.xml")
    for exact in ("model/world_train.xml", "world_flat.xml"):
        assert resolve_model_path(exact).parent == MODEL_DIR.resolve()


def test_a_world_without_the_ground_geom_fails_validation(train_model):
    import mujoco

    spec = mujoco.MjSpec.from_file(str(MODEL_DIR / "world_flat.xml"))
    spec.geom("ground").name = "floor"
    with pytest.raises(ValueError, match="lacks required elements: geom 'ground'"):
        validate_model(spec.compile(), source="no_ground.xml")


# -- resets that cannot settle -------------------------------------------------------------------
def test_starts_that_keep_falling_raise_instead_of_being_handed_back():
    config = dataclasses.replace(QUICK, settle_steps=20, randomize=True, tilt_noise=2.0)
    core = ResidualWalkCore(config, 16, seed=0)
    with pytest.raises(RuntimeError, match=r"starts fell or diverged .* tilt_noise=2.0"):
        core.reset()


# -- actions -------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("action", "message"),
    [
        (torch.zeros(2, 12, requires_grad=True), "action requires grad: pass action.detach()"),
        (torch.zeros(2, 12, device="meta"), "action must be on the CPU, got device meta"),
        (torch.zeros(2, 12, dtype=torch.bfloat16), "action must be float32 or float64"),
        (torch.zeros(2, 12, dtype=torch.float16), "action must be float32 or float64"),
    ],
)
def test_actions_torch_cannot_hand_to_numpy_are_named(action, message):
    core = ResidualWalkCore(QUICK, 2, seed=0)
    core.reset()
    with pytest.raises(ValueError, match=message):
        core.step(action)


# -- terrain -------------------------------------------------------------------------------------
def test_set_terrain_scale_on_a_plane_is_an_error_and_the_scale_is_honest():
    core = ResidualWalkCore(FLAT, 1, seed=0)
    assert core.terrain.scale == 0.0  # a plane is flat, whatever the config said
    with pytest.raises(ValueError, match=r"world_flat\.xml: the ground is a plane"):
        core.set_terrain_scale(0.5)


# -- MuJoCo's warnings ---------------------------------------------------------------------------
def test_mujoco_warnings_go_to_logging_not_to_a_file(tmp_path, monkeypatch, caplog):
    monkeypatch.chdir(tmp_path)
    core = ResidualWalkCore(QUICK, 2, seed=0)
    core.reset()
    core.sim.qvel[1, :] = 1e12
    with caplog.at_level(logging.WARNING, logger="rwalk.mujoco"):
        result = core.step(torch.zeros(2, 12))
    assert result.diverged.tolist() == [False, True]
    assert any("QACC" in r.getMessage() or "QVEL" in r.getMessage() for r in caplog.records)
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()
