"""What an unlucky or hostile user still hit: data loss, tracebacks and late checks of the
trainers and play, each ending now in one named line before any work."""

import shutil
from pathlib import Path

import pytest
import torch

from rwalk.rl.checkpoints import load_checkpoint, save_checkpoint
from rwalk.runners import play, train

TINY = ["--num-envs", "4", "--num-steps-per-env", "4", "--settle-steps", "2",
        "--max-episode-steps", "20", "--hidden-dims", "8", "--save-interval", "1",
        "--no-export", "--recipe", "plain"]  # fmt: skip


@pytest.fixture(scope="module")
def teacher(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("teacher")
    train.main([*TINY, "--teacher", "--max-iterations", "2", "--log-dir", str(folder)])
    return folder


def refused(*flags: str) -> str:
    with pytest.raises(SystemExit) as exit_:
        train.main([*TINY, *flags])
    return str(exit_.value.code)


def test_a_student_pointed_at_its_teachers_folder_deletes_nothing(teacher, tmp_path):
    folder = Path(shutil.copytree(teacher, tmp_path / "teacher"))
    before = sorted(p.name for p in folder.iterdir())
    message = refused("--distill", str(folder), "--log-dir", str(folder), "--overwrite",
                      "--max-iterations", "2")  # fmt: skip
    assert "the teacher's run is --log-dir" in message and "choose another --log-dir" in message
    assert sorted(p.name for p in folder.iterdir()) == before


@pytest.mark.parametrize("key", ["actor_state_dict", "critic_state_dict"])
def test_a_checkpoint_with_nan_weights_is_named_before_it_trains(teacher, tmp_path, key):
    folder = Path(shutil.copytree(teacher, tmp_path / "nan"))
    state = load_checkpoint(folder / "model_1.pt")
    name = next(n for n, t in state[key].items() if t.is_floating_point())
    state[key][name] = torch.full_like(state[key][name], float("nan"))
    save_checkpoint(state, folder / "model_1.pt")
    out = tmp_path / "out"
    saved = str(folder / "model_1.pt")
    resume = ["--resume", saved, "--log-dir", str(folder), "--max-iterations", "3"]
    distill = ["--distill", saved, "--log-dir", str(out), "--max-iterations", "2"]
    for flags in (resume, distill):
        if key == "critic_state_dict" and "--distill" in flags:
            continue  # a distillation reads the teacher's actor only
        message = refused(*flags, *(["--teacher"] if "--resume" in flags else []))
        assert "model_1.pt" in message and "non-finite values" in message and key in message
    assert not out.exists() or not list(out.glob("*.pt"))


@pytest.mark.parametrize("flags", [["--costs", "--clearance-weight", "1e308"],
                                   ["--env.reward-weights.stability", "-1e300"]])  # fmt: skip
def test_an_absurd_weight_is_a_usage_error_naming_it(flags, capsys):
    with pytest.raises(SystemExit) as exit_:
        train.parse_args(flags)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "within ±1e+06" in err and err.count("\n") == 1


def test_play_refuses_an_unwritable_json_before_it_evaluates(tmp_path, capsys):
    blocked = tmp_path / "file"
    blocked.write_text("x")
    with pytest.raises(SystemExit) as exit_:
        play.main(["--base-gait", "--json", str(blocked / "rows.json")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "--json" in err and "evaluating" not in err
