"""The lag-priced smoothness of PPO's mean action (rwalk-train --lag-smoothness,
``rwalk.rl.ppo``): the cost and its gradient by hand, the gradient the same as the cost
added to the loss, the observation group it reads, a tiny run through rsl-rl's runner."""

import dataclasses
import json
from pathlib import Path

import pytest
import torch
from rsl_rl.models import MLPModel
from tensordict import TensorDict
from test_learning import PLAY, TINY

from rwalk import EnvConfig
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.randomization import Randomization
from rwalk.rl.config import TrainConfig, finetune_training, student_training
from rwalk.rl.ppo import SMOOTHING_OBS, LagSmoothedPPO, lag_cost, lag_pull
from rwalk.rl.rsl_rl_env import RslRlVecEnv
from rwalk.runners import play, train
from rwalk.tensorboard_events import read_scalars


def test_the_cost_and_its_gradient_by_hand():
    mean = torch.tensor([[0.5, -0.25], [0.75, 0.0]])
    smoothing = torch.tensor([[2.0, 0.25, 0.25], [0.0, -1.0, 1.0]])  # lag, last action
    # 2 x (0.0625 + 0.25); no delay, no cost however far the mean moved
    assert lag_cost(mean, smoothing).tolist() == [0.625, 0.0]
    # W 3 over a batch of 2: 2 x 3 / 2 x lag x (mean - last)
    assert lag_pull(mean, smoothing, 3.0).tolist() == [[1.5, -3.0], [0.0, 0.0]]


def test_each_sample_pairs_with_its_envs_mean_of_the_step_before_in_the_rollout():
    """By hand: a rollout of 3 steps, 2 envs, 1 action value; env 1's episode ends at
    step 0, so its step 1 starts an episode and has no pair."""
    from types import SimpleNamespace

    smoothing = torch.zeros(3, 2, 2)
    smoothing[..., 0] = torch.tensor([[2.0, 3.0], [1.0, 3.0], [2.0, 1.0]])  # the delays
    smoothing[..., 1] = 9.0  # the applied actions: replaced
    means = torch.tensor([[[0.5], [0.25]], [[-0.5], [0.75]], [[1.0], [1.0]]])
    dones = torch.tensor([[[0], [1]], [[0], [0]], [[0], [0]]], dtype=torch.uint8)
    storage = SimpleNamespace(observations=TensorDict({"smoothing": smoothing}, [3, 2]),
                              distribution_params=(means, None), dones=dones)  # fmt: skip
    ppo = LagSmoothedPPO.__new__(LagSmoothedPPO)
    ppo.storage = storage
    ppo.pair_with_previous_means()
    got = storage.observations["smoothing"]
    assert got[..., 0].tolist() == [[0.0, 0.0], [1.0, 0.0], [2.0, 1.0]]
    assert got[1:, :, 1].tolist() == [[0.5, 0.25], [-0.5, 0.75]]


def _actor(obs: TensorDict) -> MLPModel:
    torch.manual_seed(0)
    groups = {"actor": ["policy"]}
    distribution = {"class_name": "GaussianDistribution", "init_std": 0.5}
    return MLPModel(
        obs, groups, "actor", 3, hidden_dims=[8], distribution_cfg=distribution
    ).double()


def test_the_pull_on_the_mean_is_the_cost_added_to_the_loss():
    """The hook's parameter gradients equal those of PPO's loss (here any function of the
    log probabilities) plus W x the batch's mean cost, taken by autograd."""
    torch.manual_seed(1)
    smoothing = torch.cat([torch.randint(0, 4, (6, 1)), torch.rand(6, 3) - 0.5], dim=-1)
    obs = TensorDict({"policy": torch.randn(6, 5), "smoothing": smoothing}, batch_size=[6])
    obs = obs.to(torch.float64)
    actions = torch.randn(6, 3, dtype=torch.float64)
    hooked, plain = _actor(obs), _actor(obs)
    ppo = LagSmoothedPPO.__new__(LagSmoothedPPO)  # the hook alone: no storage, no update
    ppo.lag_smoothness, ppo._sums = 7.0, [0.0, 0]

    hooked.register_forward_hook(ppo._on_forward, with_kwargs=True)
    hooked(obs, stochastic_output=True)
    (hooked.get_output_log_prob(actions).square().mean()).backward()
    plain(obs, stochastic_output=True)
    cost = lag_cost(plain.output_mean, obs["smoothing"]).mean()
    (plain.get_output_log_prob(actions).square().mean() + 7.0 * cost).backward()

    assert ppo._sums == [pytest.approx(cost.item()), 1]
    assert cost > 0
    for (name, got), want in zip(hooked.named_parameters(), plain.parameters(), strict=True):
        torch.testing.assert_close(got.grad, want.grad, msg=name)  # float64 rounding apart
    ppo_alone = _actor(obs)
    ppo_alone(obs, stochastic_output=True)
    (ppo_alone.get_output_log_prob(actions).square().mean()).backward()
    last = "mlp.2.weight"  # the cost moves the mean's layer (the std's gradient it leaves)
    assert not torch.allclose(dict(ppo_alone.named_parameters())[last].grad,
                              dict(hooked.named_parameters())[last].grad)  # fmt: skip
    assert torch.equal(ppo_alone.distribution.std_param.grad, hooked.distribution.std_param.grad)


def test_only_a_stochastic_pass_with_gradients_is_priced():
    obs = TensorDict({"policy": torch.ones(2, 5), "smoothing": torch.ones(2, 4)}, batch_size=[2])
    actor = _actor(obs.to(torch.float64))
    ppo = LagSmoothedPPO.__new__(LagSmoothedPPO)
    ppo.lag_smoothness, ppo._sums = 1.0, [0.0, 0]
    actor.register_forward_hook(ppo._on_forward, with_kwargs=True)
    obs = obs.to(torch.float64)
    actor(obs)  # the mirror loss's deterministic pass
    with torch.no_grad():
        actor(obs, stochastic_output=True)  # a rollout's
    assert ppo._sums == [0.0, 0]
    actor(obs, stochastic_output=True)
    assert ppo._sums[1] == 1


def test_the_smoothing_group_reads_the_delay_that_applies_and_the_last_action():
    config = EnvConfig(model_path="model/world_flat.xml", settle_steps=5,
                       randomization=Randomization(latency=(0, 3)))  # fmt: skip
    env = RslRlVecEnv(BatchedEnv(16, config, seed=1), smoothing_obs=SMOOTHING_OBS)
    lag = env.core.physics.lag()
    assert sorted(set(lag.tolist())) == [0, 1, 2, 3]
    action = torch.zeros(16, 12)
    action[:, 0], action[:, 3] = 0.5, -2.0  # the piece holds the clipped action
    obs, *_ = env.step(action)
    assert obs["smoothing"].shape == (16, 13)
    assert torch.equal(obs["smoothing"][:, 0], lag.float())
    want = torch.zeros(16, 12)
    want[:, 0], want[:, 3] = 0.5, -1.0
    assert torch.equal(obs["smoothing"][:, 1:], want)
    # the mirror keeps the delay and mirrors the action as the task does
    action_mirror = env.action_mirror()
    assert env.mirror("smoothing") == ((0, *(1 + i for i in action_mirror.index)),
                                       (1.0, *action_mirror.signs))  # fmt: skip
    still = RslRlVecEnv(BatchedEnv(2, dataclasses.replace(config, randomization=None), seed=1),
                        smoothing_obs=SMOOTHING_OBS)  # fmt: skip
    assert still.get_observations()["smoothing"][:, 0].tolist() == [0.0, 0.0]
    assert "smoothing" not in RslRlVecEnv(BatchedEnv(2, config, seed=1)).get_observations()


def test_the_weight_picks_the_algorithm_and_the_stages_after_train_without_it():
    assert TrainConfig().to_rsl_rl(10)["algorithm"]["class_name"] == "PPO"
    assert "lag_smoothness" not in TrainConfig().to_rsl_rl(10)["algorithm"]
    algorithm = TrainConfig(lag_smoothness=2.5).to_rsl_rl(10)["algorithm"]
    assert algorithm["class_name"] == "rwalk.rl.ppo:LagSmoothedPPO"
    assert algorithm["lag_smoothness"] == 2.5
    teacher = train.parse_args(["--lag-smoothness", "2.5", "--finetune-iterations", "5",
                                "--log-dir", "/tmp/x"])  # fmt: skip
    assert teacher.train.lag_smoothness == 2.5
    student = student_training(teacher)
    assert student.train.lag_smoothness == 0.0
    finetune = finetune_training(student, Path("/tmp/x/student/model_1.pt"),
                                 Path("/tmp/x/model_1.pt"), teacher)  # fmt: skip
    assert finetune.train.lag_smoothness == 0.0


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--lag-smoothness", "-1"], "--lag-smoothness must be >= 0, got -1.0"),
        (["--lag-smoothness", "nan"], "--lag-smoothness must be >= 0, got nan"),
        (["--lag-smoothness", "1e9"], "--lag-smoothness must be at most 1000, got 1000000000.0"),
        (["--lag-smoothness", "1", "--actor", "gru"],
         "--lag-smoothness 1.0 needs PPO with an MLP actor and critic, got --actor gru"),
        (["--lag-smoothness", "1", "--critic", "lstm"],
         "--lag-smoothness 1.0 needs PPO with an MLP actor and critic, got --critic lstm"),
        (["--lag-smoothness", "1", "--distill", "x.pt"],
         "--lag-smoothness 1.0 needs PPO with an MLP actor and critic, got --distill"),
    ],
)  # fmt: skip
def test_a_bad_weight_is_a_usage_error(flags, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        train.parse_args(["--recipe", "plain", *flags])
    assert exit_.value.code == 2 and message in capsys.readouterr().err


def test_a_tiny_run_trains_and_logs_the_cost(tmp_path):
    """Through rsl-rl's runner, with its symmetry augmentation mirroring the group too; the
    last iteration draws the model's physics, where no delay applies and nothing costs."""
    flags = [*TINY, "--max-iterations", "2", "--env.randomization.latency", "0", "3",
             "--nominal-physics-iterations", "1"]  # fmt: skip
    train.main([*flags, "--log-dir", str(tmp_path / "plain")])
    train.main([*flags, "--lag-smoothness", "50", "--log-dir", str(tmp_path / "smooth")])
    logged = read_scalars(tmp_path / "smooth")["Loss/lag_smoothness"]
    assert [value > 0 for *_, value in logged] == [True, False]
    assert logged[1][2] == 0.0
    assert "Loss/lag_smoothness" not in read_scalars(tmp_path / "plain")
    saved = json.loads((tmp_path / "smooth" / "config.json").read_text())["train"]
    assert saved["lag_smoothness"] == 50.0 and saved["symmetry"] is True
    plain, smooth = (torch.load(tmp_path / run / "model_1.pt", weights_only=True)
                     for run in ("plain", "smooth"))  # fmt: skip
    weights = plain["actor_state_dict"].keys()
    assert any(not torch.equal(plain["actor_state_dict"][name], smooth["actor_state_dict"][name])
               for name in weights if name.startswith("mlp."))  # fmt: skip
    assert smooth["actor_state_dict"].keys() == weights  # no new parameters
    rows = play.play(["--checkpoint", str(tmp_path / "smooth" / "model_1.pt"), *PLAY])
    assert rows[0].mean_length == 10  # it plays as any PPO run's
