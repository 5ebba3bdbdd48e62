"""The runtime against the env: torch-free, bit for bit in closed loop, and rwalk-sim2sim."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from conftest import write_run
from deploy_exports import make_exports

from rwalk import presets, sim2sim
from rwalk.deploy import Controller
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.gait import BezierGaitController
from rwalk.kinematics import LegGeometry

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def exports(tmp_path_factory) -> Path:
    return make_exports(tmp_path_factory.mktemp("exports"))


def test_the_runtime_and_its_tests_run_where_torch_cannot_be_imported(exports):
    code = (
        "import sys; sys.modules['torch'] = None\n"  # import torch raises ImportError
        "import pytest\n"
        "sys.exit(pytest.main(['-q', '-p', 'no:cacheprovider', 'tests/test_deploy_runtime.py']))"
    )
    env = {**os.environ, "RWALK_DEPLOY_EXPORTS": str(exports)}
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=300, check=False)  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    summary = done.stdout.strip().splitlines()[-1]  # e.g. "13 passed in 3.11s"
    assert re.match(r"\d+ passed\b", summary), summary  # none skipped for want of torch
    assert not re.search(r"skipped|xfail|deselected", summary), summary


def test_the_export_carries_the_gait_and_legs_bit_for_bit(exports):
    deploy = json.loads((exports / "mlp" / "policy.json").read_text())["deploy"]
    assert deploy["task"] == "residual_walk"
    assert (deploy["substeps"], deploy["dt"], deploy["residual_scale"]) == (5, 0.004, 0.02)
    assert deploy["cycle_steps"] == 30  # 0.6 s of 20 ms periods
    assert LegGeometry(**{k: tuple(map(lambda v: tuple(v) if isinstance(v, list) else v, x))
                          if isinstance(x, list) else x
                          for k, x in deploy["leg_geometry"].items()}) == LegGeometry()  # fmt: skip
    controller = BezierGaitController(dt=0.004)
    np.testing.assert_array_equal(np.array(deploy["gait"]["targets"]), controller.target_table)
    np.testing.assert_array_equal(
        np.array(deploy["gait"]["phase_features"]), controller.phase_table
    )


def _env(task: str = "residual_walk", n: int = 3, steps: int = 80, gait_action: str = "target",
         **options) -> BatchedEnv:  # fmt: skip
    adaptive = {"command_range": (0.05, 0.25), "gait_action": gait_action}
    config = presets.evaluation_config(task, max_steps=steps, settle_steps=50,
                                       **(adaptive if task == "adaptive_gait" else {}))  # fmt: skip
    config = dataclasses.replace(config, **options)
    return BatchedEnv(n, config, seed=0, task=task)


@pytest.mark.parametrize(
    ("policy", "task"),
    [
        ("mlp", "residual_walk"),
        ("gru", "residual_walk"),
        ("adaptive", "adaptive_gait"),
        ("schedule", "adaptive_gait"),
    ],
)
def test_the_runtime_on_mj_step_follows_the_env_bit_for_bit(exports, policy, task):
    env = _env(task, gait_action="schedule" if policy == "schedule" else "target")
    traces = sim2sim.closed_loop(exports / policy, env, seed=7, steps=80)
    assert [t.env for t in traces] == [0, 1, 2]
    assert all(t.steps >= 10 for t in traces)  # (these random policies fall soon)
    assert all(t.first_difference is None and t.max_difference == 0.0 for t in traces)


def test_a_schedule_whose_step_rises_with_the_speed_runs_bit_for_bit(exports, tmp_path):
    folder = Path(shutil.copytree(exports / "schedule", tmp_path / "schedule"))
    layout = json.loads((folder / "policy.json").read_text())
    assert layout["deploy"]["adaptive"]["schedule"]["step_rise"] == 0.0  # the export's own
    layout["deploy"]["adaptive"]["schedule"]["step_rise"] = 0.04
    (folder / "policy.json").write_text(json.dumps(layout))
    env = _env("adaptive_gait", gait_action="schedule", schedule_step_rise=0.04)
    traces = sim2sim.closed_loop(folder, env, seed=7, steps=80)
    assert env.core.task.scheduled()[:, 0].unique().numel() == 3  # three commands, three steps
    assert all(t.first_difference is None and t.max_difference == 0.0 for t in traces)
    differs = sim2sim.closed_loop(folder, _env("adaptive_gait", gait_action="schedule"), 7, 80)
    assert all(t.max_difference > 0.0 for t in differs)  # the rise is read, not ignored


def test_the_comparison_sees_a_runtime_that_differs(exports, tmp_path):
    folder = Path(shutil.copytree(exports / "mlp", tmp_path / "mlp"))
    layout = json.loads((folder / "policy.json").read_text())
    layout["deploy"]["residual_scale"] *= 1.0 + 1e-12
    (folder / "policy.json").write_text(json.dumps(layout))
    traces = sim2sim.closed_loop(folder, _env(), seed=7, steps=80)
    assert all(t.first_difference == 1 and t.max_difference > 0.0 for t in traces)


def test_the_walk_table_checks_the_band_by_hand():
    def row(physics, falls, falls_se, error, error_se):
        return {"world": "w.xml", "physics": physics, "fall_rate": falls,
                "fall_rate_se": falls_se, "velocity_error": error,
                "velocity_error_se": error_se}  # fmt: skip

    # band 2: falls |0.10 - 0.05| = 0.05 <= 2 x 0.03; error |0.020 - 0.017| <= 2 x max(0.001,
    # 0.002) = 0.004 -> yes. With error 0.022: 0.005 > 0.004 -> no.
    within = sim2sim.walk_table(
        [row("env", 0.10, 0.03, 0.020, 0.001), row("reference", 0.05, 0.03, 0.017, 0.001)], band=2.0
    )
    assert "| w.xml | env | 10% ± 3% | 0.0200 ± 0.0010 | yes |" in within
    outside = sim2sim.walk_table(
        [row("env", 0.10, 0.03, 0.022, 0.001), row("reference", 0.05, 0.03, 0.017, 0.001)], band=2.0
    )
    assert "| no |" in outside  # fmt: skip


def test_the_walks_settle_their_starts_as_the_env_does(exports, monkeypatch):
    """The runtime's walks begin where the env's evaluation begins an episode: after its
    settle steps of the zero-residual gait from phase 0 (here on the world's own mj_step),
    the gait at the tick where settling leaves a start. They began from standing, at phase 0."""
    core = _env(n=1).core  # 50 settle steps
    world, settle = core.world, sim2sim.Settle.of(core)
    np.testing.assert_array_equal(settle.ctrl, world.base_gait_ctrl(50 * world.decimation))
    assert settle.tick == world.settled_tick == 50 * world.decimation % world.controller.period
    assert settle.tick != 0
    applied, resets = [], []
    step, reset = mujoco.mj_step, Controller.reset

    def spy_step(model, data, nstep=1):
        applied.append(data.ctrl.copy())
        step(model, data, nstep)

    def spy_reset(self, readings, tick=0):
        resets.append((len(applied), tick))
        return reset(self, readings, tick)

    monkeypatch.setattr(mujoco, "mj_step", spy_step)
    monkeypatch.setattr(Controller, "reset", spy_reset)
    walked = sim2sim.walk(exports / "mlp", Path("model/world_flat.xml"), 1, 3, 0.1333,
                          settle=settle)  # fmt: skip
    assert walked.episodes == 1
    (start,) = resets  # one episode: the policy takes over after the settling substeps
    assert start == (len(settle.ctrl), settle.tick)
    np.testing.assert_array_equal(np.array(applied[: len(settle.ctrl)]), settle.ctrl)
    assert len(applied) > len(settle.ctrl)  # then the policy's periods


def test_a_world_whose_timestep_does_not_fit_the_runtime_is_named(exports, tmp_path):
    for name in ("robot.xml", "world_flat.xml"):
        shutil.copy(ROOT / "model" / name, tmp_path / name)
    robot = tmp_path / "robot.xml"
    robot.write_text(robot.read_text().replace('timestep="0.004"', 'timestep="1e-300"'))
    world = tmp_path / "world_flat.xml"
    for check in (lambda: sim2sim.walk(exports / "mlp", world, 1, 2, 0.1),  # was a TypeError
                  lambda: sim2sim.check_world(world, 0.004)):  # fmt: skip
        with pytest.raises(ValueError, match=r"timestep 1e-300 s does not divide the runtime's"):
            check()


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """A robust GRU run's checkpoint and config.json, as rwalk-train writes them."""
    torch.manual_seed(0)
    return write_run(tmp_path_factory.mktemp("run"), actor="gru", rnn_hidden_dim=8)


def test_rwalk_sim2sim_exports_compares_and_walks(checkpoint, tmp_path, capsys, monkeypatch):
    from rwalk.runners.sim2sim import main

    settles, walk = [], sim2sim.walk
    monkeypatch.setattr(
        sim2sim, "walk", lambda *a, **k: settles.append(k["settle"]) or walk(*a, **k)
    )
    out = tmp_path / "out"
    main([str(checkpoint), "--out", str(out), "--episodes", "2", "--steps", "30",
          "--world", "model/world_flat.xml", "--walk-episodes", "2",
          "--json", str(tmp_path / "s2s.json")])  # fmt: skip
    printed = capsys.readouterr().out
    assert "closed loop: 2/2 episodes bit-identical" in printed
    assert "| world_flat.xml | env |" in printed and "| world_flat.xml | reference |" in printed
    saved = json.loads((tmp_path / "s2s.json").read_text())
    assert saved["settle_steps"] == presets.EVALUATION.settle_steps  # the walks' settling too
    substeps = json.loads((out / "exported" / "policy.json").read_text())["deploy"]["substeps"]
    assert len(settles) == 2 and all(
        len(s.ctrl) == presets.EVALUATION.settle_steps * substeps for s in settles
    )
    assert 0.0 <= saved["policy_gap"] < 1e-5  # onnxruntime's float32 matmuls against torch's
    assert [w["physics"] for w in saved["walks"]] == ["env", "reference"]
    assert sorted(p.name for p in (out / "exported").iterdir()) == [
        "policy.json", "policy.onnx", "policy.pt"
    ]  # fmt: skip


def test_rwalk_sim2sim_refuses_a_missing_world_in_one_line(checkpoint, capsys):
    from rwalk.runners.sim2sim import main

    with pytest.raises(SystemExit) as exit_info:
        main([str(checkpoint), "--world", "nope.xml"])
    assert exit_info.value.code == 2
    assert "--world: 'nope.xml' not found" in capsys.readouterr().err


def refused(argv: list[str], capsys) -> str:
    """rwalk-sim2sim ``argv`` (in this process): the one line it exits 2 with."""
    from rwalk.runners.sim2sim import main

    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    err = capsys.readouterr().err.strip()
    assert exit_info.value.code == 2 and "\n" not in err, err
    return err


def test_rwalk_sim2sim_refuses_what_it_could_not_write_before_evaluating(
    checkpoint, tmp_path, monkeypatch, capsys
):
    def never(*args, **kwargs):
        raise AssertionError("evaluated before refusing")

    monkeypatch.setattr("rwalk.export.export_policy", never)
    monkeypatch.setattr(sim2sim, "closed_loop", never)
    (tmp_path / "file").write_text("x")
    flags = [str(checkpoint), "--episodes", "1", "--steps", "2", "--world"]
    err = refused([*flags, "--json", str(tmp_path / "file" / "s2s.json")], capsys)
    assert "error: --json " in err and "file' is not a folder" in err
    err = refused([*flags, "--json", str(tmp_path)], capsys)
    assert "error: --json " in err and "is a folder" in err
    err = refused([*flags, "--out", str(tmp_path / "file")], capsys)  # it was a traceback
    assert "error: --out " in err and "file' is not a folder" in err
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "exported").write_text("x")
    err = refused([*flags, "--out", str(tmp_path / "out")], capsys)
    assert "error: --out " in err and "exported' is not a folder" in err


def test_rwalk_sim2sim_refuses_a_teacher_before_exporting(tmp_path, capsys):
    teacher = write_run(tmp_path, teacher=True)
    out = tmp_path / "out"
    err = refused([str(teacher), "--out", str(out), "--world"], capsys)
    assert "is a teacher" in err and "'physics', 'heights'" in err and "privileged" in err
    assert not out.exists()  # nothing written


def test_rwalk_sim2sim_names_a_world_of_an_absurd_timestep_in_one_line(
    checkpoint, tmp_path, capsys
):
    for name in ("robot.xml", "world_flat.xml"):
        shutil.copy(ROOT / "model" / name, tmp_path / name)
    robot = tmp_path / "robot.xml"
    robot.write_text(robot.read_text().replace('timestep="0.004"', 'timestep="1e-300"'))
    out = tmp_path / "out"
    err = refused([str(checkpoint), "--out", str(out), "--episodes", "1", "--steps", "2",
                   "--world", str(tmp_path / "world_flat.xml")], capsys)  # fmt: skip
    assert "error: --world:" in err and "timestep 1e-300 s does not divide" in err
    assert not out.exists()  # before the export


def test_the_readme_deploy_snippet_walks_a_simulated_robot(exports):
    """README's Deploy example, as written there (2 periods of an exported policy)."""
    section = (ROOT / "README.md").read_text().split("## Deploy", 1)[1].split("\n## ", 1)[0]
    (code,) = re.findall(r"```python\n(.*?)```", section, re.DOTALL)
    assert '"logs/rwalk/student/exported"' in code and "range(250)" in code
    code = code.replace('"logs/rwalk/student/exported"', repr(str(exports / "gru")))
    code = code.replace("range(250)", "range(2)")
    namespace: dict = {}
    exec(compile(code, "README.md deploy", "exec"), namespace)
    controller, data = namespace["controller"], namespace["data"]
    assert namespace["targets"].shape == (5, 12) and controller.gait.tick == 10
    assert data.time == pytest.approx(0.04) and controller.state[0].any()
