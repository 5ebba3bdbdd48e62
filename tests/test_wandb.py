"""rwalk-train --logger wandb: rsl-rl's W&B writer, offline (WANDB_MODE=offline), one W&B
run per training however many learn() chunks it takes, its files in the run folder, and
continued by a resumed training; without wandb, a one-line error."""

import dataclasses

import pytest
from test_train_safety import TINY

from rwalk.rl import wandb_writer
from rwalk.rl.config import TrainArgs
from rwalk.rl.training import rsl_rl_config
from rwalk.runners import train


def test_tensorboard_stays_the_default():
    config = rsl_rl_config(TrainArgs())
    assert "logger" not in config  # rsl-rl's default: its TensorBoard writer


def test_the_wandb_config_names_project_and_run():
    args = dataclasses.replace(TrainArgs(), logger="wandb", wandb_project="p", run_name="r")
    assert rsl_rl_config(args)["logger"] == {
        "class_name": "rwalk.rl.wandb_writer:WandbWriter", "project_name": "p", "run_name": "r",
    }  # fmt: skip


def test_without_wandb_the_training_stops_in_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(wandb_writer, "wandb", None)
    with pytest.raises(SystemExit) as exit_:
        train.main([*TINY, "--log-dir", str(tmp_path / "run"), "--logger", "wandb"])
    assert "pip install 'rwalk[wandb]'" in str(exit_.value)
    assert not (tmp_path / "run" / "model_0.pt").exists()  # refused before training


def offline(monkeypatch) -> None:
    """W&B offline and silent, with no WANDB_DIR of the user's."""
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    monkeypatch.delenv("WANDB_DIR", raising=False)


def test_a_chunked_training_is_one_named_offline_wandb_run(tmp_path, monkeypatch):
    wandb = pytest.importorskip("wandb")
    offline(monkeypatch)
    logged, names, inits = [], [], []
    finish, init = wandb.finish, wandb.init

    def spy_init(*a, **kw):  # wandb.init binds wandb.log to the new run: spy on that
        inits.append(kw.get("project"))
        run = init(*a, **kw)
        log = wandb.log

        def spy_log(data, step=None, **kw):
            logged.append((step, *data))
            return log(data, step=step, **kw)

        monkeypatch.setattr(wandb, "log", spy_log)
        return run

    def spy_finish(*a, **kw):
        names.append(wandb.run.name)
        return finish(*a, **kw)

    monkeypatch.setattr(wandb, "finish", spy_finish)
    monkeypatch.setattr(wandb, "init", spy_init)
    train.main([*TINY, "--log-dir", str(tmp_path / "run"), "--max-iterations", "3",
                "--save-interval", "1", "--logger", "wandb", "--wandb-project", "rwalk-test",
                "--run-name", "tiny"])  # fmt: skip
    assert inits == ["rwalk-test"]  # 3 learn() chunks, one W&B run
    assert names == ["tiny"] and wandb.run is None  # finished with the training
    steps = {step for step, *keys in logged if "Episode_Reward/velocity_tracking" in keys}
    assert steps == {0, 1, 2}
    runs = list((tmp_path / "run" / "wandb").glob("offline-run-*"))
    assert len(runs) == 1 and list(runs[0].glob("*.wandb"))
    assert list((tmp_path / "run").glob("events.out.tfevents.*"))  # TensorBoard as well


def test_wandb_writes_into_the_run_folder_not_the_current_directory(tmp_path, monkeypatch):
    pytest.importorskip("wandb")
    offline(monkeypatch)
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    train.main([*TINY, "--log-dir", str(tmp_path / "run"), "--max-iterations", "1",
                "--logger", "wandb", "--wandb-project", "rwalk-test"])  # fmt: skip
    assert not list(cwd.iterdir())
    assert list((tmp_path / "run" / "wandb").glob("offline-run-*"))


def test_a_resumed_training_goes_on_with_its_wandb_run(tmp_path, monkeypatch):
    wandb = pytest.importorskip("wandb")
    offline(monkeypatch)
    inits, init = [], wandb.init

    def spy_init(*a, **kw):
        run = init(*a, **kw)
        inits.append((kw.get("id"), kw.get("resume"), run.id))
        return run

    monkeypatch.setattr(wandb, "init", spy_init)
    run_dir = tmp_path / "run"

    def tiny(*flags: str) -> str:
        train.main([*TINY, "--log-dir", str(run_dir), "--logger", "wandb",
                    "--wandb-project", "rwalk-test", *flags])  # fmt: skip
        return (run_dir / wandb_writer.ID_FILE).read_text().strip()

    first = tiny("--max-iterations", "2")
    assert inits == [(None, None, first)]  # a new W&B run, its id kept in the folder
    assert tiny("--resume", str(run_dir), "--max-iterations", "3") == first
    assert inits[1] == (first, "allow", first)
    again = tiny("--overwrite", "--max-iterations", "1")  # another run in the folder
    assert inits[2] == (None, None, again) and again != first


def test_an_id_file_without_an_id_starts_a_new_wandb_run(tmp_path, capsys):
    (tmp_path / wandb_writer.ID_FILE).write_text("../not an id\n")
    assert wandb_writer.saved_run_id(tmp_path) is None
    assert "holds no W&B run id" in capsys.readouterr().out
    (tmp_path / wandb_writer.ID_FILE).write_text("ze42uwms\n")
    assert wandb_writer.saved_run_id(tmp_path) == "ze42uwms"
