import dataclasses

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.envs.utils import check_env_specs

from rwalk import EnvConfig, ObservationNoise, ResidualWalkVecEnv
from rwalk.constants import (
    OBS_CONTACT,
    OBS_FOOT_POS,
    OBS_JOINT_POS,
    OBS_QUAT,
)
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.kinematics import leg_fk
from rwalk.randomization import PHYSICS_PARAMS
from rwalk.rewards import TERM_NAMES

QUICK = dataclasses.replace(EnvConfig(), settle_steps=10, max_episode_steps=40)


def _actions(n, steps, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return torch.rand(steps, n, 12, generator=gen) * 2 - 1


def _rollout(env, actions):
    td = env.reset()
    out = []
    for action in actions:
        td = env.step(td.set("action", action))["next"]
        out.append(td.clone())
    return torch.stack(out)


def test_check_env_specs():
    check_env_specs(ResidualWalkVecEnv(4, QUICK, seed=0))


def test_observation_layout_matches_the_spec():
    env = ResidualWalkVecEnv(3, QUICK, seed=0)
    td = env.reset()
    td = env.step(td.set("action", torch.zeros(3, 12)))["next"]
    obs = td["observation"].double()
    assert obs.shape == (3, 65) and td["observation"].dtype == torch.float32
    torch.testing.assert_close(obs[:, OBS_QUAT].norm(dim=-1), torch.ones(3, dtype=torch.float64))
    assert set(obs[:, OBS_CONTACT].unique().tolist()) <= {0.0, 1.0}
    # Foot positions in the torso frame are the hips plus the legs' FK of the joint angles.
    g = env.core.geometry
    fk = leg_fk(obs[:, OBS_JOINT_POS].view(3, 4, 3), g) + g.hip_tensor()
    torch.testing.assert_close(obs[:, OBS_FOOT_POS].view(3, 4, 3), fk, atol=2e-6, rtol=0)
    phase = env.core.phase
    torch.testing.assert_close(
        td["phase"].double(),
        torch.stack((torch.sin(2 * torch.pi * phase), torch.cos(2 * torch.pi * phase)), -1),
        atol=1e-6,
        rtol=0,
    )
    torch.testing.assert_close(
        td["lateral_offset"].double().squeeze(-1), obs[:, 1] - env.core.y0, atol=1e-6, rtol=0
    )


def test_reward_is_the_sum_of_the_terms():
    env = ResidualWalkVecEnv(4, QUICK, seed=0)
    data = _rollout(env, _actions(4, 20))
    terms = sum(data["reward_terms", name] for name in TERM_NAMES)
    torch.testing.assert_close(data["reward"], terms, rtol=1e-6, atol=1e-4)


def test_partial_reset_leaves_the_other_envs_untouched():
    env = ResidualWalkVecEnv(3, QUICK, seed=0)
    td = env.reset()
    for action in _actions(3, 5):
        td = env.step(td.set("action", action))["next"]
    rows_before = env.core.sim.state.copy()
    steps_before = env.core.episode_step.clone()
    mask = torch.tensor([[False], [True], [False]])
    after = env.reset(td.clone().set("_reset", mask))  # as collectors do
    np.testing.assert_array_equal(env.core.sim.state[[0, 2]], rows_before[[0, 2]])
    assert not np.array_equal(env.core.sim.state[1], rows_before[1])
    assert env.core.episode_step.tolist() == [steps_before[0], 0, steps_before[2]]
    torch.testing.assert_close(after["observation"][[0, 2]], td["observation"][[0, 2]])


def test_same_seed_same_trajectory_whatever_the_thread_count():
    actions = _actions(5, 25)
    runs = []
    for threads in (1, 2, 1):
        env = ResidualWalkVecEnv(5, dataclasses.replace(QUICK, num_threads=threads), seed=7)
        runs.append(_rollout(env, actions))
    for run in runs[1:]:
        torch.testing.assert_close(run["observation"], runs[0]["observation"], rtol=0, atol=0)
        torch.testing.assert_close(run["reward"], runs[0]["reward"], rtol=0, atol=0)
    other = _rollout(
        ResidualWalkVecEnv(5, dataclasses.replace(QUICK, randomize=True), seed=8), actions
    )
    assert not torch.equal(other["observation"], runs[0]["observation"])


def test_set_seed_restarts_the_starts():
    config = dataclasses.replace(QUICK, randomize=True)
    env = ResidualWalkVecEnv(2, config)
    env.set_seed(3)
    first = env.reset()["observation"]
    env.set_seed(3)
    again = env.reset()["observation"]
    torch.testing.assert_close(first, again, rtol=0, atol=0)


def test_bad_actions_are_refused_or_clipped():
    env = ResidualWalkVecEnv(2, QUICK, seed=0)
    td = env.reset()
    with pytest.raises(ValueError, match=r"shape \(2, 12\)"):
        env.core.step(torch.zeros(2, 11))
    nan = torch.zeros(2, 12)
    nan[1, 4] = float("nan")
    with pytest.raises(ValueError, match=r"nan.*env 1, index 4"):
        env.core.step(nan)
    big = torch.full((2, 12), 7.0)
    one = torch.ones(2, 12)
    a = ResidualWalkVecEnv(2, QUICK, seed=0)
    b = ResidualWalkVecEnv(2, QUICK, seed=0)
    ta, tb = a.reset(), b.reset()
    ra = a.step(ta.set("action", big))["next", "observation"]
    rb = b.step(tb.set("action", one))["next", "observation"]
    torch.testing.assert_close(ra, rb, rtol=0, atol=0)
    assert td is not None


def test_diverged_env_is_terminated_and_reset_without_harming_the_batch(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs the divergence to ./MUJOCO_LOG.TXT
    env = ResidualWalkVecEnv(3, QUICK, seed=0)
    reference = ResidualWalkVecEnv(3, QUICK, seed=0)
    td, ref = env.reset(), reference.reset()
    env.core.sim.qvel[1, :] = 1e12
    zeros = torch.zeros(3, 12)
    out = env.step(td.set("action", zeros))["next"]
    ref_out = reference.step(ref.set("action", zeros))["next"]
    assert out["diverged"].squeeze(-1).tolist() == [False, True, False]
    assert out["terminated"].squeeze(-1).tolist() == [False, True, False]
    assert torch.isfinite(out["observation"]).all()
    assert out["reward"][1].item() == 0.0
    torch.testing.assert_close(out["observation"][[0, 2]], ref_out["observation"][[0, 2]])
    env.reset(TensorDict({"_reset": out["done"]}, batch_size=[3]))
    again = env.step(TensorDict({"action": zeros}, batch_size=[3]))["next"]
    assert not again["diverged"].any()


def test_sync_collector_collects_with_resets():
    env = ResidualWalkVecEnv(4, dataclasses.replace(QUICK, max_episode_steps=15), seed=0)
    collector = Collector(env, policy=None, frames_per_batch=4 * 20, total_frames=4 * 40)
    batches = list(collector)
    collector.shutdown()
    assert len(batches) == 2 and batches[0].shape == (4, 20)
    assert batches[0]["next", "truncated"].sum() == 4  # every env truncated once at step 15
    assert batches[0]["next", "reward_terms", "lateral"].shape == (4, 20, 1)


def _make_small_env():
    return ResidualWalkVecEnv(2, dataclasses.replace(QUICK, max_episode_steps=8), seed=1)


def test_multi_sync_collector_runs_envs_in_worker_processes():
    collector = MultiSyncCollector(
        [_make_small_env, _make_small_env],
        policy=None,
        frames_per_batch=2 * 2 * 10,
        total_frames=80,
    )
    batches = list(collector)
    collector.shutdown()
    assert len(batches) == 2
    assert batches[0].numel() == 40
    assert batches[0]["next", "done"].any()


def test_cpu_only():
    with pytest.raises(ValueError, match="CPU"):
        ResidualWalkVecEnv(2, QUICK, device="cuda")


# ------------------------------------------------------------------- observation groups

GROUPS = {"policy": ("observation", "phase"), "critic": ("observation", "phase", "physics")}


def test_groups_are_keys_of_their_pieces_beside_the_others():
    env = ResidualWalkVecEnv(3, QUICK, seed=0, groups=GROUPS)
    check_env_specs(env)
    widths = {"policy": 65 + 2, "critic": 65 + 2 + len(PHYSICS_PARAMS)}
    for td in (env.reset(), env.step(env.reset().set("action", torch.zeros(3, 12)))["next"]):
        for group, width in widths.items():
            assert td[group].shape == (3, width) and td[group].dtype == torch.float32
        assert td["observation"].shape == (3, 65) and td["phase"].shape == (3, 2)
        # No observation noise in the config: every group is its pieces, exact.
        pieces = torch.cat([td["observation"], td["phase"]], dim=-1)
        torch.testing.assert_close(td["policy"], pieces, rtol=0, atol=0)
        physics = env.core.piece("physics").to(torch.float32)
        torch.testing.assert_close(td["critic"], torch.cat([pieces, physics], -1), rtol=0, atol=0)


def test_only_the_policy_group_carries_the_observation_noise():
    noisy = dataclasses.replace(QUICK, observation_noise=ObservationNoise())
    env = ResidualWalkVecEnv(4, noisy, seed=0, groups=GROUPS)
    td = env.step(env.reset().set("action", torch.zeros(4, 12)))["next"]
    exact = torch.cat([td["observation"], td["phase"]], dim=-1)  # the plain keys stay exact
    torch.testing.assert_close(td["observation"], env.core.piece("observation").float())
    torch.testing.assert_close(td["critic"][:, :67], exact, rtol=0, atol=0)
    scales = env.core.observations.scales("observation").float()  # (65,) half-widths
    error = (td["policy"][:, :65] - td["observation"]).abs()
    assert (error <= scales + 1e-5).all()  # within each value's half-width
    assert (error[:, scales > 0] > 0).float().mean() > 0.9  # and noisy where it has one
    torch.testing.assert_close(td["policy"][:, 65:], td["phase"], rtol=0, atol=0)  # phase: exact


def test_groups_may_come_from_the_task_and_bad_ones_name_the_fault():
    def actor(task):
        return {"actor": ("observation", *task.extras())}

    env = BatchedEnv(2, QUICK, seed=0, groups=actor)
    assert env.groups == {"actor": ("observation", "phase", "lateral_offset")}
    assert env.reset()["actor"].shape == (2, 68)
    with pytest.raises(ValueError, match="no observation piece 'heightz'"):
        BatchedEnv(2, QUICK, groups={"critic": ("observation", "heightz")})
    with pytest.raises(ValueError, match="group 'phase' would replace the env's key 'phase'"):
        BatchedEnv(2, QUICK, groups={"phase": ("observation",)})
    with pytest.raises(ValueError, match="group 'policy' must be a sequence of piece names"):
        BatchedEnv(2, QUICK, groups={"policy": "observation"})
