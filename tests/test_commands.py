"""The command curriculum (rwalk.commands): bins, hand-computed draws and updates, its
wiring into the core's resets, checkpoints, and its flags."""

import dataclasses
import math
import pickle

import pytest
import torch

from rwalk import AdaptiveGaitConfig, Core, EnvConfig
from rwalk.commands import CommandCurriculum, CommandWeights
from rwalk.runners import train

F64 = torch.float64
RANGE = (0.03, 0.27)  # 12 bins of 0.02 m/s: bin k is [0.03 + 0.02 k, 0.05 + 0.02 k)
FAST = AdaptiveGaitConfig(model_path="model/world_flat.xml", settle_steps=10,
                          max_episode_steps=100, command_range=RANGE,
                          command_curriculum=CommandCurriculum())  # fmt: skip


def weights(**changes) -> CommandWeights:
    return CommandWeights(CommandCurriculum(**changes), RANGE)


def episodes(commands, walked, error, fell):
    return (torch.tensor(commands, dtype=F64), torch.tensor(walked),
            torch.tensor(error, dtype=F64), torch.tensor(fell))  # fmt: skip


def test_only_the_bins_over_the_start_have_weight_at_first():
    w = weights()  # start (0.12, 0.14): bins [0.11, 0.13) and [0.13, 0.15)
    assert w.weights.tolist() == [0, 0, 0, 0, 5, 5, 0, 0, 0, 0, 0, 0]
    assert w.unlocked() == pytest.approx((0.11, 0.15))
    one = weights(start=(0.133, 0.133), steps=2)  # a point: its bin alone
    assert one.weights.tolist() == [0, 0, 0, 0, 0, 2, 0, 0, 0, 0, 0, 0]


def test_draws_pick_a_bin_by_weight_then_a_speed_within_it():
    w = weights()
    w.weights.copy_(torch.tensor([0, 0, 0, 0, 5, 5, 1, 0, 0, 0, 0, 0]))  # total 11
    u = torch.tensor([[0.0, 0.5], [5 / 11, 0.0], [10.5 / 11, 0.25], [0.999, 0.999]], dtype=F64)
    # 0 -> bin 4; 5 of 11 -> bin 5 (its first weight); 10.5 -> bin 6; 10.99 -> bin 6
    expected = [0.03 + 4.5 * 0.02, 0.03 + 5 * 0.02, 0.03 + 6.25 * 0.02, 0.03 + 6.999 * 0.02]
    torch.testing.assert_close(w.draw(u), torch.tensor(expected, dtype=F64))
    many = w.draw(torch.rand(20_000, 2, dtype=F64, generator=torch.Generator().manual_seed(0)))
    assert many.min() >= 0.11 and many.max() < 0.17
    share = ((many >= 0.15) & (many < 0.17)).double().mean()  # bin 6: 1 of 11
    assert abs(float(share) - 1 / 11) < 0.01


def test_a_tracked_episode_widens_its_bin_and_its_neighbours():
    w = weights()
    # bin 5: tracked (0.9 s of error over 100 steps = 0.009 m/s); bin 4: exactly at the
    # tolerance (3 / 100 = 0.03) counts; a fall, a miss and an episode that ended nothing do not
    w.update(*episodes([0.14, 0.12, 0.14, 0.14, 0.14], [100, 100, 100, 100, 0],
                       [0.9, 3.0, 0.1, 3.5, 0.0], [False, False, True, False, False]))  # fmt: skip
    assert w.weights.tolist() == [0, 0, 0, 1, 5, 5, 1, 0, 0, 0, 0, 0]
    w.update(*episodes([0.16, 0.16], [50, 50], [0.0, 0.0], [False, False]))  # bin 6, twice
    assert w.weights.tolist() == [0, 0, 0, 1, 5, 5, 3, 2, 0, 0, 0, 0]
    w.update(*episodes([0.27, 0.03], [10, 10], [0.0, 0.0], [False, False]))  # the two ends
    assert w.weights.tolist() == [1, 1, 0, 1, 5, 5, 3, 2, 0, 0, 1, 1]  # no wrap-around
    for _ in range(9):
        w.update(*episodes([0.16], [10], [0.0], [False]))
    assert w.weights.tolist() == [1, 1, 0, 1, 5, 5, 5, 5, 0, 0, 1, 1]  # full is the most
    assert w.unlocked() == pytest.approx(RANGE)
    log = w.log()
    assert float(log["Curriculum/command_low"]) == pytest.approx(0.03)
    assert float(log["Curriculum/command_weight"]) == pytest.approx(25 / 60)


def test_saved_weights_carry_over_and_bad_ones_are_named():
    w = weights()
    saved = torch.tensor([0, 1, 2, 3, 4, 5, 5, 4, 3, 2, 1, 0])
    assert w.load(saved) is None and torch.equal(w.weights, saved)
    assert "12" in w.load(torch.tensor([5, 5])) and torch.equal(w.weights, saved)
    for bad in (saved.double(), saved + 1, -saved, saved.reshape(3, 4)):
        with pytest.raises(ValueError, match="command_weights"):
            w.load(bad)


@pytest.mark.parametrize(
    "bad, field",
    [({"bins": 0}, "bins"), ({"bins": True}, "bins"), ({"steps": 0}, "steps"),
     ({"steps": 1.5}, "steps"), ({"start": (0.2, 0.1)}, "start"),
     ({"start": (math.nan, 0.1)}, "start"), ({"start": (0.1,)}, "start"),
     ({"tolerance": 0.0}, "tolerance"), ({"tolerance": -0.01}, "tolerance"),
     ({"tolerance": math.inf}, "tolerance"), ({"tolerance": math.nan}, "tolerance")],
)  # fmt: skip
def test_bad_settings_are_named(bad, field):
    with pytest.raises(ValueError, match=rf"CommandCurriculum\.{field}"):
        CommandCurriculum(**bad)


def test_the_range_it_cuts_must_hold_the_start_and_one_command_per_episode():
    with pytest.raises(ValueError, match=r"CommandCurriculum\.start"):
        EnvConfig(command_range=(0.2, 0.3), command_curriculum=CommandCurriculum())
    with pytest.raises(ValueError, match="LOW < HIGH"):
        EnvConfig(command_range=(0.13, 0.13), command_curriculum=CommandCurriculum())
    with pytest.raises(ValueError, match=r"EnvConfig\.command_interval"):
        EnvConfig(command_range=RANGE, command_interval=4.0,
                  command_curriculum=CommandCurriculum())  # fmt: skip
    no_range = dataclasses.replace(FAST, command_range=None)  # a flag may add it later
    with pytest.raises(ValueError, match="needs a command_range"):
        Core(no_range, 1)


def test_the_core_draws_from_the_unlocked_bins_and_its_resets_widen_them():
    core = Core(FAST, 4, seed=3)
    core.reset()
    target = core.task.target.clone()
    assert ((target >= 0.11) & (target < 0.15)).all() and len(set(target.tolist())) == 4
    # episodes end: env 0 tracked, 1 fell, 2 missed, 3 tracked but cut short (rsl-rl's
    # randomly shortened first episodes): only env 0 counts
    core.walked_steps[:] = torch.tensor([100, 100, 100, 99])
    core.episode_speed_error[:] = torch.tensor([1.0, 0.0, 4.0, 0.0], dtype=F64)
    core.fell[:] = torch.tensor([False, True, False, False])
    bin_0 = int(((target[0] - 0.03) / 0.02).floor())
    core.reset()
    expected = torch.zeros(12, dtype=torch.long)
    expected[4:6] = 5
    expected[bin_0 - 1 : bin_0 + 2] += 1
    assert core.task.commands.weights.tolist() == expected.clamp(max=5).tolist()
    again = Core(FAST, 4, seed=3)  # the draws are the seed's
    again.reset()
    assert torch.equal(again.task.target, target)
    copy = pickle.loads(pickle.dumps(core))  # a pickled core keeps its weights
    assert torch.equal(copy.task.commands.weights, core.task.commands.weights)
    plain = Core(dataclasses.replace(FAST, command_curriculum=None), 4, seed=3)
    plain.reset()
    assert plain.task.commands is None and float(plain.task.target.max()) > 0.15


def test_checkpoints_carry_the_weights(tmp_path):
    import contextlib
    import io

    from rwalk.rl.runner import SafeRunner
    from rwalk.rl.training import make_env, rsl_rl_config

    args = train.parse_args(["--task", "adaptive_gait", "--no-robust", "--num-envs", "4",
                             "--command-range", "0.03", "0.27", "--env.settle-steps", "2",
                             "--env.command-curriculum.steps", "3",
                             "--env.max-episode-steps", "2", "--hidden-dims", "8"])  # fmt: skip

    def runner():
        with contextlib.redirect_stdout(io.StringIO()):
            return SafeRunner(make_env(args), rsl_rl_config(args), log_dir=None, device="cpu")

    first = runner()
    for _ in range(2):  # the episodes end: the log shows the commands drawn
        extras = first.env.step(torch.zeros(4, 16))[3]
    low, high = first.env.core.task.commands.unlocked()
    assert float(extras["log"]["Curriculum/command_low"]) == low <= 0.11
    assert float(extras["log"]["Curriculum/command_high"]) == high >= 0.15
    first.env.core.task.commands.weights.copy_(torch.tensor([0, 1, 2, 3] * 3))
    first.save(str(tmp_path / "model_0.pt"))
    second = runner()
    assert second.env.core.task.commands.weights.tolist() == [0, 0, 0, 0, 3, 3] + [0] * 6
    second.load(str(tmp_path / "model_0.pt"))
    assert second.env.core.task.commands.weights.tolist() == [0, 1, 2, 3] * 3


def test_every_setting_is_a_flag_and_a_bad_one_is_one_line(capsys):
    training = train.parse_args(["--task", "adaptive_gait", "--command-range", "0.03", "0.27",
                                 "--env.command-curriculum.start", "0.1", "0.16",
                                 "--env.command-curriculum.tolerance", "0.02"])  # fmt: skip
    assert training.env.command_curriculum == CommandCurriculum(start=(0.1, 0.16),
                                                                tolerance=0.02)  # fmt: skip
    with pytest.raises(SystemExit) as exit_:
        train.parse_args(["--task", "adaptive_gait", "--command-range", "0.03", "0.27",
                          "--env.command-curriculum.tolerance", "-1"])  # fmt: skip
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "--env.command-curriculum.tolerance" in err and "-1" in err and err.count("\n") == 1
