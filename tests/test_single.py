"""The one-env step (numpy and floats) against env i of the batched torch step, bit for bit."""

import dataclasses

import numpy as np
import pytest
import torch

from rwalk import EnvConfig, GaitCosts, ResidualWalkEnv
from rwalk.core import ResidualWalkCore
from rwalk.envs.single_step import SingleStep

# Large residuals make falls (terminations) common; short episodes add truncations.
CONFIG = EnvConfig(residual_scale=0.06, max_episode_steps=90, settle_steps=10, randomize=True)


@pytest.mark.parametrize(
    ("world", "costs"),
    [("model/world_train.xml", None), ("model/world_flat.xml", None),
     ("model/world_train.xml", GaitCosts())],  # terms that read the core's parts
)  # fmt: skip
def test_single_step_is_env_i_of_the_batched_step_bit_for_bit(world, costs):
    config = dataclasses.replace(CONFIG, model_path=world, costs=costs)
    seed, n, i = 5, 3, 2
    batch = ResidualWalkCore(config, n, seed=seed)
    single = ResidualWalkEnv(config=config, seed=seed + i)
    assert SingleStep.supports(single.core)
    batch.reset()
    single.reset()
    core = single.core
    gen = torch.Generator().manual_seed(1)
    ends = {"terminated": 0, "truncated": 0}
    for step in range(400):
        # Small actions first (episodes run to truncation), then large ones (falls).
        amplitude = 0.2 if step < 200 else 1.2
        actions = (torch.rand(n, 12, generator=gen, dtype=torch.float64) * 2 - 1) * amplitude
        want = batch.step(actions)
        obs, reward, terminated, truncated, info = single.step(actions[i].numpy())
        assert torch.equal(core.obs[0], want.obs[i]), step
        assert np.array_equal(obs, want.obs[i].numpy().astype(np.float32))
        assert reward == want.reward[i].item(), step
        assert info["reward_components"] == {k: v[i].item() for k, v in want.terms.items()}
        assert (terminated, truncated) == (want.terminated[i].item(), want.truncated[i].item())
        assert info["phase"] == batch.phase[i].item()
        assert info["lateral_offset"] == (batch.obs[i, 1] - batch.y0[i]).item()
        for name in batch.episode_sums:
            assert torch.equal(core.episode_sums[name][0], batch.episode_sums[name][i])
        for name in ("tick", "episode_step", "walked_steps", "episode_distance"):
            assert torch.equal(getattr(core, name)[0], getattr(batch, name)[i]), name
        done = want.terminated | want.truncated
        if bool(done.any()):
            batch.reset(done.nonzero()[:, 0])
        if terminated or truncated:
            ends["terminated" if terminated else "truncated"] += 1
            single.reset()
            assert torch.equal(core.obs[0], batch.obs[i])
    assert ends["terminated"] and ends["truncated"], ends


def test_single_step_and_batched_step_of_one_core_mix():
    # The two steps share the core's state: alternating them walks like either alone.
    config = dataclasses.replace(CONFIG, model_path="model/world_flat.xml")
    mixed, plain = (ResidualWalkCore(config, 1, seed=3) for _ in range(2))
    mixed.reset()
    plain.reset()
    gen = torch.Generator().manual_seed(2)
    for step in range(60):
        action = torch.rand(1, 12, generator=gen, dtype=torch.float64) * 2 - 1
        want = plain.step(action)
        if step % 2:
            got = mixed.step(action)
            assert torch.equal(got.reward, want.reward)
        else:
            assert SingleStep(mixed).step(action[0].numpy()).reward == want.reward.item()
        assert torch.equal(mixed.obs, plain.obs) and torch.equal(mixed.tick, plain.tick)


def test_the_single_step_refuses_a_batch_and_bad_actions():
    core = ResidualWalkCore(dataclasses.replace(CONFIG, settle_steps=0), 2, seed=0)
    core.reset()
    with pytest.raises(ValueError, match="num_envs=2"):
        SingleStep(core)
    single = SingleStep(ResidualWalkCore(dataclasses.replace(CONFIG, settle_steps=0), 1, seed=0))
    single.core.reset()
    with pytest.raises(ValueError, match="non-finite value nan"):
        single.step(np.array([0.0] * 5 + [np.nan] + [0.0] * 6))
    with pytest.raises(ValueError, match="float32 or float64"):
        single.step(np.zeros(12, dtype=np.float16))
    # Integer actions are accepted, as by the batched step.
    single.step(np.zeros(12, dtype=np.int64))


def test_single_bench_smoke(capsys):
    from rwalk.runners import single_bench

    results = single_bench.main(["--steps", "3", "--rounds", "1"])
    assert [r.label for r in results] == ["10 x 2 ms", "5 x 4 ms"]
    assert all(r.steps == 3 and r.step_us > 0 and r.floor_us > 0 for r in results)
    assert "floor/step" in capsys.readouterr().out
