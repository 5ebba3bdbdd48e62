import dataclasses

import numpy as np
import pytest
import torch

from rwalk import EnvConfig, ResidualWalkCore
from rwalk.constants import OBS_POS

QUICK = dataclasses.replace(EnvConfig(), settle_steps=10, randomize=True)


def test_step_before_reset_is_refused():
    core = ResidualWalkCore(QUICK, 2, seed=0)
    with pytest.raises(RuntimeError, match="reset"):
        core.step(torch.zeros(2, 12))


def test_stepping_in_inference_mode_then_resetting_outside_works():
    core = ResidualWalkCore(QUICK, 2, seed=0)
    core.reset()
    with torch.inference_mode():
        core.step(torch.zeros(2, 12))
    core.reset(np.array([1]))
    core.step(torch.zeros(2, 12))
    assert core.episode_step.tolist() == [2, 1]


def test_physics_steps_are_counted():
    core = ResidualWalkCore(QUICK, 3, seed=0)
    k = core.decimation  # 5 substeps of 4 ms per env step
    assert k == 5 and QUICK.settle_steps == 10
    core.reset()
    assert core.physics_steps == {"step": 0, "settle": 3 * 10 * k}
    core.step(torch.zeros(3, 12))
    core.reset(np.array([1]))
    assert core.physics_steps == {"step": 3 * k, "settle": 4 * 10 * k}
    assert core.resets == 4
    assert core.settle_share == pytest.approx(200 / 215)


def test_pooled_resets_return_settled_starts_and_refill_in_one_batch():
    config = dataclasses.replace(QUICK, settle_pool=4, settle_reuse=2)
    core = ResidualWalkCore(config, 3, seed=0)
    core.reset()
    settled_before = core.physics_steps["settle"]
    core.reset(np.array([0, 2]))
    # The empty pool was filled once: 4 starts x 10 env steps x 5 substeps.
    assert core.physics_steps["settle"] - settled_before == 4 * 10 * core.decimation
    pool = core.starts.pool
    assert pool.uses_left.tolist() == [1, 1, 2, 2]
    np.testing.assert_array_equal(core.sim.state[[0, 2]], pool.sim.state[[0, 1]])
    assert core.episode_step[[0, 2]].tolist() == [0, 0]
    assert core.tick[0].item() == 10 * core.decimation % core.controller.period
    torch.testing.assert_close(core.y0[[0, 2]], core.obs[[0, 2], OBS_POS.start + 1])
    # Round robin: the next reset uses entry 2, the one after entries 3 and 0.
    core.reset(np.array([1]))
    core.reset(np.array([0, 2]))
    assert pool.uses_left.tolist() == [0, 1, 1, 1]
    assert core.physics_steps["settle"] - settled_before == 4 * 10 * core.decimation  # no refill
    # Each entry is its own settle from its own random start.
    assert len({tuple(np.round(pool.sim.qpos[i, :2], 9)) for i in range(4)}) == 4


def test_pooled_starts_step_like_in_place_starts():
    pooled = ResidualWalkCore(dataclasses.replace(QUICK, settle_pool=2), 2, seed=5)
    pooled.reset()
    # Fills pool entries 0 and 1, which draw like envs 2 and 3 (seeds 7 and 8), and
    # takes entry 0: the first start of a single env seeded 7.
    pooled.reset(np.array([1]))
    reference = ResidualWalkCore(QUICK, 1, seed=5 + 2)
    reference.reset()
    assert torch.equal(pooled.obs[1], reference.obs[0])
    np.testing.assert_array_equal(pooled.sim.state[1], reference.sim.state[0])
    for _ in range(5):
        a = pooled.step(torch.zeros(2, 12))
        b = reference.step(torch.zeros(1, 12))
        # Bit for bit: nothing in a step depends on the batch's length.
        assert torch.equal(a.obs[1], b.obs[0])
        assert torch.equal(a.reward[1:], b.reward)


def test_terrain_change_drops_pooled_starts():
    core = ResidualWalkCore(dataclasses.replace(QUICK, settle_pool=2), 2, seed=0)
    core.reset()
    core.reset(np.array([0]))
    assert core.starts.pool.uses_left.sum() == 1
    core.set_terrain_scale(0.5)
    assert core.starts.pool.uses_left.sum() == 0


@pytest.mark.parametrize(
    ("field", "value"), [("settle_pool", -1), ("settle_reuse", 0), ("decimation", 0)]
)
def test_bad_config_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(EnvConfig(), **{field: value})
