"""rwalk-adaptive-report: the gait by kind of ground and level, the adaptation floor, the
cost of transport, and the refusal of a checkpoint of the other task."""

import json
import math
from pathlib import Path

import pytest
import torch

from rwalk import adaptive_evaluation as ae
from rwalk.adaptive_evaluation import GaitStats, adaptation, walk_levels
from rwalk.levels import TerrainLevels
from rwalk.runners import adaptive_report, train
from rwalk.tasks import AdaptiveGaitConfig

TINY = ["--num-envs", "10", "--num-steps-per-env", "4", "--settle-steps", "2",
        "--max-episode-steps", "30", "--hidden-dims", "16", "--save-interval", "1",
        "--no-export", "--max-iterations", "1", "--recipe", "plain"]  # fmt: skip
QUICK = ["--episodes", "2", "--max-steps", "20", "--settle-steps", "2", "--gait-steps", "55"]


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory) -> tuple[Path, Path]:
    residual, adaptive = tmp_path_factory.mktemp("residual"), tmp_path_factory.mktemp("adaptive")
    train.main([*TINY, "--log-dir", str(residual)])
    train.main([*TINY, "--task", "adaptive_gait", "--gait-action", "target", "--costs",
                "--command-range", "0.05", "0.25", "--log-dir", str(adaptive)])  # fmt: skip
    return residual / "model_0.pt", adaptive / "model_0.pt"


class HoldTargets:
    """A policy that asks each kind of tile for its own gait targets (no residuals)."""

    def __init__(self, targets: torch.Tensor, n: int) -> None:
        kinds = len(ae.TERRAIN_KINDS)
        self.action = torch.zeros(n, 16)
        self.action[:, :4] = targets[torch.arange(n) % kinds]

    def __call__(self) -> torch.Tensor:
        return self.action

    def reset(self) -> None:
        pass


def test_the_gait_statistics_are_per_kind_and_level():
    kinds = len(ae.TERRAIN_KINDS)
    targets = torch.tensor([[-0.8 + 0.4 * k, 0.2 * k - 0.4, 0.0, 0.1 * k] for k in range(kinds)])
    built = []

    def policy_for(env):
        built.append(env.core.config)
        return HoldTargets(targets, env.core.num_envs)

    levels = TerrainLevels(levels=2, seed=1234)
    stats = walk_levels(policy_for, AdaptiveGaitConfig(gait_action="target"), False, episodes=2,
                        seed=5, steps=60, levels=levels)  # fmt: skip
    assert [(s.kind, s.level) for s in stats] == [
        (kind, level) for level in range(2) for kind in ae.TERRAIN_KINDS
    ]
    assert [c.terrain_levels.start_level for c in built] == [0, 1]
    assert all(c.terrain_levels.kinds == ae.TERRAIN_KINDS and c.gait_action == "target"
               for c in built)  # fmt: skip
    low = torch.tensor([0.01, 0.0, 0.3, 0.05], dtype=torch.float64)
    high = torch.tensor([0.04, 0.16, 0.9, 0.09], dtype=torch.float64)
    for s in stats:
        k = ae.TERRAIN_KINDS.index(s.kind)
        # A full sweep takes 40 steps at the delta rate: from step 50 on, the targets hold.
        expected = (low + high) / 2 + targets[k].double() * (high - low) / 2
        assert s.fall_rate == 0.0 and s.episodes == 2
        assert s.mean[:4] == pytest.approx(expected.tolist(), abs=1e-12)
        assert max(s.interval[:4]) < 1e-9 and max(s.spread[:4]) < 1e-6
        if s.level == 0:
            # Level 0's tiles are nearly flat and the stance feet rest on the ground: each
            # swing lifts a foot to about the held step height (the apex above the stance
            # line, which lies below the ground by stance_depth, taken up by the body).
            assert abs(s.mean[4] - float(expected[0])) < 0.001


def test_the_gait_at_each_commanded_speed_is_a_row_per_speed():
    targets = torch.tensor([[0.5, -0.5, 0.25, 0.0]]).expand(len(ae.TERRAIN_KINDS), 4)
    built = []

    def policy_for(env):
        built.append(env.core.config)
        return HoldTargets(targets, env.core.num_envs)

    trained = AdaptiveGaitConfig(gait_action="target", command_range=(0.05, 0.25))
    stats = ae.walk_speeds(policy_for, trained, episodes=2, seed=5, steps=60)
    assert [s.kind for s in stats] == ["0.05 m/s", "0.1 m/s", "0.15 m/s", "0.2 m/s", "0.25 m/s"]
    assert [c.command_range for c in built] == [(v, v) for v in ae.SPEEDS]
    assert all(c.terrain_scale == 1.0 and c.max_episode_steps == 60 for c in built)
    # The held targets, read as in the test above: the middle of each range plus its share.
    expected = [0.025 + 0.5 * 0.015, 0.08 - 0.5 * 0.08, 0.6 + 0.25 * 0.3, 0.07]
    for s in stats:
        assert (s.level, s.episodes, s.fall_rate) == (0, 2, 0.0)
        assert s.mean[:4] == pytest.approx(expected, abs=1e-12)


def _stats(kind, level, height_mm, interval_mm):
    h, i = height_mm / 1000, interval_mm / 1000
    return GaitStats(kind, level, 100, 0.0, (h, 0.08, 0.6, 0.07), (i, 0, 0, 0), (0, 0, 0, 0))


def test_rows_of_an_older_report_show_no_swing_peak():
    row = ae.gait_table([_stats("steps", 3, 10.5, 0.25)]).splitlines()[-1]
    assert row.startswith("| steps | 3 | 0% | 10.5 ± 0.2 (0.0) | 80.0 ± 0.0 (0.0) |")
    assert row.endswith("| 70.0 ± 0.0 (0.0) | - |")


def test_adaptation_compares_hard_upper_levels_with_flat_ground_by_hand():
    flat = [_stats("flat", level, 10.0, 1.0) for level in range(10)]
    hard = [_stats(kind, level, 20.0 + level, 2.0) for kind in ("rough", "steps")
            for level in range(10)]  # fmt: skip
    ignored = [_stats("stones", level, 1.0, 0.1) for level in range(10)]
    result = adaptation(flat + hard + ignored)
    # hard: levels 5..9 of rough and steps, mean 20 + 7 mm; interval 1.96 sqrt(10 (2/1.96)^2) / 10
    assert result["hard"][0] == pytest.approx(0.027, abs=1e-15)
    assert result["hard"][1] == pytest.approx(0.002 / math.sqrt(10), rel=1e-12)
    assert result["flat"] == pytest.approx((0.010, 0.001 / math.sqrt(10)), rel=1e-12)
    assert result["ratio"] == pytest.approx(2.7) and result["met"]
    low = adaptation(flat + [_stats("rough", level, 14.0, 1.0) for level in range(5, 10)])
    assert low["ratio"] == pytest.approx(1.4) and not low["met"]
    wide = adaptation([_stats("flat", 0, 10.0, 4.0), _stats("steps", 7, 16.0, 4.0)])
    assert wide["ratio"] == pytest.approx(1.6) and not wide["met"]  # intervals overlap


def test_the_report_runs_end_to_end_and_reads_its_json_back(checkpoints, tmp_path, capsys):
    residual, adaptive = checkpoints
    adaptive_report.main(["--residual", str(residual), "--adaptive", str(adaptive), *QUICK,
                          "--out", str(tmp_path)])  # fmt: skip
    printed = capsys.readouterr().out
    data = json.loads((tmp_path / "adaptive.json").read_text())
    assert (tmp_path / "adaptive_levels.png").stat().st_size > 10_000
    assert len(data["a"]) == len(data["b"]) == 3 and len(data["c"]) == 15
    assert len(data["gait"]) == 10 * len(ae.TERRAIN_KINDS)
    flat_rows = {row["name"].split(" | ")[0]: row for row in data["a"]}
    for row in flat_rows.values():  # every gait spends energy to move on flat ground
        assert row["power"] > 0.5
        assert row["cost_of_transport"] == pytest.approx(
            row["power"] / (0.8 * 9.81 * row["forward_velocity"]), rel=1e-12
        )
    assert "cost of transport" in printed and "(d) the adaptive policy's gait" in printed
    assert "step height on rough and step tiles" in printed
    assert "swing peak above ground (mm)" in printed
    assert all(len(row["mean"]) == len(ae.MEASURED) for row in data["gait"])
    adaptive_report.main(["--tables", str(tmp_path / "adaptive.json")])
    assert capsys.readouterr().out.strip() == printed.strip()


def test_one_policy_alone_gets_its_rows_and_no_gait_without_the_adaptive(
    checkpoints, tmp_path, monkeypatch, capsys
):
    # a residual policy alone: (a)-(c) for the base gait and it, no gait by terrain, no plot
    def never(*args, **kwargs):
        raise AssertionError("the gait by terrain ran without an adaptive policy")

    monkeypatch.setattr(adaptive_report, "gait_by_terrain", never)
    residual, _ = checkpoints
    adaptive_report.main(["--residual", str(residual), *QUICK, "--out", str(tmp_path)])
    printed = capsys.readouterr().out
    data = json.loads((tmp_path / "adaptive.json").read_text())
    assert set(data) == {"a", "b", "c"} and not (tmp_path / "adaptive_levels.png").exists()
    assert [row["name"].split(" | ")[0] for row in data["a"]] == ["base gait", "residual"]
    assert len(data["c"]) == 2 * len(ae.SPEEDS) and "(d)" not in printed
    adaptive_report.main(["--tables", str(tmp_path / "adaptive.json")])
    assert capsys.readouterr().out.strip() == printed.strip()
    with pytest.raises(SystemExit) as raised:
        adaptive_report.main([*QUICK])
    assert raised.value.code == 2
    assert "give --residual, --adaptive or both" in capsys.readouterr().err


def test_a_checkpoint_of_the_other_task_is_refused_naming_both(checkpoints, capsys):
    residual, adaptive = checkpoints
    with pytest.raises(SystemExit) as raised:
        adaptive_report.main(["--residual", str(adaptive), "--adaptive", str(residual), *QUICK])
    assert raised.value.code == 2
    error = capsys.readouterr().err
    assert "--residual" in error and "'adaptive_gait' policy, not a 'residual_walk' one" in error


def test_an_out_folder_it_could_not_write_is_refused_before_any_row(
    checkpoints, tmp_path, monkeypatch, capsys
):
    def never(*args, **kwargs):
        raise AssertionError("a row ran before the refusal")

    monkeypatch.setattr(adaptive_report, "compare", never)
    monkeypatch.setattr(adaptive_report, "gait_by_terrain", never)
    residual, adaptive = checkpoints
    (tmp_path / "file").write_text("x")
    (tmp_path / "out" / "adaptive.json").mkdir(parents=True)
    for out, why in ((tmp_path / "file", "file' is not a folder"),
                     (tmp_path / "file" / "docs", "file' is not a folder"),
                     (tmp_path / "out", "adaptive.json' is a folder")):  # fmt: skip
        with pytest.raises(SystemExit) as raised:
            adaptive_report.main(["--residual", str(residual), "--adaptive", str(adaptive),
                                  *QUICK, "--out", str(out)])  # fmt: skip
        error = capsys.readouterr().err.strip()
        assert raised.value.code == 2 and "\n" not in error
        assert "error: --out " in error and why in error


def test_a_target_policy_is_refused_by_an_env_that_reads_deltas(checkpoints):
    from rwalk import presets
    from rwalk.envs.torchrl_env import BatchedEnv
    from rwalk.evaluation import load_policy

    _, adaptive = checkpoints
    env = BatchedEnv(1, presets.evaluation_config("adaptive_gait", settle_steps=0,
                                                  command_range=(0.1, 0.1)),
                     task="adaptive_gait")  # fmt: skip
    with pytest.raises(ValueError, match="target; the env reads its action as 'delta'"):
        load_policy(adaptive, env)


def test_robustness_walks_each_policy_on_an_env_of_its_task(checkpoints, tmp_path, capsys):
    from rwalk.runners import robustness

    residual, adaptive = checkpoints
    out = tmp_path / "r.json"
    robustness.main(["--checkpoint", f"residual={residual}", "--checkpoint", f"adaptive={adaptive}",
                     "--episodes", "2", "--max-steps", "20", "--settle-steps", "2",
                     "--conditions", "rougher", "--json", str(out)])  # fmt: skip
    rows = json.loads(out.read_text())["rows"]
    assert [r["policy"] for r in rows] == ["base gait", "residual", "adaptive"]
    assert "| rougher | adaptive | " in capsys.readouterr().out


def test_the_fall_interval_is_wilson_s():
    from rwalk.evaluation import Evaluation, fall_interval

    def falls(rate, n):
        return fall_interval(Evaluation("x", n, 0.0, rate, 0.1, 0.0, 0.0, 0.0, 1.0))

    assert falls(0.0, 100) == pytest.approx((0.0, 0.03699), abs=1e-5)  # 1.96² / (100 + 1.96²)
    assert falls(0.5, 100) == pytest.approx((0.4038, 0.5962), abs=1e-4)
    assert falls(1.0, 10) == pytest.approx((0.7225, 1.0), abs=1e-4)


def test_a_trained_policys_gait_at_each_speed_reads_its_checkpoint(checkpoints):
    adaptive = checkpoints[1]
    stats = ae.gait_at_speeds(adaptive, episodes=2, seed=3, steps=55)
    assert [s.kind for s in stats] == [f"{v:g} m/s" for v in ae.SPEEDS]
    low = (0.01, 0.0, 0.3, 0.05)  # the trained bounds' lows (AdaptiveGaitConfig's defaults)
    high = (0.04, 0.16, 0.9, 0.09)
    for s in stats:
        assert s.episodes == 2 and len(s.mean) == len(ae.MEASURED)
        params = zip(low, s.mean[:4], high, strict=True)
        assert all(lo - 1e-9 <= m <= hi + 1e-9 for lo, m, hi in params)
