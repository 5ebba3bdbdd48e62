"""rwalk-average: a run's policy averaged over its saved checkpoints (``average_policy``)."""

import pytest
import torch

from rwalk.rl.checkpoints import CheckpointError, average_policy, load_checkpoint


def save(folder, iteration, weight, *, key="actor_state_dict", mean=0.0, shape=(2,)):
    """A minimal rsl-rl save of iteration ``iteration``: the policy's weight all ``weight``,
    its normaliser's mean ``mean``, a critic (or teacher) and optimizer tagged with it."""
    other = "teacher_state_dict" if key == "student_state_dict" else "critic_state_dict"
    state = {
        key: {"mlp.0.weight": torch.full(shape, weight, dtype=torch.float32),
              "distribution.std_param": torch.full(shape, weight / 10, dtype=torch.float32),
              "obs_normalizer._mean": torch.full((3,), mean),
              "obs_normalizer.count": torch.tensor(iteration)},
        other: {"mlp.0.weight": torch.full((1,), float(iteration))},
        "optimizer_state_dict": {"param_groups": [{"lr": float(iteration)}]},
        "iter": iteration, "infos": None, "trainer": "rsl_rl",
    }  # fmt: skip
    path = folder / f"model_{iteration}.pt"
    torch.save(state, path)
    return path


@pytest.mark.parametrize("key", ["actor_state_dict", "student_state_dict"])
def test_the_weights_are_the_mean_and_the_rest_is_the_newest(tmp_path, key):
    paths = [save(tmp_path, it, w, key=key, mean=it) for it, w in ((25, 4.0), (0, 1.0), (10, 2.0))]
    out = average_policy(paths)  # given out of order: the newest is iteration 25
    policy = out[key]
    # (1 + 2 + 4) / 3 in float64, rounded once to float32
    assert torch.equal(policy["mlp.0.weight"], torch.full((2,), 7 / 3, dtype=torch.float32))
    assert torch.equal(policy["distribution.std_param"], torch.full((2,), 0.7 / 3).float())
    assert torch.equal(policy["obs_normalizer._mean"], torch.full((3,), 25.0))
    assert int(policy["obs_normalizer.count"]) == 25
    other = "teacher_state_dict" if key == "student_state_dict" else "critic_state_dict"
    assert float(out[other]["mlp.0.weight"]) == 25.0
    assert out["optimizer_state_dict"]["param_groups"][0]["lr"] == 25.0
    assert out["iter"] == 25 and out["averaged"] == [0, 10, 25]
    assert load_checkpoint(paths[0])[key]["mlp.0.weight"][0] == 4.0  # inputs untouched


def test_the_mean_is_summed_in_float64_not_in_the_weights_dtype(tmp_path):
    # 1 + 2^-24 + 2^-24 is 1 in float32 (each add rounds to even) and 1 + 2^-23 in float64
    tiny = 2.0**-24
    paths = [save(tmp_path, it, w) for it, w in ((0, 1.0), (1, tiny), (2, tiny))]
    got = average_policy(paths)["actor_state_dict"]["mlp.0.weight"]
    assert torch.equal(got, torch.full((2,), (1 + 2 * tiny) / 3, dtype=torch.float64).float())
    float32_mean = (torch.tensor(1.0) + torch.tensor(tiny) + torch.tensor(tiny)) / 3
    assert float(float32_mean) != float(got[0])  # a float32 sum loses both halves of an ulp


def test_fewer_than_two_a_repeated_iteration_or_another_policy_are_refused(tmp_path):
    one = save(tmp_path, 0, 1.0)
    with pytest.raises(CheckpointError, match="two checkpoints or more, got 1"):
        average_policy([one])
    (tmp_path / "b").mkdir()
    again = save(tmp_path / "b", 0, 2.0)
    with pytest.raises(CheckpointError, match="two checkpoints hold iteration 0"):
        average_policy([one, again])
    wider = save(tmp_path / "b", 5, 2.0, shape=(3,))
    with pytest.raises(CheckpointError, match="other entries or shapes"):
        average_policy([one, wider])
    student = save(tmp_path / "b", 6, 2.0, key="student_state_dict")
    with pytest.raises(CheckpointError, match=r"model_0\.pt.*other entries or shapes"):
        average_policy([one, student])


def test_a_checkpoint_that_is_not_an_rsl_rl_save_is_named(tmp_path):
    one = save(tmp_path, 0, 1.0)
    foreign = tmp_path / "model_1.pt"
    torch.save({"iteration": 1, "actor": {}, "trainer": "torchrl"}, foreign)
    with pytest.raises(CheckpointError, match=r"model_1\.pt.*torchrl trainer"):
        average_policy([one, foreign])
    with pytest.raises(FileNotFoundError, match=r"model_9\.pt"):
        average_policy([one, tmp_path / "model_9.pt"])
