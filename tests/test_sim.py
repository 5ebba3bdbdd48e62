import numpy as np
import pytest
import torch

from rwalk.gait import BezierGaitController
from rwalk.sim import BatchedSim


def _standing_sim(model, n, threads):
    sim = BatchedSim(model, n, threads)
    sim.reset()
    controller = BezierGaitController(dt=model.opt.timestep)
    stand = controller.joint_targets(torch.zeros(1, dtype=torch.long), 1)[0][0, 0].numpy()
    sim.qpos[:, 0] = -3.5
    sim.qpos[:, 1] = np.linspace(-1, 1, n)
    sim.qpos[:, 2] = 0.12
    sim.qpos[:, 7:] = stand
    return sim, controller


def _gait_ctrl(controller, n, substeps, start=0):
    tick = torch.full((n,), start, dtype=torch.long)
    return np.ascontiguousarray(controller.joint_targets(tick, substeps)[0].numpy())


def test_results_do_not_depend_on_the_thread_count(train_model):
    finals = []
    for threads in (1, 2):
        sim, controller = _standing_sim(train_model, 5, threads)
        for k in range(10):
            sim.rollout(_gait_ctrl(controller, 5, 10, start=k * 10))
        finals.append(sim.state.copy())
    np.testing.assert_array_equal(finals[0], finals[1])


def test_warmstart_is_carried_between_calls(train_model):
    # With the warmstart in the state rows, two calls of K substeps continue
    # exactly like one call of 2K (plain mujoco.rollout would restart it at zero).
    one, controller = _standing_sim(train_model, 3, 1)
    two, _ = _standing_sim(train_model, 3, 1)
    ctrl = _gait_ctrl(controller, 3, 40)
    one.rollout(ctrl)
    two.rollout(np.ascontiguousarray(ctrl[:, :20]))
    two.rollout(np.ascontiguousarray(ctrl[:, 20:]))
    np.testing.assert_array_equal(one.state, two.state)
    np.testing.assert_array_equal(one.sensordata, two.sensordata)


def test_rollout_of_some_rows_leaves_the_others(train_model):
    sim, controller = _standing_sim(train_model, 4, 2)
    before = sim.state.copy()
    ids = np.array([1, 3], dtype=np.int32)
    sim.rollout(_gait_ctrl(controller, 2, 10), ids)
    np.testing.assert_array_equal(sim.state[[0, 2]], before[[0, 2]])
    assert not np.array_equal(sim.state[[1, 3]], before[[1, 3]])


def test_a_diverging_row_is_flagged_and_the_rest_run_on(train_model, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs the divergence to ./MUJOCO_LOG.TXT
    reference, controller = _standing_sim(train_model, 3, 2)
    sim, _ = _standing_sim(train_model, 3, 2)
    sim.qvel[1, :] = 1e12
    ctrl = _gait_ctrl(controller, 3, 10)
    reference.rollout(ctrl)
    diverged = sim.rollout(ctrl)
    np.testing.assert_array_equal(diverged, [False, True, False])
    np.testing.assert_array_equal(sim.state[[0, 2]], reference.state[[0, 2]])
    assert np.isfinite(sim.state).all()
    # After a reset the row runs normally again.
    sim.reset(np.array([1], dtype=np.int32))
    sim.qpos[1, 2] = 0.12
    assert not sim.rollout(ctrl).any()


def test_bad_arguments_are_refused(train_model):
    with pytest.raises(ValueError, match="num_sims"):
        BatchedSim(train_model, 0)
    with pytest.raises(ValueError, match="num_threads"):
        BatchedSim(train_model, 2, -1)
