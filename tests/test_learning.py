"""Teacher, student, memory, symmetry and warm starts (rwalk-train --teacher / --distill /
--actor / --symmetry / --warm-start): tiny runs through the real rsl-rl runners, and the
refusals of bad pairings."""

import json
import shutil
import subprocess
from functools import partial
from pathlib import Path

import pytest
import torch
from rsl_rl.algorithms import PPO
from test_distributed import TORCHRUN, environment

from rwalk import Core
from rwalk.randomization import NOMINAL_PARAMS, PhysicsRandomizer, Randomization
from rwalk.rewards import GaitCosts
from rwalk.rl.checkpoints import checkpoint_files, load_checkpoint
from rwalk.rl.config import student_training
from rwalk.runners import play, train
from rwalk.tensorboard_events import read_scalars

ROOT = Path(__file__).resolve().parents[1]
TINY = ["--num-envs", "8", "--num-steps-per-env", "8", "--settle-steps", "2",
        "--max-episode-steps", "30", "--hidden-dims", "16", "--save-interval", "1",
        "--no-export", "--recipe", "plain"]  # fmt: skip
PLAY = ["--episodes", "2", "--max-steps", "10", "--settle-steps", "2"]


@pytest.fixture(scope="module")
def teacher(tmp_path_factory) -> Path:
    """A tiny teacher run (its actor reads the privileged pieces)."""
    folder = tmp_path_factory.mktemp("teacher")
    train.main([*TINY, "--teacher", "--max-iterations", "2", "--log-dir", str(folder)])
    return folder


def test_a_teachers_actor_reads_the_privileged_pieces(teacher):
    args = json.loads((teacher / "config.json").read_text())["train"]
    assert args["teacher"] is True
    actor = load_checkpoint(teacher / "model_1.pt")["actor_state_dict"]
    # 65 + phase 2 + lateral 1 + physics 9 + heights 20
    assert actor["mlp.0.weight"].shape[1] == 65 + 2 + 1 + 9 + 20
    rows = play.play(["--checkpoint", str(teacher / "model_1.pt"), *PLAY])
    assert rows[0].episodes == 2


@pytest.mark.parametrize("actor", ["mlp", "gru"])
def test_a_student_distils_the_teacher_and_resumes(teacher, tmp_path, actor, capsys):
    folder = tmp_path / "student"
    flags = [*TINY, "--distill", str(teacher), "--actor", actor, "--rnn-hidden-dim", "16"]
    train.main([*flags, "--max-iterations", "2", "--log-dir", str(folder)])
    assert f"distilling the teacher {teacher / 'model_1.pt'}" in capsys.readouterr().out
    saved = load_checkpoint(folder / "model_1.pt")
    assert {"student_state_dict", "teacher_state_dict"} <= saved.keys()
    # the student is blind: 65 + phase 2 + lateral 1; the frozen teacher read 97
    inputs = "rnn.rnn.weight_ih_l0" if actor == "gru" else "mlp.0.weight"
    assert saved["student_state_dict"][inputs].shape[1] == 68
    assert saved["teacher_state_dict"]["mlp.0.weight"].shape[1] == 97
    teacher_weights = load_checkpoint(teacher / "model_1.pt")["actor_state_dict"]
    assert torch.equal(saved["teacher_state_dict"]["mlp.0.weight"], teacher_weights["mlp.0.weight"])
    assert "Loss/behavior" in read_scalars(folder)
    train.main([*flags, "--max-iterations", "3", "--resume", str(folder),
                "--log-dir", str(folder)])  # fmt: skip
    assert [it for it, _ in checkpoint_files(folder)] == [0, 1, 2]
    rows = play.play(["--checkpoint", str(folder / "model_2.pt"), *PLAY])
    assert rows[0].mean_length == 10


def test_a_smoothness_cost_shapes_the_student_and_zero_is_rsl_rls_distillation(
        teacher, tmp_path, monkeypatch):  # fmt: skip
    from rsl_rl.algorithms import Distillation

    from rwalk.rl import distillation

    def student(name: str, *flags: str) -> dict:
        train.main([*TINY, "--distill", str(teacher), "--max-iterations", "2",
                    "--log-dir", str(tmp_path / name), *flags])  # fmt: skip
        return load_checkpoint(tmp_path / name / "model_1.pt")["student_state_dict"]

    ours, smooth = student("ours"), student("smooth", "--distill-smoothness", "50")
    monkeypatch.setattr(distillation, "SmoothDistillation", Distillation)
    rsl_rl = student("rsl_rl")
    assert all(torch.equal(tensor, rsl_rl[name]) for name, tensor in ours.items())
    assert not all(torch.equal(tensor, smooth[name]) for name, tensor in ours.items())
    logged = read_scalars(tmp_path / "smooth")
    assert "Loss/smoothness" not in read_scalars(tmp_path / "ours")
    assert len(logged["Loss/smoothness"]) == 2 and all(v > 0 for *_, v in logged["Loss/smoothness"])
    saved = json.loads((tmp_path / "smooth" / "config.json").read_text())["train"]
    assert saved["distill_smoothness"] == 50.0


def test_the_smoothness_cost_pairs_the_steps_of_one_episode_within_a_pass():
    """By hand: 2 envs, 2 action values, a rollout of 3 steps, env 1's episode ending at
    step 0; gradient windows of 2 steps."""
    from types import SimpleNamespace

    from rwalk.rl.distillation import SmoothDistillation

    alg = object.__new__(SmoothDistillation)  # the loss alone: no models, no runner
    dones = torch.tensor([[[0], [1]], [[0], [0]], [[0], [0]]], dtype=torch.uint8)
    alg.storage = SimpleNamespace(num_transitions_per_env=3, dones=dones)
    alg.gradient_length, alg.smoothness = 2, 10.0
    alg._imitation, alg._calls, alg._previous = torch.nn.functional.mse_loss, 0, None
    alg._sums = [0.0, 0.0, 0]
    steps = [torch.tensor(rows, requires_grad=True) for rows in
             ([[0.0, 0.0], [1.0, 1.0]], [[1.0, 1.0], [1.0, 1.0]], [[1.0, 3.0], [2.0, 1.0]],
              [[5.0, 5.0], [5.0, 5.0]])]  # fmt: skip
    losses = [alg._step_loss(a, torch.zeros(2, 2)) for a in steps]
    # step 0: mean a^2 = 0.5, nothing before it; step 1: 1, + 10 x (env 0's change 1, env 1's
    # new episode 0) / 2; step 2: 3.75, + 10 x (2 + 0.5) / 2; step 3 starts a new pass: 25
    assert [loss.item() for loss in losses] == [0.5, 1.0 + 5.0, 3.75 + 12.5, 25.0]
    losses[1].backward()  # within a window: both actions of the pair
    assert steps[0].grad is not None and steps[1].grad is not None
    losses[2].backward()  # step 2 opens the next window: step 1's action is held
    assert torch.equal(steps[1].grad, (2 * steps[1] / 4 + 10 * 2 * (steps[1] - steps[0]) / 4
                                       * torch.tensor([[1.0], [0.0]])).detach())  # fmt: skip
    assert alg._sums == [0.5 + 1.0 + 3.75 + 25.0, 0.5 + 1.25, 2]


def test_distill_levels_starts_the_student_on_its_teachers_levels(teacher, tmp_path):
    saved = load_checkpoint(teacher / "model_1.pt")
    saved["env_state"]["terrain_level"] = torch.full_like(saved["env_state"]["terrain_level"], 5)
    torch.save(saved, tmp_path / "model_1.pt")  # a teacher whose curriculum climbed to 5
    (tmp_path / "config.json").write_text((teacher / "config.json").read_text())
    levels = {}
    for name, flags in (("own", []), ("teacher", ["--distill-levels"])):
        folder = tmp_path / name
        train.main([*TINY, "--distill", str(tmp_path / "model_1.pt"), *flags,
                    "--max-iterations", "1", "--log-dir", str(folder)])  # fmt: skip
        levels[name] = load_checkpoint(folder / "model_0.pt")["env_state"]["terrain_level"]
    # in one iteration an env moves a level at most
    assert levels["own"].max() <= 1
    assert levels["teacher"].min() >= 4 and (levels["teacher"] == 5).any()


def test_recurrent_ppo_and_symmetry_train_and_play(tmp_path):
    for name, flags in (("gru", ["--actor", "lstm", "--rnn-hidden-dim", "16"]),
                        ("sym", ["--symmetry"])):  # fmt: skip
        folder = tmp_path / name
        train.main([*TINY, *flags, "--max-iterations", "2", "--log-dir", str(folder)])
        assert play.play(["--checkpoint", str(folder / "model_1.pt"), *PLAY])[0].episodes == 2
    assert "Loss/symmetry" in read_scalars(tmp_path / "sym")
    actor = load_checkpoint(tmp_path / "gru" / "model_1.pt")["actor_state_dict"]
    assert "rnn.rnn.weight_hh_l0" in actor


def test_one_command_trains_the_teacher_then_its_student(tmp_path, capsys):
    """The student on --student-num-envs envs, its settled-start pool in the teacher's
    proportion."""
    folder = tmp_path / "run"
    train.main([*TINY, "--teacher", "--max-iterations", "2", "--student-iterations", "3",
                "--student-actor", "mlp", "--student-num-envs", "4",
                "--log-dir", str(folder)])  # fmt: skip
    out = capsys.readouterr().out
    assert f"distilling the teacher {folder / 'model_1.pt'}" in out
    assert [it for it, _ in checkpoint_files(folder)] == [0, 1]
    assert [it for it, _ in checkpoint_files(folder / "student")] == [0, 1, 2]
    student = json.loads((folder / "student" / "config.json").read_text())["train"]
    assert student["distill"] == str(folder) and student["actor"] == "mlp"
    assert not student["teacher"] and student["student_iterations"] == 0
    assert student["student_num_envs"] == 0
    runs = [json.loads((path / "config.json").read_text()) for path in (folder, folder / "student")]
    assert [(run["num_envs"], run["env"]["settle_pool"]) for run in runs] == [(8, 2), (4, 1)]
    saved = load_checkpoint(folder / "student" / "model_2.pt")
    assert saved["student_state_dict"]["mlp.0.weight"].shape[1] == 68  # blind
    assert play.play(["--checkpoint", str(folder / "student" / "model_2.pt"), *PLAY])


def test_the_default_recipe_trains_a_teacher_then_its_blind_gru_student(tmp_path):
    folder = tmp_path / "run"
    precise = [flag for flag in TINY if flag not in ("--recipe", "plain")]
    train.main([*precise, "--max-iterations", "2", "--student-iterations", "2",
                "--log-dir", str(folder)])  # fmt: skip
    teacher = json.loads((folder / "config.json").read_text())
    assert teacher["preset"]["recipe"] == "precise" and teacher["train"]["teacher"]
    assert teacher["env"]["costs"]["power"] == 2.0 and teacher["env"]["shaping"]["tracking"] == 300
    assert teacher["env"]["terrain_levels"]["kinds"][0] == "flat"
    student = json.loads((folder / "student" / "config.json").read_text())["train"]
    assert student["actor"] == "gru" and student["distill_levels"]
    assert student["policy_obs"] == teacher["train"]["policy_obs"][:-2]  # blind
    assert [it for it, _ in checkpoint_files(folder / "student")] == [0, 1]


def test_the_adaptive_recipe_trains_a_teacher_then_its_student_on_the_schedule(tmp_path):
    folder = tmp_path / "adaptive"
    precise = [flag for flag in TINY if flag not in ("--recipe", "plain")]
    train.main([*precise, "--task", "adaptive_gait", "--max-iterations", "2",
                "--student-iterations", "2", "--log-dir", str(folder)])  # fmt: skip
    teacher = json.loads((folder / "config.json").read_text())
    assert teacher["preset"]["task"] == "adaptive_gait" and teacher["train"]["teacher"]
    assert teacher["env"]["gait_action"] == "schedule"
    assert teacher["env"]["bounds"]["body_height"][:2] == [0.0699, 0.0701]
    student = json.loads((folder / "student" / "config.json").read_text())
    assert student["num_envs"] == 4 and student["train"]["actor"] == "gru"  # half of 8
    assert student["env"]["gait_action"] == "schedule"
    assert [it for it, _ in checkpoint_files(folder / "student")] == [0, 1]


def test_the_default_recipe_distils_its_student_on_half_the_envs():
    args = train.parse_args([])
    assert (args.num_envs, args.train.student_iterations, args.train.student_num_envs) == (
        1024, 160, 512)  # fmt: skip
    student = student_training(args)
    assert (student.num_envs, student.env.settle_pool) == (512, args.env.settle_pool // 2)
    assert train.parse_args(["--num-envs", "3"]).train.student_num_envs == 2  # rounded
    assert train.parse_args(["--num-envs", "1"]).train.student_num_envs == 1
    whole = train.parse_args(["--student-num-envs", "0"])  # the flag: the teacher's envs
    assert whole.train.student_num_envs == 0 and student_training(whole).num_envs == 1024
    for alone in (["--student-iterations", "0"], ["--no-teacher"]):  # no student to size
        assert train.parse_args(alone).train.student_num_envs == 0


def test_a_teacher_may_read_only_the_ground_under_its_feet(tmp_path):
    folder = tmp_path / "run"
    train.main([*TINY, "--teacher", "--teacher-obs", "physics", "heights_under_feet",
                "--max-iterations", "2", "--student-iterations", "2", "--student-actor", "mlp",
                "--log-dir", str(folder)])  # fmt: skip
    teacher = json.loads((folder / "config.json").read_text())["train"]
    assert teacher["policy_obs"][-2:] == ["physics", "heights_under_feet"]
    assert teacher["critic_obs"] == teacher["policy_obs"]  # the critic reads what it reads
    saved = load_checkpoint(folder / "model_1.pt")
    for model in ("actor_state_dict", "critic_state_dict"):  # 68 + physics 9 + 4 heights
        assert saved[model]["mlp.0.weight"].shape[1] == 65 + 2 + 1 + 9 + 4
    student = json.loads((folder / "student" / "config.json").read_text())["train"]
    assert student["policy_obs"] == teacher["policy_obs"][:-2]  # blind
    assert student["teacher_obs"] == ["physics", "heights"]  # (the default: it is no teacher)
    distilled = load_checkpoint(folder / "student" / "model_1.pt")
    assert distilled["student_state_dict"]["mlp.0.weight"].shape[1] == 68


def test_symmetry_is_the_default_where_rsl_rl_allows_it():
    from rwalk.rl.config import mirrored
    from rwalk.rl.training import rsl_rl_config

    def augments(*flags: str) -> bool:
        args = train.parse_args(list(flags))
        in_config = "symmetry_cfg" in rsl_rl_config(args).get("algorithm", {})
        assert in_config == mirrored(args)
        return in_config

    assert augments() and augments("--teacher")
    assert not augments("--actor", "gru")  # the default adapts; an explicit flag is refused
    assert not augments("--distill", "x.pt") and not augments("--no-symmetry")


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--actor", "transformer"], "--actor must be one of mlp, gru, lstm, got 'transformer'"),
        (["--teacher", "--student-actor", "cnn"], "--student-actor must be one of"),
        (["--student-iterations", "5"], "--student-iterations needs --teacher"),
        (["--distill-levels"], "--distill-levels needs --distill or --student-iterations"),
        (["--finetune-num-envs", "4"], "--finetune-num-envs 4 needs --finetune-iterations"),
        (["--student-num-envs", "4"], "--student-num-envs 4 needs --student-iterations"),
        (
            ["--teacher", "--student-iterations", "1", "--student-num-envs", "-1"],
            "--student-num-envs must be >= 0, got -1",
        ),
        (
            [
                *("--teacher", "--student-iterations", "1", "--student-num-envs", "1"),
                *("--num-steps-per-env", "2"),
            ],
            "--num-mini-batches must be <= --student-num-envs * --num-steps-per-env = 2, got 4",
        ),
        (
            [
                *("--teacher", "--student-iterations", "1", "--finetune-iterations", "1"),
                *("--finetune-num-envs", "1", "--num-steps-per-env", "2"),
            ],
            "--num-mini-batches must be <= --finetune-num-envs * --num-steps-per-env = 2, got 4",
        ),
        (
            [
                *("--teacher", "--student-iterations", "1", "--finetune-iterations", "1"),
                *("--finetune-num-envs", "-1"),
            ],
            "--finetune-num-envs must be >= 0, got -1",
        ),
        (["--teacher-obs", "physics"], "--teacher-obs physics needs --teacher"),
        (
            ["--teacher", "--teacher-obs", "sensors"],
            "--teacher-obs sensors: privileged pieces from physics, heights, "
            "heights_under_feet, each once",
        ),
        (["--teacher", "--teacher-obs", "physics", "physics"], "--teacher-obs physics physics:"),
        (["--symmetry", "--actor", "gru"], "--symmetry needs --actor mlp"),
        (["--symmetry", "--distill", "x.pt"], "--symmetry and --distill do not go together"),
        (["--teacher", "--distill", "x.pt"], "--teacher and --distill do not go together"),
        (
            ["--warm-start", "x.pt", "--distill", "y.pt"],
            "--warm-start and --distill do not go together",
        ),
        (["--nominal-physics-iterations", "-1"], "--nominal-physics-iterations must be >= 0"),
        (["--nominal-physics-keep", "mass"], "--nominal-physics-keep names ranges of"),
        (
            ["--nominal-physics-entropy-coef", "-0.01"],
            "--nominal-physics-entropy-coef must be >= 0, got -0.01",
        ),
        (
            ["--nominal-physics-entropy-coef", "nan"],
            "--nominal-physics-entropy-coef must be >= 0, got nan",
        ),
        (["--late-iterations", "5"], "--late-iterations 5 and the stage's values go together"),
        (
            ["--flat-kinds", "ice"],
            "--flat-kinds ice: kinds of tile from rough, slopes, steps, stones, flat, each once",
        ),
        (["--flat-kinds", "stones", "stones"], "--flat-kinds stones stones: kinds of tile"),
        (["--flat-until", "5"], "--flat-until 5 needs --flat-kinds KIND ...: the kinds"),
        (["--flat-from", "5"], "--flat-from 5 needs --flat-kinds KIND ..."),
        (["--flat-kinds", "stones", "--flat-from", "-1"], "--flat-from must be >= 0, got -1"),
        (
            ["--flat-kinds", "stones", "--flat-from", "5", "--flat-until", "5"],
            "--flat-until must be in [6, 1e+09], got 5",
        ),
        (
            ["--flat-kinds", "stones", "--flat-from", "300"],
            "--flat-from 300: the run ends before, at --max-iterations 300",
        ),
        (
            ["--flat-kinds", "flat"],
            "--flat-kinds flat: this training's map has the kinds rough slopes steps stones",
        ),
        (
            ["--no-robust", "--flat-kinds", "stones"],
            "--flat-kinds stones: this training's map has the kinds none",
        ),
        (
            ["--distill-smoothness", "1"],
            "--distill-smoothness 1.0 needs --distill or --student-iterations",
        ),
        (
            ["--distill", "x.pt", "--no-symmetry", "--distill-smoothness", "-1"],
            "--distill-smoothness must be >= 0, got -1.0",
        ),
        (
            ["--distill", "x.pt", "--no-symmetry", "--distill-smoothness", "nan"],
            "--distill-smoothness must be >= 0, got nan",
        ),
        (
            ["--distill", "x.pt", "--no-symmetry", "--distill-smoothness", "1e4"],
            "--distill-smoothness must be at most 1000, got 10000.0",
        ),
        (["--no-robust", "--late-sigma", "0.04"], "--late-sigma 0.04 needs --late-iterations N"),
        (["--late-iterations", "-1", "--late-sigma", "0.04"], "--late-iterations must be >= 0"),
        (["--late-iterations", "5", "--late-sigma", "nan"], "--late-sigma must be a finite"),
        (["--late-iterations", "5", "--late-tracking", "-1"], "--late-tracking must be >= 0"),
        (
            ["--late-iterations", "5", "--late-sigma-per-speed", "-0.1"],
            "--late-sigma-per-speed must be >= 0, got -0.1",
        ),
        (
            ["--late-iterations", "5", "--late-clearance-target", "-0.01"],
            "--late-clearance-target must be a finite number > 0, got -0.01",
        ),
        (
            ["--late-iterations", "5", "--late-sigma", "0.04"],
            "--late-sigma 0.04 changes --env.shaping, which this training has not",
        ),
        (
            ["--costs", "--late-iterations", "5", "--late-clearance-target", "9"],
            "--late-clearance-target 9.0: GaitCosts.clearance_target must be > 0 and within",
        ),
        (
            ["--late-iterations", "5", "--late-action-rate", "-1"],
            "--late-action-rate must be >= 0, got -1.0",
        ),
        (
            ["--costs", "--late-iterations", "5", "--late-clearance-target-per-speed", "-1"],
            "--late-clearance-target-per-speed must be >= 0, got -1.0",
        ),
        (
            ["--costs", "--late-iterations", "5", "--late-clearance-target-per-speed", "1"],
            "--late-clearance-target-per-speed 1.0: GaitCosts.clearance_target_per_speed 1.0 s "
            "asks 0.133333 m at 0.133333 m/s",
        ),
        (
            [
                "--distill",
                "x.pt",
                "--no-symmetry",
                "--late-iterations",
                "5",
                "--late-sigma",
                "0.04",
                "--env.shaping.tracking",
                "1",
            ],
            "--late-iterations changes the reward, which a distilled student does not learn",
        ),
    ],
)
def test_bad_pairings_are_usage_errors(flags, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        train.parse_args(["--recipe", "plain", *flags])  # the plain defaults' pairings
    assert exit_.value.code == 2 and message in capsys.readouterr().err


def _refused(out: Path, *flags: str) -> str:
    """The one-line error of a tiny training into ``out`` with ``flags``, which must have
    written no checkpoint there."""
    with pytest.raises(SystemExit) as exit_:
        train.main([*TINY, "--max-iterations", "2", "--log-dir", str(out), *flags])
    assert not out.exists() or not any(out.glob("*.pt"))
    return str(exit_.value.code)


def test_a_checkpoint_that_is_no_teacher_of_this_run_is_named(teacher, tmp_path):
    refused = partial(_refused, tmp_path / "out")

    assert "not found" in refused("--distill", str(tmp_path / "missing.pt"))
    cut = tmp_path / "cut" / "model_1.pt"
    cut.parent.mkdir()
    cut.write_bytes((teacher / "model_1.pt").read_bytes()[:5000])
    assert "cannot be read" in refused("--distill", str(cut))
    plain = tmp_path / "plain"
    shutil.copytree(teacher, plain)
    config = json.loads((plain / "config.json").read_text())
    config["train"]["teacher"] = False
    (plain / "config.json").write_text(json.dumps(config))
    assert "trained without --teacher" in refused("--distill", str(plain))
    assert (
        "its teacher trained with --task residual_walk, this student with --task "
        "adaptive_gait" in refused("--distill", str(teacher), "--task", "adaptive_gait")
    )
    assert "with --no-robust" in refused("--distill", str(teacher), "--no-robust")


def test_two_ranks_distil_one_student(teacher, tmp_path):
    done = subprocess.run(
        [*TORCHRUN, "--standalone", "--nproc-per-node", "2", "-m", "rwalk.runners.train",
         *TINY, "--distill", str(teacher), "--max-iterations", "2",
         "--log-dir", str(tmp_path / "run")],
        cwd=ROOT, env=environment(), capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert [it for it, _ in checkpoint_files(tmp_path / "run")] == [0, 1]
    assert "student_state_dict" in load_checkpoint(tmp_path / "run" / "model_1.pt")


def _frames_seen(checkpoint: Path) -> int:
    """Observations the actor's normaliser has counted (every step of every env so far)."""
    return int(load_checkpoint(checkpoint)["actor_state_dict"]["obs_normalizer.count"])


def test_a_warm_start_takes_the_models_and_starts_a_new_run(tmp_path, capsys):
    source, run = tmp_path / "source", tmp_path / "run"
    train.main([*TINY, "--max-iterations", "2", "--log-dir", str(source)])
    per_iteration = 8 * 8  # --num-envs x --num-steps-per-env
    assert _frames_seen(source / "model_1.pt") == 2 * per_iteration
    # another world (no pushes), the same pieces and models: iteration 0 of a new run,
    # its normaliser going on from the source's counts
    flags = [*TINY, "--warm-start", str(source), "--env.pushes.speed", "0", "0",
             "--log-dir", str(run)]  # fmt: skip
    train.main([*flags, "--max-iterations", "1"])
    assert f"warm start from {source / 'model_1.pt'}" in capsys.readouterr().out
    saved = load_checkpoint(run / "model_0.pt")
    assert saved["iter"] == 0 and _frames_seen(run / "model_0.pt") == 3 * per_iteration
    assert json.loads((run / "config.json").read_text())["train"]["warm_start"] == str(source)
    # resuming it goes on from its own checkpoint, not from the warm start again
    train.main([*flags, "--max-iterations", "2", "--resume", str(run)])
    assert "warm start" not in capsys.readouterr().out
    assert _frames_seen(run / "model_1.pt") == 4 * per_iteration


def test_a_warm_start_that_does_not_fit_is_named(teacher, tmp_path):
    source = tmp_path / "source"
    train.main([*TINY, "--max-iterations", "1", "--log-dir", str(source)])

    refused = partial(_refused, tmp_path / "out")

    missing = tmp_path / "missing.pt"
    assert f"--warm-start {missing}: checkpoint" in refused("--warm-start", str(missing))
    assert "not found" in refused("--warm-start", str(missing))
    lone = tmp_path / "lone" / "model_0.pt"
    lone.parent.mkdir()
    shutil.copy(source / "model_0.pt", lone)
    assert "config.json is not beside" in refused("--warm-start", str(lone))
    assert ("its run trained with --task residual_walk, this run with --task adaptive_gait"
            in refused("--warm-start", str(source), "--task", "adaptive_gait"))  # fmt: skip
    assert "--policy-obs" in refused("--warm-start", str(source), "--no-robust")
    assert "--policy-obs" in refused("--warm-start", str(teacher))  # reads privileged pieces
    assert "--hidden-dims" in refused("--warm-start", str(source), "--hidden-dims", "8")
    assert "--actor" in refused("--warm-start", str(source), "--actor", "gru")
    student = tmp_path / "student"
    train.main([*TINY, "--distill", str(teacher), "--max-iterations", "1",
                "--log-dir", str(student)])  # fmt: skip
    assert "a distilled student" in refused("--warm-start", str(student))


def test_one_command_fine_tunes_its_student_with_ppo_and_the_teachers_critic(tmp_path, capsys):
    """--finetune-iterations: a third stage, PPO on the distilled GRU student (its weights,
    normaliser and levels) with the teacher's MLP critic and action std; it resumes, plays
    and exports like any PPO run."""
    folder = tmp_path / "run"
    flags = [flag for flag in TINY if flag != "--no-export"]
    train.main([*flags, "--teacher", "--max-iterations", "2", "--student-iterations", "2",
                "--rnn-hidden-dim", "16", "--finetune-iterations", "1",
                "--finetune-learning-rate", "1e-12", "--finetune-num-envs", "4",
                "--log-dir", str(folder)])  # fmt: skip
    student, teacher = folder / "student" / "model_1.pt", folder / "model_1.pt"
    assert f"warm start from {student}, its critic from {teacher}" in capsys.readouterr().out
    finetune = folder / "finetune"
    record = json.loads((finetune / "config.json").read_text())["train"]
    taught = json.loads((folder / "student" / "config.json").read_text())["train"]
    assert record["warm_start"] == str(student) and record["warm_start_critic"] == str(teacher)
    assert record["actor"] == "gru" and record["critic"] == "mlp" and record["distill"] == ""
    assert record["policy_obs"] == taught["policy_obs"] and record["learning_rate"] == 1e-12
    assert record["critic_obs"] == json.loads((folder / "config.json").read_text())[
        "train"]["critic_obs"]  # fmt: skip
    assert record["warm_start_levels"] and record["finetune_iterations"] == 0
    # on --finetune-num-envs envs, its settled-start pool in the student's proportion
    tuned_run, taught_run = (json.loads((path / "config.json").read_text())
                             for path in (finetune, folder / "student"))  # fmt: skip
    assert (taught_run["num_envs"], tuned_run["num_envs"], record["finetune_num_envs"]) == (8, 4, 0)
    pools = taught_run["env"]["settle_pool"], tuned_run["env"]["settle_pool"]
    assert pools == (2, 1)
    # at a step of ~1e-12 the first iteration leaves the weights where the warm start put
    # them: the student's, with the teacher's std; the teacher's critic
    tuned, distilled = load_checkpoint(finetune / "model_0.pt"), load_checkpoint(student)
    ppo = load_checkpoint(teacher)
    for name, weights in distilled["student_state_dict"].items():
        if "normalizer" not in name and not name.startswith("distribution."):
            assert torch.allclose(tuned["actor_state_dict"][name], weights, atol=1e-6), name
    std = tuned["actor_state_dict"]["distribution.std_param"]
    assert torch.allclose(std, ppo["actor_state_dict"]["distribution.std_param"], atol=1e-6)
    assert not torch.allclose(std, distilled["student_state_dict"]["distribution.std_param"])
    for name, weights in ppo["critic_state_dict"].items():
        if "normalizer" not in name:
            assert torch.allclose(tuned["critic_state_dict"][name], weights, atol=1e-6), name
    assert (finetune / "exported" / "policy.onnx").is_file()
    train.main(["--resume", str(finetune), "--max-iterations", "2"])
    assert [it for it, _ in checkpoint_files(finetune)] == [0, 1]
    assert play.play(["--checkpoint", str(finetune / "model_1.pt"), *PLAY])[0].episodes == 2


def test_a_distilled_student_resumed_runs_its_fine_tune_when_it_ends(teacher, tmp_path):
    folder = tmp_path / "student"
    flags = [*TINY, "--distill", str(teacher), "--finetune-iterations", "1"]
    train.main([*flags, "--max-iterations", "1", "--log-dir", str(folder)])
    finetune = folder / "finetune"  # a --distill run's: in its own folder
    assert json.loads((finetune / "config.json").read_text())["train"]["warm_start"] == str(
        folder / "model_0.pt")  # fmt: skip
    shutil.rmtree(finetune)  # as if stopped before its fine-tune
    train.main(["--resume", str(folder), "--max-iterations", "2"])
    assert json.loads((finetune / "config.json").read_text())["train"]["warm_start"] == str(
        folder / "model_1.pt")  # fmt: skip
    assert [it for it, _ in checkpoint_files(finetune)] == [0]


def test_a_warm_start_may_keep_its_curriculum_levels(tmp_path):
    source = tmp_path / "source"
    train.main([*TINY, "--max-iterations", "1", "--log-dir", str(source)])
    saved = load_checkpoint(source / "model_0.pt")
    saved["env_state"]["terrain_level"] = torch.full_like(saved["env_state"]["terrain_level"], 5)
    climbed = tmp_path / "climbed"  # a run whose curriculum climbed to 5
    climbed.mkdir()
    torch.save(saved, climbed / "model_0.pt")
    shutil.copy(source / "config.json", climbed)
    levels = {}
    for name, flags in (("own", []), ("kept", ["--warm-start-levels"])):
        train.main([*TINY, "--warm-start", str(climbed), *flags, "--max-iterations", "1",
                    "--log-dir", str(tmp_path / name)])  # fmt: skip
        levels[name] = load_checkpoint(tmp_path / name / "model_0.pt")["env_state"]["terrain_level"]
    assert levels["own"].max() <= 1  # in one iteration an env moves a level at most
    assert levels["kept"].min() >= 4 and (levels["kept"] == 5).any()


def test_a_warm_start_critic_that_does_not_fit_is_named(teacher, tmp_path):
    student = tmp_path / "student"
    train.main([*TINY, "--distill", str(teacher), "--actor", "gru", "--rnn-hidden-dim", "16",
                "--max-iterations", "1", "--log-dir", str(student)])  # fmt: skip
    refused = partial(_refused, tmp_path / "out", "--warm-start", str(student), "--actor", "gru",
                      "--rnn-hidden-dim", "16")  # fmt: skip
    assert "--warm-start-critic" in refused()  # a student has no critic
    assert (f"--warm-start-critic {student / 'model_0.pt'}: a distilled student"
            in refused("--warm-start-critic", str(student)))  # fmt: skip
    # the teacher's critic reads the privileged pieces, an MLP: this run's must too
    assert "--critic-obs" in refused("--warm-start-critic", str(teacher), "--critic", "mlp",
                                     "--critic-obs", "observation")  # fmt: skip
    assert ("its run trained with --critic mlp, this run with --critic gru"
            in refused("--warm-start-critic", str(teacher)))  # fmt: skip


@pytest.fixture
def draws(monkeypatch) -> list:
    """(ranges, physics drawn) at every reset of every env of the runs that follow."""
    drawn = []
    reset = PhysicsRandomizer.reset

    def spy(self, rows, settle_tail):
        reset(self, rows, settle_tail)
        drawn.append((self.randomization, self.params[rows].clone()))

    monkeypatch.setattr(PhysicsRandomizer, "reset", spy)
    return drawn


#: TINY with 4-step episodes: every env resets often.
_CUT = TINY.index("--max-episode-steps")
SHORT = [*TINY[:_CUT], *TINY[_CUT + 2 :], "--max-episode-steps", "4"]
NOMINAL = torch.tensor(NOMINAL_PARAMS, dtype=torch.float64)


def assert_same_actor(ours: Path, theirs: Path) -> None:
    """The two checkpoints' actors are equal bit for bit."""
    mine, other = (load_checkpoint(path)["actor_state_dict"] for path in (ours, theirs))
    for name, tensor in other.items():
        assert torch.equal(mine[name], tensor), name


def test_the_last_iterations_draw_the_models_physics(tmp_path, draws, capsys, monkeypatch):
    entropies = []
    update = PPO.update

    def spy(self, *args, **kwargs):
        entropies.append(self.entropy_coef)
        return update(self, *args, **kwargs)

    monkeypatch.setattr(PPO, "update", spy)
    run = tmp_path / "run"
    train.main([*SHORT, "--max-iterations", "3", "--nominal-physics-iterations", "1",
                "--nominal-physics-entropy-coef", "0", "--nominal-physics-keep",
                "--log-dir", str(run)])  # fmt: skip
    assert "iteration 2: new episodes draw the model's own physics" in capsys.readouterr().out
    assert entropies == [0.005, 0.005, 0.0]  # and the stage's entropy bonus from there on
    narrowed = [ranges == Randomization.nominal() for ranges, _ in draws]
    before = [p for (_, p), n in zip(draws, narrowed, strict=True) if not n]
    after = [p for (_, p), n in zip(draws, narrowed, strict=True) if n]
    assert before and after and narrowed[-1]  # randomised first, narrowed to the end
    assert all(torch.equal(p, NOMINAL.expand_as(p)) for p in after)
    assert not all(torch.equal(p, NOMINAL.expand_as(p)) for p in before)
    # the iterations before the stage are the plain run's, bit for bit
    plain = tmp_path / "plain"
    train.main([*SHORT, "--max-iterations", "2", "--nominal-physics-iterations", "0",
                "--log-dir", str(plain)])  # fmt: skip
    assert_same_actor(run / "model_1.pt", plain / "model_1.pt")
    # resumed past its start (the last 1 of 4), it narrows them at its first iteration
    draws.clear()
    train.main([*SHORT, "--max-iterations", "4", "--nominal-physics-iterations", "1",
                "--resume", str(run), "--log-dir", str(run)])  # fmt: skip
    out = capsys.readouterr().out
    assert "iteration 3: new episodes draw the model's own physics" in out
    assert "iteration 3: entropy bonus 0\n" in out  # the stage's, from its first iteration
    assert draws[-1][0] == Randomization.nominal()


def test_the_late_stage_changes_the_rewards_values_and_resumes_into_it(tmp_path, capsys,
                                                                      monkeypatch):  # fmt: skip
    calls = []
    set_reward = Core.set_reward

    def spy(self, costs=None, shaping=None):
        calls.append((costs, shaping))
        return set_reward(self, costs, shaping)

    monkeypatch.setattr(Core, "set_reward", spy)
    shaped = [*SHORT, "--env.shaping.tracking", "300", "--costs"]
    run = tmp_path / "run"
    # iterations 1-3 are one learn() call: the late stage begins after its first update
    # (before iteration 2), the model's physics after its second (before iteration 3)
    train.main([*shaped, "--max-iterations", "4", "--save-interval", "4",
                "--nominal-physics-iterations", "1", "--late-iterations", "2",
                "--late-sigma", "0.04", "--late-clearance-target", "0.025",
                "--late-tracking", "200", "--log-dir", str(run)])  # fmt: skip
    out = capsys.readouterr().out
    late = ("iteration 2: the reward's late values --env.shaping.tracking 200, "
            "--env.shaping.sigma 0.04, --env.costs.clearance-target 0.025")  # fmt: skip
    physics = "iteration 3: new episodes draw the model's own physics but for friction"
    assert late in out and physics in out and out.index(late) < out.index(physics)
    ((costs, shaping),) = calls
    assert (shaping.sigma, shaping.tracking, costs.clearance_target) == (0.04, 200.0, 0.025)
    assert costs.clearance == GaitCosts().clearance  # the other values as they were
    # the iterations before the stage are the plain run's, bit for bit
    plain = tmp_path / "plain"
    train.main([*shaped, "--max-iterations", "2", "--nominal-physics-iterations", "0",
                "--log-dir", str(plain)])  # fmt: skip
    assert_same_actor(run / "model_0.pt", plain / "model_0.pt")  # model_0: before it
    # resumed past its start, the stage begins at the first iteration
    calls.clear()
    train.main([*shaped, "--max-iterations", "5", "--nominal-physics-iterations", "1",
                "--late-iterations", "2", "--late-sigma", "0.04", "--late-clearance-target",
                "0.025", "--late-tracking", "200", "--resume", str(run),
                "--log-dir", str(run)])  # fmt: skip
    assert "iteration 4: the reward's late values" in capsys.readouterr().out
    assert len(calls) == 1


def test_the_flat_kinds_walk_level_0_within_their_window(tmp_path, capsys):
    run = tmp_path / "run"
    # one learn() call (iterations 0-3): the window is iterations 1 and 2
    train.main([*SHORT, "--max-iterations", "4", "--save-interval", "4", "--flat-kinds",
                "stones", "--flat-from", "1", "--flat-until", "3",
                "--log-dir", str(run)])  # fmt: skip
    out = capsys.readouterr().out
    flat = "iteration 1: the 2 envs on stones tiles walk level 0\n"
    back = "iteration 3: the 2 envs on stones tiles walk the curriculum again from drawn levels\n"
    assert flat in out and back in out and out.index(flat) < out.index(back)
    record = json.loads((run / "config.json").read_text())["train"]
    assert (record["flat_kinds"], record["flat_from"], record["flat_until"]) == (["stones"], 1, 3)
    # resumed past the window, the levels are the checkpoint's: no window begins again
    train.main([*SHORT, "--max-iterations", "6", "--flat-kinds", "stones", "--flat-from", "1",
                "--flat-until", "3", "--resume", str(run), "--log-dir", str(run)])  # fmt: skip
    assert "envs on stones tiles" not in capsys.readouterr().out
    # a window to the run's end: the stones envs (every fourth of 8) end at level 0
    until_end = tmp_path / "until_end"
    train.main([*SHORT, "--max-iterations", "3", "--save-interval", "3", "--flat-kinds",
                "stones", "--log-dir", str(until_end)])  # fmt: skip
    assert "iteration 0: the 2 envs on stones tiles walk level 0" in capsys.readouterr().out
    levels = load_checkpoint(until_end / "model_2.pt")["env_state"]["terrain_level"]
    assert levels[3::4].tolist() == [0, 0]


def test_by_default_the_last_third_keeps_only_friction_randomised(tmp_path, draws, capsys):
    # iterations 1 and 2 are one learn() call (--save-interval 3): the stage starts
    # inside it, after iteration 1's update, and adds no checkpoint
    train.main([*SHORT, "--max-iterations", "3", "--save-interval", "3",
                "--log-dir", str(tmp_path / "run")])  # fmt: skip
    out = capsys.readouterr().out
    assert "iteration 2: new episodes draw the model's own physics but for friction" in out
    assert "entropy bonus" not in out  # --entropy-coef throughout
    assert sorted(p.name for p in (tmp_path / "run").glob("model_*.pt")) == [
        "model_0.pt", "model_2.pt"]  # fmt: skip
    stage = Randomization.nominal(friction=Randomization().friction)
    assert draws[0][0] == Randomization()  # randomised before the stage
    after = torch.cat([p for ranges, p in draws if ranges == stage])
    assert len(after) > 1 and draws[-1][0] == stage
    assert torch.equal(after[:, 1:], NOMINAL[1:].expand(len(after), -1))  # all but friction
    assert len(set(after[:, 0].tolist())) > 1  # friction still drawn


def test_the_logged_mirror_loss_once_per_update_trains_the_same_bits(tmp_path, monkeypatch):
    from rwalk.rl import runner

    flags = [*TINY, "--max-iterations", "2", "--num-learning-epochs", "2",
             "--num-mini-batches", "2"]  # fmt: skip
    train.main([*flags, "--log-dir", str(tmp_path / "once")])
    every_mini_batch = lambda alg: alg.symmetry.compute_loss  # noqa: E731 (rsl-rl's own)
    monkeypatch.setattr(runner, "_mirror_loss_once_per_update", every_mini_batch)
    train.main([*flags, "--log-dir", str(tmp_path / "every")])
    once, every = (load_checkpoint(tmp_path / run / "model_1.pt") for run in ("once", "every"))
    for model in ("actor_state_dict", "critic_state_dict"):
        assert once[model].keys() == every[model].keys()
        for name, tensor in once[model].items():
            assert torch.equal(tensor, every[model][name]), name
    states = [checkpoint["optimizer_state_dict"]["state"] for checkpoint in (once, every)]
    assert states[0].keys() == states[1].keys()
    for key, state in states[0].items():
        for name, value in state.items():
            assert torch.equal(torch.as_tensor(value), torch.as_tensor(states[1][key][name]))
    logged = [read_scalars(tmp_path / run)["Loss/symmetry"] for run in ("once", "every")]
    assert len(logged[0]) == len(logged[1]) == 2 and all(value >= 0 for *_, value in logged[0])


def test_the_logged_mirror_loss_is_measured_once_per_update_without_autograd():
    from types import SimpleNamespace

    from rwalk.rl.runner import _mirror_loss_once_per_update

    grad_enabled = []

    def compute(actor, batch, original_batch_size):
        grad_enabled.append(torch.is_grad_enabled())
        return torch.tensor(float(len(grad_enabled)))

    symmetry = SimpleNamespace(compute_loss=compute)
    alg = SimpleNamespace(symmetry=symmetry, num_learning_epochs=2, num_mini_batches=3)
    loss = _mirror_loss_once_per_update(alg)
    assert [float(loss(None, None, 0)) for _ in range(12)] == [1.0] * 6 + [2.0] * 6
    assert grad_enabled == [False, False]  # two updates of six mini-batches
