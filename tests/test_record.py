"""One config story: a run's record (config.json) is its resolved configs; every nested field
is a flag; older records migrate once; a task owns its identity."""

import dataclasses
import hashlib
import json
import re
from pathlib import Path

import pytest
import torch

from rwalk import episodes, presets
from rwalk.config import EnvConfig, with_fields
from rwalk.core import Core
from rwalk.machine import describe
from rwalk.randomization import Randomization
from rwalk.rewards import GaitCosts, Shaping
from rwalk.rl import record
from rwalk.rl.config import Training, student_training
from rwalk.rl.legacy import TrainArgs, from_flags
from rwalk.rl.record import ConfigError, read_machines, read_record, record_of, write_record
from rwalk.rl.torchrl_config import TorchRLTraining
from rwalk.runners import train, train_torchrl
from rwalk.tasks import AdaptiveGaitConfig

ROOT = Path(__file__).resolve().parents[1]
RECORDS = Path(__file__).parent / "data" / "records"
SMALL = ["--num-envs", "6", "--settle-steps", "4", "--max-episode-steps", "40", "--threads", "1"]
#: SMALL with the plain training (PPO alone, the late kernel): the default before --recipe.
PLAIN = [*SMALL, "--recipe", "plain"]
#: The four kinds of run whose records must rebuild their envs bit for bit.
KINDS = {
    "default": [],
    "adaptive teacher": ["--task", "adaptive_gait", "--command-range", "0.05", "0.25", "--costs",
                         "--terrain-kinds", "flat", "rough", "slopes", "steps", "stones",
                         "--teacher"],
    "no-robust": ["--no-robust", "--terrain-scale", "0.7"],
}  # fmt: skip


def trace(config: EnvConfig, num_envs: int, seed: int, steps: int = 130, terms: bool = True
          ) -> str:  # fmt: skip
    """sha256 of every observation, reward (and reward term, unless not ``terms``) and
    ending of ``steps`` steps of random actions (episodes of 40 steps: resets from the
    settled-start pool)."""
    core = Core(config, num_envs, seed=seed)
    core.reset()
    generator = torch.Generator().manual_seed(7)
    digest = hashlib.sha256()
    for _ in range(steps):
        action = torch.rand(num_envs, core.task.action_dim, generator=generator) * 2 - 1
        result, _ = episodes.step(core, action.double())
        pieces = [core.piece(name) for name in core.task.pieces()]
        ends = (result.obs, result.reward, result.terminated, result.truncated)
        for tensor in (*ends, *(result.terms.values() if terms else ()), *pieces):
            digest.update(tensor.numpy().tobytes())
    return digest.hexdigest()


def trainings() -> dict[str, Training]:
    runs = {name: train.parse_args([*SMALL, *flags]) for name, flags in KINDS.items()}
    teacher = dataclasses.replace(runs["adaptive teacher"].train, student_iterations=3)
    runs["student"] = student_training(dataclasses.replace(runs["adaptive teacher"], train=teacher))
    return runs


@pytest.mark.parametrize("name", ["default", "adaptive teacher", "student", "no-robust"])
def test_the_env_built_from_the_record_is_the_env_the_run_trained_in(name, tmp_path):
    training = trainings()[name]
    write_record(tmp_path / "config.json", training)
    saved = read_record(tmp_path / "config.json")
    assert saved == training
    built = trace(training.env_config(), training.num_envs, training.run.seed)
    assert trace(saved.env_config(), saved.num_envs, saved.run.seed) == built


def test_the_command_line_builds_what_the_older_flags_built():
    # Bits unchanged: the plain training (the default before --recipe) and its --no-robust
    # world, as the schema-1 flags (and presets) built them before the configs became the
    # record; two changes since: the plain training's last 100 iterations draw the model's
    # physics, and its last 50 train with the speed kernel (its terms at weight 0 before:
    # exact zeros).
    plain, no_robust = ["--recipe", "plain"], ["--recipe", "plain", "--no-robust"]
    for flags, old, stage, late in ((plain, {}, 100, 50), (no_robust, {"robust": False}, 0, 0)):
        new = train.parse_args([*SMALL, *flags])
        args = dataclasses.replace(TrainArgs(), num_envs=6, settle_steps=4, max_episode_steps=40,
                                   threads=1, **old)  # fmt: skip
        migrated = from_flags(args)
        assert migrated.train.nominal_physics_iterations == 0  # the schema-1 code had no stage
        assert migrated.train.late_iterations == 0
        keep = new.train.nominal_physics_keep
        staged = dataclasses.replace(migrated.train, nominal_physics_iterations=stage,
                                     nominal_physics_keep=keep, late_iterations=late,
                                     late_tracking=200.0 if late else None)  # fmt: skip
        env = dataclasses.replace(migrated.env, shaping=Shaping() if late else None)
        assert new == dataclasses.replace(migrated, env=env, train=staged)
        legacy = args.env.config(threads=1)
        unshaped = dataclasses.replace(new.env_config(), shaping=None)
        assert trace(unshaped, 6, 0) == trace(legacy, 6, 0)
        # the kernel at weight 0 adds its terms and not a bit to the reward
        assert trace(new.env_config(), 6, 0, terms=False) == trace(legacy, 6, 0, terms=False)


#: The residual task's recipe (ResidualWalk.recipe) as the flags docs/learning.md gives.
RECIPE_FLAGS = [
    "--recipe", "plain", "--costs", "--env.costs.power", "2", "--env.shaping.tracking", "300",
    "--env.shaping.sigma", "0.02", "--terrain-kinds", "flat", "rough", "slopes", "steps",
    "stones", "--max-iterations", "420", "--late-iterations", "0", "--teacher", "--teacher-obs",
    "physics", "heights_under_feet", "--student-iterations", "160", "--student-actor", "gru",
    "--distill-levels", "--env.randomization.kp-scale", "0.75", "1.15",
    "--env.randomization.force-scale", "0.75", "1.15", "--env.randomization.latency", "0", "3",
    "--env.residual-scale", "0.03", "--env.observation-noise.torso-forward-speed", "0.045",
    "--student-num-envs", "3",  # half of SMALL's 6
]  # fmt: skip


def test_a_recipes_fields_are_set_by_their_paths_a_missing_part_at_its_defaults():
    plain = EnvConfig()
    assert plain.costs is None and plain.randomization is None
    made = with_fields(plain, {"costs.power": 2.0, "randomization.latency": (0, 3),
                               "residual_scale": 0.03})  # fmt: skip
    assert made.costs == dataclasses.replace(GaitCosts(), power=2.0)
    assert made.randomization == dataclasses.replace(Randomization(), latency=(0, 3))
    assert made.residual_scale == 0.03 and plain.costs is None  # a new config
    narrow = with_fields(AdaptiveGaitConfig(), {"bounds.body_height.low": 0.06})
    assert narrow.bounds.body_height == (0.06, 0.09, 0.001)  # a field of a NamedTuple
    assert narrow.bounds.step_height == AdaptiveGaitConfig().bounds.step_height
    with pytest.raises(ValueError, match=r"GaitCosts.power must be a finite number.*nan"):
        with_fields(plain, {"costs.power": float("nan")})  # checked as the flag is


def test_the_default_training_is_the_recipe_that_its_flags_give():
    default, given = train.parse_args(SMALL), train.parse_args([*SMALL, *RECIPE_FLAGS])
    assert default.preset.recipe == "precise" and given.preset.recipe == "plain"
    assert default.env == given.env
    assert (default.train, default.run) == (given.train, given.run)
    assert default.train.nominal_physics_iterations == 140  # a third of 420


def test_a_flag_sets_a_field_the_recipe_sets():
    default = train.parse_args(SMALL)
    assert default.env.residual_scale == 0.03 and default.env.randomization.latency == (0, 3)
    assert default.env.observation_noise.forward_speed == 0.045  # x3 torso_linvel's 0.015
    wide = (0.75, 1.15)
    assert default.env.randomization.kp_scale == default.env.randomization.force_scale == wide
    given = train.parse_args(
        [*SMALL, "--env.residual-scale", "0.02", "--env.randomization.latency", "0", "2"]
    )
    assert given.env.residual_scale == 0.02 and given.env.randomization.latency == (0, 2)
    assert given.env.randomization.kp_scale == wide  # the recipe's, not given
    plain = train.parse_args([*SMALL, "--recipe", "plain"])
    assert plain.env.residual_scale == 0.02 and plain.env.randomization.latency == (0, 2)
    assert plain.env.randomization.kp_scale == (0.85, 1.15)
    assert plain.env.observation_noise.forward_speed == 0.015  # torso_linvel's
    given = train.parse_args([*SMALL, "--env.observation-noise.torso-forward-speed", "0.03"])
    assert given.env.observation_noise.forward_speed == 0.03


@pytest.mark.parametrize("flags", [["--no-teacher"], ["--distill", "logs/teacher"]])
def test_a_run_without_a_teacher_keeps_the_rest_of_the_recipe(flags):
    training = train.parse_args([*SMALL, *flags])
    assert not training.train.teacher and training.train.student_iterations == 0
    assert not training.train.distill_levels and training.train.teacher_obs == (
        "physics",
        "heights",
    )
    assert training.env.costs.power == 2.0 and training.env.shaping.tracking == 300.0
    assert training.run.max_iterations == 420 and training.train.late_iterations == 0


@pytest.mark.parametrize("flags", [["--student-iterations", "0"], ["--student-iterations=0"]])
def test_a_teacher_alone_needs_no_more_flags(flags):
    """--student-iterations 0 leaves the student's start on its teacher's levels out too
    (it used to need --no-distill-levels); the rest is the recipe's."""
    training = train.parse_args([*SMALL, *flags])
    assert training.train.teacher and training.train.student_iterations == 0
    assert not training.train.distill_levels
    assert training.train.teacher_obs == ("physics", "heights_under_feet")
    assert training.env.observation_noise.forward_speed == 0.045
    assert train.parse_args(SMALL).train.distill_levels  # a student: the recipe's


@pytest.mark.parametrize(
    "flags",
    [["--recipe", "plain"], ["--no-robust"], ["--task", "adaptive_gait", "--recipe", "plain"],
     ["--task", "adaptive_gait", "--no-robust"]],
)  # fmt: skip
def test_only_a_robust_world_trains_its_tasks_recipe(flags):
    training = train.parse_args([*SMALL, *flags])
    assert not training.train.teacher and training.run.max_iterations == 300
    assert training.env.costs is None
    assert training.preset.own_recipe is None


#: The adaptive task's recipe (AdaptiveGait.recipe) as the flags docs/adaptive.md gave
#: before it was one (the adaptive default's command of 2026-12-07).
ADAPTIVE_RECIPE_FLAGS = [
    "--task", "adaptive_gait", "--recipe", "plain", "--costs", "--command-range", "0.03",
    "0.27", "--terrain-kinds", "flat", "rough", "slopes", "steps", "stones",
    "--max-iterations", "500", "--env.bounds.body-height.low", "0.0699",
    "--env.bounds.body-height.high", "0.0701", "--env.bounds.step-length.low", "0.04",
    "--env.bounds.cycle-time.low", "0.45", "--env.costs.power", "2",
    "--env.shaping.tracking", "300", "--env.shaping.sigma", "0.02", "--gait-action",
    "schedule", "--env.gait.step-height", "0.013", "--env.gait.duty-factor", "0.55",
    "--env.schedule-step-rise", "0.04", "--env.schedule-window", "0", "0.25", "0.25", "1",
    "--teacher", "--student-iterations", "190", "--student-actor", "gru",
    "--distill-levels", "--finetune-iterations", "150",
    "--student-num-envs", "3",  # half of SMALL's 6
]  # fmt: skip


def test_the_adaptive_task_trains_its_default_from_its_recipe():
    default = train.parse_args([*SMALL, "--task", "adaptive_gait"])
    given = train.parse_args([*SMALL, *ADAPTIVE_RECIPE_FLAGS])
    assert default.preset.recipe == "precise" and default.preset.own_recipe is not None
    assert default.env == given.env
    assert (default.train, default.run) == (given.train, given.run)
    # the flags given on top of the recipe set the same values: the same run
    on_top = ["--task", "adaptive_gait", *ADAPTIVE_RECIPE_FLAGS[4:]]  # without --recipe plain
    assert train.parse_args([*SMALL, *on_top]).env == given.env
    narrower = train.parse_args([*SMALL, "--task", "adaptive_gait", "--command-range",
                                 "0.05", "0.25", "--no-teacher"])  # fmt: skip
    assert narrower.env.command_range == (0.05, 0.25) and not narrower.train.teacher
    assert default.train.finetune_iterations == 150 and narrower.train.finetune_iterations == 0
    alone = train.parse_args([*SMALL, "--task", "adaptive_gait", "--student-iterations", "0"])
    assert alone.train.teacher and alone.train.finetune_iterations == 0  # no student to tune
    assert narrower.env.gait_action == "schedule" and narrower.run.max_iterations == 500


def test_a_recipe_not_known_and_a_recipe_torchrl_does_not_train_are_refused(capsys):
    with pytest.raises(SystemExit):
        train.parse_args(["--recipe", "fast"])
    assert "--recipe" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        train_torchrl.parse_args(["--recipe", "precise"])
    error = capsys.readouterr().err
    assert "--recipe precise trains a teacher" in error and "--recipe plain" in error
    assert train_torchrl.parse_args([]).preset.recipe == "plain"


def test_a_record_from_before_the_recipe_reads_as_the_plain_training(tmp_path):
    training = train.parse_args(PLAIN)
    write_record(tmp_path / "config.json", training)
    saved = json.loads((tmp_path / "config.json").read_text())
    del saved["preset"]["recipe"]
    (tmp_path / "config.json").write_text(json.dumps(saved))
    assert read_record(tmp_path / "config.json") == training


def test_a_student_is_blind_and_trains_in_its_teachers_world():
    runs = trainings()
    teacher, student = runs["adaptive teacher"], runs["student"]
    # (the adaptive recipe's student on half its teacher's envs, its settled starts too)
    assert student.num_envs == teacher.train.student_num_envs == 3
    assert student.env == dataclasses.replace(teacher.env, settle_pool=student.env.settle_pool)
    assert student.train.distill == teacher.run.log_dir
    assert "physics" in teacher.train.policy_obs and "physics" not in student.train.policy_obs
    assert student.run.log_dir == str(Path(teacher.run.log_dir) / "student")


@pytest.mark.parametrize(
    ("name", "trainer", "cls"),
    [("v1_rwalk_train", "rsl_rl", Training), ("v1_before_trainer_key", "rsl_rl", Training),
     ("v1_torchrl", "torchrl", TorchRLTraining)],
)  # fmt: skip
def test_an_older_record_is_migrated_to_its_resolved_configs(name, trainer, cls):
    migrated = read_record(RECORDS / f"{name}.json", trainer, cls)
    stored = json.loads((RECORDS / f"{name}.migrated.json").read_text())
    assert json.loads(json.dumps(record_of(migrated, trainer))) == stored
    assert read_record(RECORDS / f"{name}.migrated.json", trainer, cls) == migrated


def test_a_record_written_before_a_field_existed_reads_that_field_as_its_default(tmp_path):
    # Schema-2 records of this round were written before EnvConfig.shaping,
    # command_interval, TrainConfig.warm_start, nominal_physics_iterations and the
    # adaptive schedule's fields existed: a missing field is what the run trained with.
    data = json.loads((RECORDS / "v1_rwalk_train.migrated.json").read_text())
    del data["env"]["shaping"], data["env"]["command_interval"], data["train"]["warm_start"]
    del data["train"]["nominal_physics_iterations"]
    del data["env"]["schedule_stride"], data["env"]["schedule_window"]  # (2026-11-29)
    del data["train"]["distill_levels"]  # (2026-11-29, later)
    del data["train"]["teacher_obs"]  # (2026-11-29, thirty-first session)
    del data["env"]["costs"]["power_per_metre_above"]  # (2026-11-29, thirty-second)
    del data["env"]["schedule_step_rise"]  # (2026-12-02, forty-first)
    del data["env"]["observation_noise"]["torso_forward_speed"]  # (2026-12-06, sixty-ninth)
    del data["train"]["student_num_envs"]  # (2026-12-06, seventy-sixth)
    del data["train"]["distill_smoothness"]  # (2026-12-07, eighty-first)
    del data["train"]["lag_smoothness"]  # (2026-12-08, eighty-seventh)
    (tmp_path / "config.json").write_text(json.dumps(data))
    record = read_record(tmp_path / "config.json", "rsl_rl", Training)
    assert record.env.shaping is None and record.env.command_interval is None
    assert record == read_record(RECORDS / "v1_rwalk_train.json", "rsl_rl", Training)
    # Also where the default has changed since: the default training ends on a stage at
    # the model's physics, a record of it written before the field trained without one.
    data = record_of(train.parse_args(PLAIN))
    assert data["train"].pop("nominal_physics_iterations") == 100
    assert data["train"].pop("nominal_physics_entropy_coef") is None
    # and its last 50 iterations train with the speed kernel: a record written before the
    # late stage existed trained without one
    assert data["train"].pop("late_iterations") == 50
    assert data["train"].pop("late_tracking") == 200.0
    del data["train"]["late_sigma"], data["train"]["late_clearance_target"]
    (tmp_path / "config.json").write_text(json.dumps(data))
    old = read_record(tmp_path / "config.json").train
    assert old.nominal_physics_iterations == 0 and old.nominal_physics_entropy_coef is None
    assert old.late_iterations == 0 and old.late_tracking is None
    # a staged run recorded before the stage's entropy bonus kept --entropy-coef throughout
    data["train"]["nominal_physics_iterations"] = 100
    (tmp_path / "config.json").write_text(json.dumps(data))
    assert read_record(tmp_path / "config.json").train.nominal_physics_entropy_coef is None


@pytest.mark.parametrize(
    ("flags", "stage", "entropy"),
    [([], 100, None), (["--no-robust"], 0, None), (["--task", "adaptive_gait", "--costs"], 0, None),
     (["--nominal-physics-iterations", "0"], 0, None),
     (["--nominal-physics-iterations", "7", "--nominal-physics-entropy-coef", "0.002"], 7, 0.002),
     (["--nominal-physics-entropy-coef", "0"], 100, 0.0),
     (["--no-robust", "--nominal-physics-entropy-coef", "0"], 0, None)],
)  # fmt: skip
def test_the_stage_at_the_models_physics_is_the_tasks_own_and_written_out(
    flags, stage, entropy, tmp_path
):
    # residual_walk's robust training ends on 100 iterations at the model's physics but
    # for friction (docs/learning.md); the adaptive task's and a world without physics
    # randomisation have none, and no stage has no entropy bonus of its own; the record
    # keeps the number, not the rule.
    training = train.parse_args([*PLAIN, *flags])
    assert training.train.nominal_physics_iterations == stage
    assert training.train.nominal_physics_keep == (("friction",) if stage else ())
    assert training.train.nominal_physics_entropy_coef == entropy
    write_record(tmp_path / "config.json", training)
    stored = json.loads((tmp_path / "config.json").read_text())["train"]
    assert stored["nominal_physics_iterations"] == stage
    assert stored["nominal_physics_entropy_coef"] == entropy


@pytest.mark.parametrize(
    ("flags", "stage", "keep"),
    [([], 140, ("friction",)),  # the residual recipe's student: its teacher's 140 of 160
     (["--student-nominal-physics-iterations", "0"], 0, ()),
     (["--student-nominal-physics-iterations", "30"], 30, ("friction",)),
     (["--task", "adaptive_gait"], 0, ()),  # its teacher has none
     (["--task", "adaptive_gait", "--student-nominal-physics-iterations", "170"], 170,
      ("friction",))],
)  # fmt: skip
def test_the_students_stage_at_the_models_physics_is_its_teachers_unless_it_has_its_own(
    flags, stage, keep
):
    teacher = train.parse_args([*SMALL, *flags])
    student = student_training(teacher)
    assert student.train.nominal_physics_iterations == stage
    assert student.train.nominal_physics_keep == keep
    assert student.train.student_nominal_physics_iterations is None  # a student has none


@pytest.mark.parametrize(
    ("flags", "late", "tracking", "sigma"),
    [([], 50, 200.0, None), (["--max-iterations", "600"], 100, 200.0, None),
     (["--late-tracking", "300"], 50, 300.0, None), (["--late-sigma", "0.04"], 50, 200.0, 0.04),
     (["--late-iterations", "0"], 0, None, None), (["--no-robust"], 0, None, None),
     (["--task", "adaptive_gait", "--costs"], 0, None, None),
     (["--max-iterations", "2"], 0, None, None),
     (["--max-iterations", "8", "--late-iterations", "9", "--late-tracking", "1",
       "--env.shaping.tracking", "0"], 9, 1.0, None)],
)  # fmt: skip
def test_the_late_speed_kernel_is_the_residual_tasks_own_and_written_out(
    flags, late, tracking, sigma, tmp_path
):
    # residual_walk's robust training ends on 50 iterations (a sixth) with the speed
    # kernel at 200 (docs/learning.md); its terms sit at weight 0 before the stage. The
    # late flags replace the stage's values; the adaptive task, a world without physics
    # randomisation and a run too short for a stage have none. The record keeps the numbers.
    training = train.parse_args([*PLAIN, *flags])
    assert training.train.late_iterations == late
    assert (training.train.late_tracking, training.train.late_sigma) == (tracking, sigma)
    if "adaptive_gait" not in flags:
        assert training.env.shaping == (Shaping() if late else None)
    write_record(tmp_path / "config.json", training)
    assert read_record(tmp_path / "config.json") == training
    stored = json.loads((tmp_path / "config.json").read_text())["train"]
    assert (stored["late_iterations"], stored["late_tracking"]) == (late, tracking)


# ------------------------------------------------------------ every nested field is a flag


@pytest.mark.parametrize(
    ("flags", "field", "value"),
    [
        (["--env.reward-weights.stability", "-5"], "reward_weights.stability", -5.0),
        (["--env.costs.clearance", "3000"], "costs.clearance", 3000.0),
        (["--costs", "--clearance-weight", "4000"], "costs.clearance", 4000.0),
        (["--env.randomization.friction", "0.4", "1.1"], "randomization.friction", (0.4, 1.1)),
        (["--env.observation-noise.joint-vel", "0.5"], "observation_noise.joint_vel", 0.5),
        (
            ["--env.observation-noise.torso-forward-speed", "0.045"],
            "observation_noise.torso_forward_speed",
            0.045,
        ),
        (["--env.terrain-levels.promote", "0.7"], "terrain_levels.promote", 0.7),
        (
            ["--env.terrain-levels.floor-kinds", "stones", "--env.terrain-levels.floor-level", "3"],
            "terrain_levels.floor_level",
            3,
        ),
        (["--env.shaping.kind-tracking", "-270"], "shaping.kind_tracking", -270.0),
        (["--env.shaping.latency-action-rate", "70"], "shaping.latency_action_rate", 70.0),
        (["--no-robust", "--env.pushes.speed", "0.1", "0.2"], "pushes.speed", (0.1, 0.2)),
        (["--env.pushes.force", "0", "0.8"], "pushes.force", (0.0, 0.8)),
    ],
)
def test_a_nested_field_set_on_the_command_line_reaches_the_env(flags, field, value):
    training = train.parse_args([*SMALL, *flags])
    core = Core(training.env_config(), training.num_envs, seed=0)
    config = core.config
    for part in field.split("."):
        config = getattr(config, part)
    assert config == value
    if field == "reward_weights.stability":  # the term the core adds is weighed by it
        assert core.config.reward_weights.stability == -5.0
    if field == "terrain_levels.floor_level":  # the stones envs start on level 3
        stones = core.terrain_kind == core.config.terrain_levels.kinds.index("stones")
        assert core.terrain_level[stones].tolist() == [3] and not core.terrain_level[~stones].any()
    if field == "shaping.kind_tracking":  # the stones envs' term is weighed by it
        assert dict((t.name, t.weight) for t in core.terms)["kind_tracking"] == -270.0
    if field == "shaping.latency_action_rate":  # the delayed envs' change is priced by it
        assert dict((t.name, t.weight) for t in core.terms)["latency_action_rate"] == -70.0
    if field == "pushes.force":  # every env's steady force is in the new range
        core.reset()
        assert bool((core.pushes.force.norm(dim=-1) <= 0.8 + 1e-12).all())
        assert bool(core.pushes.force.any())
    if field == "randomization.friction":  # every env's drawn friction is in the new range
        core.reset()
        drawn = core.physics.params[:, 0]
        assert bool(((drawn >= 0.4) & (drawn <= 1.1)).all())


def test_a_flag_that_names_no_field_names_the_near_ones(capsys):
    with pytest.raises(SystemExit) as exit_:
        train.parse_args(["--env.randomization.fricton", "0.5", "1.0"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1
    assert "'--env.randomization.fricton'" in err and "near: --env.randomization.friction" in err


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--env.randomization.friction", "1.3", "0.5"],
         "--env.randomization.friction has min > max"),
        (["--costs", "--env.costs.stumble", "-1"], "--env.costs.stumble is the size of a cost"),
        (["--costs", "--env.costs.stumble", "inf"], "--env.costs.stumble must be a finite number"),
        (["--env.pushes.force", "0", "9"], "--env.pushes.force must be at most 5 N, got (0.0, 9"),
        (["--env.pushes.force", "-1", "1"], "--env.pushes.force must be >= 0, got (-1.0, 1.0)"),
        (["--task", "adaptive_gait", "--env.bounds.step-height.low", "0.05"],
         "--env.bounds.step-height: low must be < high"),
        (["--task", "adaptive_gait", "--costs", "--late-tracking", "300"],
         "--late-tracking 300.0 needs --late-iterations N: this training has no late stage"),
        (["--late-tracking", "nan"], "--late-tracking must be"),
        (["--late-sigma", "-0.01"], "--late-sigma must be"),
        (["--env.terrain-levels.floor-kinds", "ice"],
         "--env.terrain-levels.floor-kinds must be kinds of this map's tiles"),
        (["--env.terrain-levels.floor-kinds", "stones", "--env.terrain-levels.floor-level", "10"],
         "--env.terrain-levels.floor-level 10 is a terrain level outside the map"),
        (["--env.shaping.kind-tracking", "inf"], "--env.shaping.kind-tracking must be a finite"),
        (["--no-robust", "--env.shaping.kind-tracking", "-270"],
         "--env.shaping.kind-tracking -270.0 weighs the envs on tracking_kinds ('stones',)"),
        (["--env.observation-noise.torso-forward-speed", "nan"],
         "--env.observation-noise.torso-forward-speed must be a scale >= 0, got nan"),
    ],
)  # fmt: skip
def test_a_bad_nested_value_is_one_line_naming_its_flag(capsys, flags, message):
    with pytest.raises(SystemExit):
        train.parse_args(flags)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err


def test_resume_refuses_a_contradicting_nested_flag_naming_both_values(tmp_path, capsys):
    folder = tmp_path / "run"
    tiny = ["--num-envs", "4", "--num-steps-per-env", "4", "--settle-steps", "2",
            "--max-episode-steps", "20", "--hidden-dims", "8", "--save-interval", "1",
            "--no-export", "--recipe", "plain", "--log-dir", str(folder)]  # fmt: skip
    train.main([*tiny, "--env.costs.clearance", "3000", "--max-iterations", "1"])
    saved = (folder / "config.json").read_text()
    assert json.loads(saved)["env"]["costs"]["clearance"] == 3000.0
    with pytest.raises(SystemExit) as exit_:
        train.main([*tiny, "--resume", str(folder), "--max-iterations", "2",
                    "--env.costs.clearance", "2000"])  # fmt: skip
    message = str(exit_.value.code)
    assert "--env.costs.clearance 3000.0" in message
    assert "not --env.costs.clearance 2000.0" in message
    assert (folder / "config.json").read_text() == saved
    train.main([*tiny, "--resume", str(folder), "--max-iterations", "2"])  # its own come back
    assert json.loads((folder / "config.json").read_text())["env"]["costs"]["clearance"] == 3000.0


def test_resume_goes_on_in_the_runs_own_folder_with_its_own_seed(tmp_path, monkeypatch):
    """Without --log-dir and --seed, a resumed run writes to the folder it was resumed
    from with the seed it trained with, not to the defaults (logs/rwalk, seed 0)."""
    monkeypatch.chdir(tmp_path)
    folder = tmp_path / "runs" / "mine"
    tiny = ["--num-envs", "4", "--num-steps-per-env", "4", "--settle-steps", "2",
            "--max-episode-steps", "20", "--hidden-dims", "8", "--save-interval", "1",
            "--no-export", "--recipe", "plain"]  # fmt: skip
    train.main([*tiny, "--seed", "3", "--log-dir", str(folder), "--max-iterations", "1"])
    for resume in (folder, folder / "model_0.pt"):
        training = train.parse_args(["--resume", str(resume), "--max-iterations", "2"])
        assert (training.run.log_dir, training.run.seed) == (str(folder), 3)
    elsewhere = train.parse_args(["--resume", str(folder), "--log-dir", "other", "--seed", "5"])
    assert (elsewhere.run.log_dir, elsewhere.run.seed) == ("other", 5)
    train.main(["--resume", str(folder), "--max-iterations", "2"])
    assert (folder / "model_1.pt").exists() and not (tmp_path / "logs").exists()
    assert json.loads((folder / "config.json").read_text())["run"]["seed"] == 3


def test_a_plain_resume_keeps_a_long_runs_length_and_its_late_stage(tmp_path):
    # the defaults' 300 iterations would cut a 400-iteration run short, and its
    # 350-iteration late stage, which counts back from the run's end, would start at once
    flags = ["--max-iterations", "400", "--late-iterations", "350", "--late-tracking", "1",
             "--env.shaping.tracking", "0", "--log-dir", str(tmp_path)]  # fmt: skip
    write_record(tmp_path / "config.json", train.parse_args(flags))
    resumed = train.parse_args(["--resume", str(tmp_path)])
    assert (resumed.run.max_iterations, resumed.train.late_iterations) == (400, 350)
    shorter = train.parse_args(["--resume", str(tmp_path), "--max-iterations", "360"])
    assert shorter.run.max_iterations == 360  # a run setting: the flag still sets it


def test_a_plain_resume_keeps_the_runs_threads(tmp_path):
    # a run trained on one thread beside another resumed on every core would fight it, and
    # one thread and two round differently on some CPUs
    flags = ["--threads", "1", "--share-cores", "--log-dir", str(tmp_path)]
    write_record(tmp_path / "config.json", train.parse_args(flags))
    resumed = train.parse_args(["--resume", str(tmp_path)])
    assert (resumed.run.threads, resumed.run.share_cores) == (1, True)
    given = train.parse_args(["--resume", str(tmp_path), "--threads", "2", "--no-share-cores"])
    assert (given.run.threads, given.run.share_cores) == (2, False)


def test_a_record_lists_the_machines_its_run_trained_on(tmp_path, monkeypatch, capsys):
    """A run repeats bit for bit on one machine only: its record names the machine, and a
    resume on another one adds it and says so."""
    folder = tmp_path / "run"
    tiny = ["--num-envs", "4", "--num-steps-per-env", "4", "--settle-steps", "2",
            "--max-episode-steps", "20", "--hidden-dims", "8", "--save-interval", "1",
            "--no-export", "--recipe", "plain", "--log-dir", str(folder)]  # fmt: skip
    train.main([*tiny, "--max-iterations", "1"])
    train.main([*tiny, "--resume", str(folder), "--max-iterations", "2"])  # the same machine
    assert json.loads((folder / "config.json").read_text())["machines"] == [describe()]
    assert "another machine" not in capsys.readouterr().out
    elsewhere = describe() | {"vector": "sse4_2 avx avx2 fma", "torch_cpu": "AVX2"}
    monkeypatch.setattr(record, "describe", lambda: elsewhere)
    train.main([*tiny, "--resume", str(folder), "--max-iterations", "3"])
    out = capsys.readouterr().out
    assert "note: this run trained on another machine or library version" in out
    assert f"torch_cpu {describe()['torch_cpu']}" in out and "torch_cpu AVX2" in out
    assert read_machines(folder / "config.json") == [describe(), elsewhere]
    assert read_record(folder / "config.json").run.max_iterations == 3  # still a record


def test_the_torchrl_trainer_takes_the_same_nested_flags():
    training = train_torchrl.parse_args(["--env.pushes.interval", "1.0", "2.0"])
    assert training.env.pushes.interval == (1.0, 2.0) and training.num_envs == 256


# ------------------------------------------------------------------------- bad records

BAD_RECORDS = [
    ("{not json", "is not JSON"),
    ('{"schema": 3, "env": {}}', "has schema 3"),
    ('{"schema": 2, "env": {}, "flux": 1}', "unknown key 'flux'"),
    ('{"schema": 2, "preset": {}}', "has no env"),
    ('{"schema": 2, "env": {"settle_steps": "x"}}', "env.settle_steps must be an int, got 'x'"),
    ('{"schema": 2, "env": {"costs": {"clearance": -1}}}', "env.costs: GaitCosts.clearance"),
    ('{"schema": 2, "env": {"randomization": {"friction": [1, 2, 3]}}}',
     "env.randomization.friction must be a list of 2 items"),
    ('{"schema": 2, "env": {"gait": {"duty_factor": 1.5}}}',
     "env.gait: GaitParameters.duty_factor must be in (0, 1), got 1.5"),
    ('{"schema": 2, "env": {"bounds": {}}}', "unknown key 'bounds'"),
    ('{"schema": 2, "preset": {"task": "adaptive_gait"}, "env": {"bounds": {"step_height": '
     '[0.05, 0.01, 0.001]}}}', "env.bounds: GaitBounds.step_height: low must be < high"),
    ('{"schema": 2, "env": {}, "train": {"hidden_dims": [0]}}', "--hidden-dims must be sizes"),
    ('{"schema": 2, "env": {}, "preset": {"task": "fly"}}', "unknown task 'fly'"),
    ('{"schema": 2, "env": {"model_path": "' + "x" * 5000 + '"}}', "env.model_path must be a str"),
    ('{"schema": 2, "env": {}, "machines": [{"cpu": 1}]}',
     '"machines" must be a list of objects of strings'),
]  # fmt: skip


@pytest.mark.parametrize(("text", "message"), BAD_RECORDS)
def test_a_bad_record_is_one_error_naming_the_file_and_the_field(tmp_path, text, message):
    path = tmp_path / "config.json"
    path.write_text(text)
    with pytest.raises(ConfigError) as error:
        read_record(path)
    assert "config.json" in str(error.value) and message in str(error.value)
    assert "\n" not in str(error.value) and len(str(error.value)) < 2000


def test_a_record_too_large_is_read_no_further_than_the_cap(tmp_path):
    path = tmp_path / "config.json"
    path.write_text('{"schema": 2, "pad": "' + "x" * (2 << 20) + '"}')
    with pytest.raises(ConfigError, match="larger than"):
        read_record(path)


# ------------------------------------------------------------------------ one place each


def test_no_module_outside_the_tasks_branches_on_a_task_name_or_a_task_configs_fields():
    branch = re.compile(
        r"""(==|!=|\bin\b)\s*\(?\s*["'](residual_walk|adaptive_gait)["']"""
        r"""|["'](residual_walk|adaptive_gait)["']\s*(==|!=)"""
        r"""|__dataclass_fields__|\.(gait_action|start_spread|bounds)\b"""
    )
    found = []
    for path in (ROOT / "rwalk").rglob("*.py"):
        if "tasks" in path.relative_to(ROOT / "rwalk").parts[:1]:
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            code = line.split("#")[0]
            # legacy.py reads schema-1 flags; deploy.py's adaptive runtime reads its own section
            if branch.search(code) and path.name not in ("legacy.py", "deploy.py"):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert found == []


def test_the_episode_and_settle_defaults_are_written_once():
    default = re.compile(r"(episode_steps|settle_steps|max_steps|EPISODE_STEPS|SETTLE_STEPS)\b"
                         r"[^=\n]*=\s*(1000|500)\b")  # fmt: skip
    found = [f"{path.relative_to(ROOT)}: {match.group(0)}"
             for path in (ROOT / "rwalk").rglob("*.py")
             for match in default.finditer(path.read_text())]  # fmt: skip
    assert found == ["rwalk/constants.py: EPISODE_STEPS = 1000",
                     "rwalk/constants.py: SETTLE_STEPS = 500"]  # fmt: skip


def test_an_evaluation_env_acts_as_the_record_says():
    trained = AdaptiveGaitConfig(gait_action="target", command_range=(0.1, 0.2), start_spread=0.5)
    config = presets.evaluation_env(trained, settle_steps=3)
    assert type(config) is AdaptiveGaitConfig and config.gait_action == "target"
    assert config.command_range == (0.1, 0.2) and config.start_spread == 0.0  # the episodes'
    assert config.settle_steps == 3 and config.position_noise == presets.START_SPREAD
    scheduled = dataclasses.replace(trained, gait_action="schedule", schedule_stride=0.05,
                                    schedule_window=(0.5, 0.1, 0.2, 0.0))  # fmt: skip
    config = presets.evaluation_env(scheduled)
    assert (config.gait_action, config.schedule_stride, config.schedule_window) == (
        "schedule", 0.05, (0.5, 0.1, 0.2, 0.0))  # fmt: skip
