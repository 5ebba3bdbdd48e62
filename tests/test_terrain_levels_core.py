"""The core on a terrain-levels map: starts on each env's pad, the curriculum, the
privileged pieces, the observation from the episode's start, and the robustness runner."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest
import torch

from rwalk import EnvConfig, ResidualWalkVecEnv, robustness
from rwalk.constants import FOOT_SITES, OBS_POS
from rwalk.core import Core
from rwalk.evaluation import Evaluation
from rwalk.levels import TerrainLevels
from rwalk.perturbations import Pushes
from rwalk.presets import PAD_SPREAD, training_config
from rwalk.randomization import Randomization
from rwalk.runners import robustness as robustness_runner
from rwalk.starts import sensor_observation as _observation
from rwalk.wrappers import RslRlVecEnv

SMALL = TerrainLevels(levels=4, tile_length=3.0, pad_length=0.8, seed=1)


def config(**kw) -> EnvConfig:
    base = dict(
        terrain_levels=SMALL, settle_steps=20, randomize=True, position_noise=PAD_SPREAD,
        max_episode_steps=50,
    )  # fmt: skip
    return EnvConfig(**(base | kw))


def test_each_env_starts_on_the_pad_of_its_tile():
    levels = SMALL
    c = Core(config(terrain_levels=TerrainLevels(**{**vars(levels), "start_level": 2})), 8)
    c.reset()
    origins = c.terrain_map.origins(np.full(8, 2), np.arange(8) % len(levels.kinds))
    xy = c.obs[:, OBS_POS.start : OBS_POS.start + 2].numpy()
    # spread +-0.1 m, then 20 steps of gait walk forward by a few cm
    assert np.all(np.abs(xy[:, 1] - origins[:, 1]) < 0.15)
    assert np.all((xy[:, 0] - origins[:, 0] > -0.15) & (xy[:, 0] - origins[:, 0] < 0.3))
    assert torch.equal(c.terrain_kind, torch.arange(8) % 4)


def test_pool_starts_move_to_the_env_s_pad_with_their_observation():
    c = Core(config(settle_pool=4, settle_reuse=1), 4, seed=2)
    c.reset()
    c.terrain_level[1] = 3
    c.reset(np.array([1]))
    origin = c.terrain_map.origin(3, 1)
    assert abs(float(c.obs[1, 0]) - origin[0]) < 0.3 and abs(float(c.obs[1, 1]) - origin[1]) < 0.15
    # the torso moved with its observation (the imu site sits within mm of the torso origin)
    assert np.abs(c.sim.qpos[1, :2] - c.obs[1, :2].numpy()).max() < 0.005
    c.step(torch.zeros(4, 12))
    assert abs(float(c.obs[1, 1]) - origin[1]) < 0.15  # it walks on there, no jump


def test_the_curriculum_moves_levels_by_the_distance_walked():
    c = Core(config(terrain_levels=TerrainLevels(**{**vars(SMALL), "start_level": 1})), 4)
    c.reset()
    v = c.config.expected_velocity
    c.walked_steps[:] = 100
    expected = v * 100 * c.control_dt
    c.episode_distance[:] = torch.tensor([0.9, 0.5, 0.2, 0.9], dtype=torch.float64) * expected
    c.fell[:] = torch.tensor([False, False, False, True])
    c.reset()
    # >= 0.7 up; between 0.35 and 0.7 stays; < 0.35 down; a fall down
    assert c.terrain_level.tolist() == [2, 1, 0, 0]
    fixed = Core(config(terrain_levels=TerrainLevels(**{**vars(SMALL), "curriculum": False})), 2)
    fixed.reset()
    fixed.walked_steps[:] = 100
    fixed.fell[:] = True
    fixed.reset()
    assert fixed.terrain_level.tolist() == [0, 0]


def test_a_fall_is_recorded_for_the_curriculum():
    c = Core(config(), 2)
    c.reset()
    c.sim.qpos[0, 3:7] = (0.0, 1.0, 0.0, 0.0)  # upside down
    result = c.step(torch.zeros(2, 12))
    assert bool(result.terminated[0]) and c.fell.tolist() == [True, False]


def test_heights_piece_is_each_foot_above_the_ground_around_it():
    c = Core(config(), 2, seed=4)
    c.reset()
    c.sim.forward()  # sensors at the current state, where mj_forward puts the sites
    c.obs.copy_(_observation(c._sensors))
    data = mujoco.MjData(c.model)
    heights = c.piece("heights").view(2, 4, 5)
    for i in range(2):
        c.sim.batch.get_data(i, data)
        mujoco.mj_forward(c.model, data)
        for leg, site in enumerate(FOOT_SITES):
            x, y, z = data.site(site).xpos
            for s, (dx, dy) in enumerate(((0, 0), (0.03, 0), (-0.03, 0), (0, 0.03), (0, -0.03))):
                ground = float(c.terrain.heights_at(torch.tensor(x + dx), torch.tensor(y + dy)))
                assert float(heights[i, leg, s]) == pytest.approx(z - ground, abs=1e-9)
            # the teacher's lighter piece (--teacher-obs heights_under_feet): under it only
            assert float(c.piece("heights_under_feet")[i, leg]) == float(heights[i, leg, 0])
    # on the flat pad the ground is at 0 under every sample: all five agree
    assert torch.allclose(heights, heights[..., :1].expand_as(heights), atol=1e-12)


def test_observation_from_start_hides_where_on_the_map_an_env_is():
    c = Core(config(), 3)
    c.reset()
    local = c.piece("observation_from_start")
    assert torch.equal(local[:, :2], torch.zeros(3, 2, dtype=torch.float64))
    assert torch.equal(local[:, 2:], c.obs[:, 2:])
    c.step(torch.zeros(3, 12))
    local = c.piece("observation_from_start")
    assert torch.equal(local[:, 0], c.obs[:, 0] - c.x0)
    assert c.piece_size("observation_from_start") == 65


def test_bad_map_settings_name_the_field():
    with pytest.raises(ValueError, match="terrain level outside the map"):
        TerrainLevels(levels=4, start_level=4)
    with pytest.raises(
        ValueError, match=r"EnvConfig.terrain_scale must be 1\.0 with terrain_levels"
    ):
        config(terrain_scale=0.5)
    c = Core(config(), 1)
    with pytest.raises(ValueError, match="cannot change a terrain-levels map"):
        c.set_terrain_scale(0.5)


def test_same_seed_same_world_and_trajectory_at_any_thread_count():
    kw = dict(randomization=Randomization(), pushes=Pushes(interval=(0.1, 0.3)), settle_pool=2)
    runs = []
    for threads in (1, 2):
        c = Core(config(num_threads=threads, **kw), 6, seed=9)
        c.reset()
        trace = []
        for step in range(40):
            result = c.step(torch.full((6, 12), 0.2 * (-1) ** step))
            done = (result.terminated | result.truncated).nonzero().squeeze(-1)
            c.reset(done.numpy())
            trace.append(c.obs.clone())
        runs.append((torch.stack(trace), c.physics.params.clone(), c.terrain_level.clone()))
    assert all(torch.equal(a, b) for a, b in zip(*runs, strict=True))


def test_robust_training_logs_the_levels_and_gives_the_critic_privileged_pieces():
    cfg = training_config(num_envs=8, robust=True, settle_steps=5, max_episode_steps=3)
    env = RslRlVecEnv(ResidualWalkVecEnv(8, cfg, seed=0))
    assert env.groups["critic"][-2:] == ("physics", "heights")
    log = {}
    for _ in range(4):
        _, _, _, extras = env.step(torch.zeros(8, 12))
        log |= extras.get("log", {})
    assert {"Curriculum/terrain_level", "Curriculum/level_rough", "Curriculum/level_stones"} <= set(
        log
    )
    assert float(log["Curriculum/terrain_level"]) == float(env.core.terrain_level.double().mean())


def test_robustness_conditions_and_floors():
    for name in robustness.CONDITIONS:
        assert isinstance(robustness.condition_config(name), EnvConfig)
    assert robustness.condition_config("payload").randomization.payload == (0.2, 0.2)
    assert robustness.condition_config("new maps", map_level=3).terrain_levels.start_level == 3
    with pytest.raises(ValueError, match="unknown condition 'moon'"):
        robustness.condition_config("moon")
    with pytest.raises(ValueError, match="terrain level outside the map"):
        robustness.condition_config("new maps", map_level=10)

    def row(condition, policy, falls, error, bias=0.0):
        e = Evaluation(policy, 100, 0.0, falls, 0.1, error, 0.001, 0.0, 1000.0,
                       velocity_bias=bias)  # fmt: skip
        return robustness.Row(condition, policy, e)

    # held out: falls <= 3% and <= 1/4 of the base gait's, error <= 0.03 and <= 1/2 of its,
    # |bias| <= 0.01
    rows = [row("payload", "base gait", 0.12, 0.08), row("payload", "a", 0.03, 0.03, -0.01),
            row("payload", "b", 0.04, 0.01), row("payload", "c", 0.0, 0.031),
            row("payload", "d", 0.0, 0.02, 0.011)]  # fmt: skip
    assert robustness.floors(rows) == {"a": "met", "b": "missed", "c": "missed", "d": "missed"}
    # nominal: falls <= 2%, error <= 0.02, |bias| <= 0.005
    nominal = [row("nominal", "base gait", 0.1, 0.08), row("nominal", "a", 0.02, 0.02, 0.005),
               row("nominal", "b", 0.0, 0.021), row("nominal", "c", 0.0, 0.01, -0.006)]  # fmt: skip
    assert robustness.floors(nominal) == {"a": "met", "b": "missed", "c": "missed"}


def test_robustness_runs_paired_episodes_and_writes_its_rows(tmp_path, capsys):
    out = tmp_path / "r.json"
    robustness_runner.main(
        ["--episodes", "2", "--max-steps", "20", "--settle-steps", "5", "--conditions",
         "pushes", "new maps", "--json", str(out), "--plot", str(tmp_path / "r.png")]
    )  # fmt: skip
    data = json.loads(out.read_text())
    assert [(r["condition"], r["policy"]) for r in data["rows"]] == [
        ("pushes", "base gait"),
        ("new maps", "base gait"),
    ]
    assert data["rows"][0]["evaluation"]["episodes"] == 2
    assert (tmp_path / "r.png").stat().st_size > 0
    printed = capsys.readouterr().out
    assert "| pushes | base gait |" in printed
    robustness_runner.main(["--tables", str(out)])
    assert "| new maps | base gait |" in capsys.readouterr().out


def test_robustness_splits_a_map_s_rows_by_kind_of_tile(tmp_path, capsys):
    out = tmp_path / "r.json"
    robustness_runner.main(
        ["--episodes", "8", "--max-steps", "30", "--settle-steps", "5", "--conditions",
         "new maps", "pushes", "--by-kind", "--json", str(out)]
    )  # fmt: skip
    rows = robustness.read_rows(out)
    kinds = TerrainLevels().kinds
    assert [r.condition for r in rows] == (
        ["new maps"] + [f"new maps: {kind}" for kind in kinds] + ["pushes"]  # pushes: no map
    )
    whole, parts = rows[0].evaluation, [r.evaluation for r in rows[1:-1]]
    assert [p.episodes for p in parts] == [2] * len(kinds)  # env i walks kind i mod 4
    # the kinds' rows split the whole row's episodes: the falls add up, the means average
    assert sum(round(p.fall_rate * 2) for p in parts) == round(whole.fall_rate * 8)
    for field in ("velocity_error", "velocity_bias", "forward_velocity", "mean_return"):
        mean = sum(getattr(p, field) for p in parts) / len(parts)
        assert mean == pytest.approx(getattr(whole, field), rel=1e-12), field
    assert "| new maps: stones | base gait |" in capsys.readouterr().out


def test_robustness_refuses_outputs_it_could_not_write_before_any_row(
    tmp_path, monkeypatch, capsys
):
    def never(*args, **kwargs):
        raise AssertionError("a row ran before the refusal")

    monkeypatch.setattr(robustness_runner, "run_condition", never)
    file = tmp_path / "file"
    file.write_text("x")
    for flag, path, why in (("--json", file / "r.json", "is not a folder"),
                            ("--json", tmp_path, "is a folder"),
                            ("--plot", file / "r.png", "is not a folder")):  # fmt: skip
        with pytest.raises(SystemExit) as exit_:
            robustness_runner.main(["--episodes", "2", "--conditions", "pushes", flag, str(path)])
        err = capsys.readouterr().err.strip()
        assert exit_.value.code == 2 and "\n" not in err
        assert f"error: {flag} " in err and why in err


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--conditions", "moon"], "--conditions must be some of 'nominal', 'new maps'"),
        (["--conditions"], "--conditions needs at least one of 'nominal'"),
        (["--episodes", "0"], "--episodes must be >= 1, got 0"),
        (["--map-level", "99"], "--map-level: level 99 is a terrain level outside the map"),
        (["--checkpoint", "a=nope.pt"], "--checkpoint a: checkpoint 'nope.pt' not found"),
        (["--checkpoint", "x/m.pt", "--checkpoint", "x=y/m.pt"], "two checkpoints are labelled"),
    ],
)
def test_robustness_names_a_bad_flag_in_one_line(flags, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        robustness_runner.parse_args(flags)
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "\n" not in err and message in err


def test_envs_passing_the_top_restart_at_a_drawn_level():
    top = TerrainLevels(**{**vars(SMALL), "start_level": 3})
    c = Core(config(terrain_levels=top), 64, seed=3)
    c.reset()
    c.walked_steps[:] = 100
    c.episode_distance[:] = c.config.expected_velocity * 100 * c.control_dt
    c.reset()
    levels = c.terrain_level
    assert set(levels.tolist()) == {0, 1, 2, 3}  # uniform over the map's 4 levels
    again = Core(config(terrain_levels=top), 64, seed=3)
    again.reset()
    again.walked_steps[:] = 100
    again.episode_distance[:] = again.episode_distance + c.config.expected_velocity * 2
    again.reset()
    assert torch.equal(again.terrain_level, levels)  # the same keys, the same draws
    stay = Core(config(terrain_levels=TerrainLevels(**{**vars(top), "recycle": False})), 4)
    stay.reset()
    stay.walked_steps[:] = 100
    stay.episode_distance[:] = 10.0
    stay.reset()
    assert stay.terrain_level.tolist() == [3, 3, 3, 3]


def test_review_episodes_start_at_or_below_the_env_s_level_and_do_not_move_it():
    levels = TerrainLevels(**{**vars(SMALL), "start_level": 3, "review": 0.5})
    c = Core(config(terrain_levels=levels), 64, seed=4)
    c.reset()
    cur = c.curriculum
    reviewing, review_level = cur.reviewing.clone(), cur.review_level.clone()
    assert 16 < int(reviewing.sum()) < 48  # about half of 64 (binomial: 32 +- 4)
    assert set(review_level[reviewing].tolist()) == {0, 1, 2, 3}  # uniform over 0..3
    # every env starts on the pad of its episode's tile
    level = torch.where(reviewing, review_level, cur.terrain_level)
    origins = c.terrain_map.origins(level.numpy(), c.terrain_kind.numpy())
    xy = c.obs[:, OBS_POS.start : OBS_POS.start + 2].numpy()
    assert np.all(np.abs(xy[:, 1] - origins[:, 1]) < 0.15)
    assert np.all((xy[:, 0] - origins[:, 0] > -0.15) & (xy[:, 0] - origins[:, 0] < 0.3))
    # a walk far too short demotes the envs that walked their own level, not the reviewers
    c.walked_steps[:] = 100
    c.episode_distance[:] = 0.0
    c.reset()
    assert torch.equal(c.terrain_level, torch.where(reviewing, 3, 2))
    again = Core(config(terrain_levels=levels), 64, seed=4)
    again.reset()
    assert torch.equal(again.curriculum.reviewing, reviewing)  # the same keys, the same draws
    assert torch.equal(again.curriculum.review_level, review_level)
    plain = Core(config(terrain_levels=TerrainLevels(**{**vars(levels), "review": 0.0})), 64)
    plain.reset()
    assert not plain.curriculum.reviewing.any()


def test_flattened_kinds_walk_level_0_and_stay_there():
    levels = TerrainLevels(**{**vars(SMALL), "start_level": 2, "review": 0.5})
    c = Core(config(terrain_levels=levels), 8, seed=5)
    c.reset()
    cur = c.curriculum
    stones = cur.flatten(("stones",))  # kind 3 of rough, slopes, steps, stones
    assert stones.tolist() == [False, False, False, True] * 2
    assert c.terrain_level.tolist() == [2, 2, 2, 0] * 2 and not cur.reviewing[stones].any()
    # a walk long enough to promote: the others move (or review), the stones envs stay at
    # level 0 and never review
    c.walked_steps[:] = 100
    c.episode_distance[:] = c.config.expected_velocity * 100 * c.control_dt
    c.reset()
    assert c.terrain_level[stones].tolist() == [0, 0] and not cur.reviewing[stones].any()
    assert (c.terrain_level[~stones] == 3).any()
    origins = c.terrain_map.origins(np.zeros(2, dtype=np.int64), np.array([3, 3]))
    xy = c.obs[stones, OBS_POS.start : OBS_POS.start + 2].numpy()
    assert np.all(np.abs(xy[:, 1] - origins[:, 1]) < 0.15)  # on level 0's stones pad
    with pytest.raises(ValueError, match=r"no 'flat' tiles to flatten: the map's kinds are"):
        cur.flatten(("flat",))
    # released, each restarts on a level drawn from the map's 4, as a pass past the top
    many = Core(config(terrain_levels=levels), 64, seed=5)
    many.reset()
    ours = many.curriculum.flatten(("stones",))
    assert torch.equal(many.curriculum.release(("stones",)), ours)
    assert not many.curriculum.flat.any()
    assert set(many.terrain_level[ours].tolist()) == {0, 1, 2, 3}
    again = Core(config(terrain_levels=levels), 64, seed=5)
    again.reset()
    again.curriculum.flatten(("stones",))
    again.curriculum.release(("stones",))
    assert torch.equal(again.terrain_level, many.terrain_level)  # the same keys, the same draws


def test_envs_on_floor_kinds_never_walk_below_their_floor():
    """Stones envs with floor_level 2 start there, a demotion stops there, and their
    review, redrawn and released levels are drawn from 2 up; the other kinds as before."""
    levels = TerrainLevels(**{**vars(SMALL), "review": 0.5, "floor_kinds": ("stones",),
                              "floor_level": 2})  # fmt: skip
    c = Core(config(terrain_levels=levels), 64, seed=6)
    c.reset()
    cur, stones = c.curriculum, c.terrain_kind == 3  # kind 3 of rough, slopes, steps, stones
    assert c.terrain_level.tolist() == [0, 0, 0, 2] * 16
    assert cur.floor.tolist() == [0, 0, 0, 2] * 16
    assert set(cur.review_level[cur.reviewing & stones].tolist()) == {2}  # from 2 to 2
    origins = c.terrain_map.origins(np.full(16, 2), np.full(16, 3))
    xy = c.obs[stones & ~cur.reviewing, OBS_POS.start : OBS_POS.start + 2].numpy()
    assert np.all(np.abs(xy[:, 1] - origins[: len(xy), 1]) < 0.15)  # on level 2's pad
    c.walked_steps[:] = 100
    c.episode_distance[:] = 0.0  # far too short: a demotion
    c.reset()
    assert c.terrain_level.tolist() == [0, 0, 0, 2] * 16
    top = TerrainLevels(**{**vars(levels), "start_level": 3, "review": 0.0})
    t = Core(config(terrain_levels=top), 64, seed=6)
    t.reset()
    t.walked_steps[:] = 100
    t.episode_distance[:] = t.config.expected_velocity * 100 * t.control_dt
    t.reset()  # past the top: redrawn
    drawn = t.terrain_level.clone()
    assert set(drawn[stones].tolist()) == {2, 3}
    assert set(t.terrain_level[~stones].tolist()) == {0, 1, 2, 3}
    t.curriculum.flatten(("stones",))
    t.curriculum.release(("stones",))
    assert set(t.terrain_level[stones].tolist()) == {2, 3}
    t.curriculum.load_checkpoint({"terrain_level": torch.zeros(64, dtype=torch.long)})
    assert t.terrain_level.tolist() == [0, 0, 0, 2] * 16  # a saved level under the floor
    unfloored = TerrainLevels(**{**vars(top), "floor_kinds": (), "floor_level": 0})
    plain = Core(config(terrain_levels=unfloored), 64, seed=6)
    plain.reset()
    plain.walked_steps[:] = 100
    plain.episode_distance[:] = t.config.expected_velocity * 100 * t.control_dt
    plain.reset()  # the same keys: floor 0 draws what the map's draws were before floors
    assert torch.equal(plain.terrain_level[~stones], drawn[~stones])


def test_checkpoints_carry_the_curriculum(tmp_path):
    import contextlib
    import dataclasses
    import io

    from rwalk.rl.config import TrainArgs as Args
    from rwalk.rl.runner import SafeRunner
    from rwalk.rl.training import make_env, rsl_rl_config

    args = dataclasses.replace(
        Args(), num_envs=8, settle_steps=2, max_episode_steps=30, hidden_dims=(8,)
    )

    def runner():
        with contextlib.redirect_stdout(io.StringIO()):
            return SafeRunner(make_env(args), rsl_rl_config(args), log_dir=None, device="cpu")

    first = runner()
    first.env.core.terrain_level.copy_(torch.arange(8) % 10)
    first.save(str(tmp_path / "model_0.pt"))
    second = runner()
    assert second.env.core.terrain_level.tolist() == [0] * 8
    second.load(str(tmp_path / "model_0.pt"))
    assert second.env.core.terrain_level.tolist() == list(range(8))


def test_levels_of_another_number_of_envs_carry_over_by_kind_of_tile():
    saved = {"terrain_level": torch.tensor([1, 2, 3, 0, 2])}  # 5 envs on 4 kinds
    more = Core(config(), 10).curriculum
    note = more.load_checkpoint(saved)
    # env j (kind j % 4) takes the saved envs of its kind in turn: kind 0 has saved envs
    # 0 and 4, kinds 1-3 one each
    assert more.terrain_level.tolist() == [1, 2, 3, 0, 2, 2, 3, 0, 1, 2]
    assert "5 envs, this run has 10" in note
    fewer = Core(config(), 3).curriculum
    assert fewer.load_checkpoint(saved) is not None
    assert fewer.terrain_level.tolist() == [1, 2, 3]  # the first ones
    too_few = Core(config(), 4).curriculum
    note = too_few.load_checkpoint({"terrain_level": torch.tensor([3, 3])})  # no kind 2, 3
    assert "starts again at the start level" in note and too_few.terrain_level.tolist() == [0] * 4
