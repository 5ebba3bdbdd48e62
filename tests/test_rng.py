"""Seeds and random streams: independent starts per seed, env i like a single env s + i."""

import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest

from rwalk import EnvConfig, ResidualWalkCore, rng
from rwalk.core import START_STREAM

# Perturbed starts; no settling, so a reset costs one forward pass.
FAST = dataclasses.replace(EnvConfig(), settle_steps=0, randomize=True, num_threads=1)


def _starts(seed: int, resets: int, config: EnvConfig = FAST) -> np.ndarray:
    """qpos of a single env's first ``resets`` starts. Shape: (resets, nq)."""
    core = ResidualWalkCore(config, 1, seed=seed)
    poses = []
    for _ in range(resets):
        core.reset()
        poses.append(core.sim.qpos[0].copy())
    return np.stack(poses)


def test_neighbouring_seeds_share_no_start():
    a, b = _starts(0, 50), _starts(1, 50)
    shared = {tuple(p) for p in a} & {tuple(p) for p in b}
    assert not shared


def test_a_seed_reproduces_its_starts_and_seed_restarts_them():
    first = _starts(3, 4)
    np.testing.assert_array_equal(first, _starts(3, 4))
    core = ResidualWalkCore(FAST, 1, seed=99)
    core.reset()
    core.seed(3)
    again = []
    for _ in range(4):
        core.reset()
        again.append(core.sim.qpos[0].copy())
    np.testing.assert_array_equal(first, np.stack(again))


def test_start_k_of_env_i_is_keyed_by_seed_plus_i_and_k():
    seed, num_envs = 40, 3
    core = ResidualWalkCore(FAST, num_envs, seed=seed)
    for k in range(3):
        core.reset()
        u = 2.0 * rng.uniform(rng.keys(seed + np.arange(num_envs), START_STREAM, k), 5) - 1.0
        xy = np.asarray(FAST.start_position) + u[:, :2] * np.asarray(FAST.position_noise)
        np.testing.assert_array_equal(core.sim.qpos[:, :2], xy)


def test_env_i_of_a_batch_starts_like_a_single_env_over_several_resets():
    config = dataclasses.replace(FAST, settle_steps=3)
    seed, num_envs = 9, 4
    core = ResidualWalkCore(config, num_envs, seed=seed)
    partial = [None, [1, 3], [2], [0, 1, 2, 3], [1]]
    starts: list[list[np.ndarray]] = [[] for _ in range(num_envs)]
    for ids in partial:
        core.reset(None if ids is None else np.array(ids))
        for i in range(num_envs) if ids is None else ids:
            starts[i].append(core.sim.state[i].copy())
    for i in range(num_envs):
        single = ResidualWalkCore(config, 1, seed=seed + i)
        for k, state in enumerate(starts[i]):
            single.reset()
            np.testing.assert_array_equal(single.sim.state[0], state, err_msg=f"env {i} start {k}")


def test_a_new_stream_leaves_existing_streams_unchanged():
    seeds, counters = np.arange(5), np.arange(5)
    before = rng.uniform(rng.keys(seeds, START_STREAM, counters), 5)
    other = rng.uniform(rng.keys(seeds, "terrain_bumps", counters), 5)
    after = rng.uniform(rng.keys(seeds, START_STREAM, counters), 5)
    np.testing.assert_array_equal(before, after)
    assert not np.isin(other, before).any()


def test_stream_ids_do_not_depend_on_the_process():
    # Python's hash() of a str changes with PYTHONHASHSEED; a stream id must not.
    # Load rng.py alone (numpy only), not the whole package with torch and MuJoCo.
    code = (
        "import importlib.util as u, sys; spec = u.spec_from_file_location('rng', sys.argv[1]); "
        "m = u.module_from_spec(spec); spec.loader.exec_module(m); "
        "print(int(m.stream_id('start_pose')))"
    )
    env = dict(os.environ, PYTHONHASHSEED="12345")
    out = subprocess.run(
        [sys.executable, "-c", code, rng.__file__],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    assert int(out.stdout) == int(rng.stream_id("start_pose"))


@pytest.mark.parametrize("name", ["", None])
def test_bad_stream_name_is_rejected(name):
    with pytest.raises(ValueError, match="stream name"):
        rng.stream_id(name)


def test_the_largest_seed_works_and_wraps_for_later_envs():
    top = 2**64 - 1
    core = ResidualWalkCore(FAST, 2, seed=top)
    wrapped = ResidualWalkCore(FAST, 1, seed=0)  # env 1 of the batch: (2^64 - 1) + 1 mod 2^64
    for _ in range(3):
        core.reset()
        wrapped.reset()
        np.testing.assert_array_equal(core.sim.qpos[1], wrapped.sim.qpos[0])
    np.testing.assert_array_equal(core.sim.qpos[0], _starts(top, 3)[-1])


@pytest.mark.parametrize("seed", [2**64, -1, 1.5, True])
def test_seeds_outside_64_bits_are_rejected_and_the_env_stays_usable(seed):
    with pytest.raises(ValueError, match=str(seed).replace(".", r"\.")):
        ResidualWalkCore(FAST, 1, seed=seed)
    core = ResidualWalkCore(FAST, 1, seed=7)
    core.reset()
    with pytest.raises(ValueError, match="seed"):
        core.seed(seed)
    core.reset()  # still seeded 7: its second start
    np.testing.assert_array_equal(core.sim.qpos[0], _starts(7, 2)[-1])
