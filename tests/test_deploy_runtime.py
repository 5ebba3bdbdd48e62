"""rwalk.deploy's runtime, torch-free: these tests also run in a process where importing
torch fails (tests/test_deploy.py runs them there, with RWALK_DEPLOY_EXPORTS set)."""

from __future__ import annotations

import json
import os
import shutil
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from rwalk.deploy import SENSOR_LAYOUT, Controller

TORCH_FREE = "RWALK_DEPLOY_EXPORTS" in os.environ


def export_folders(tmp_path_factory) -> Path:
    """The test exports: RWALK_DEPLOY_EXPORTS in the torch-free run, else made once a
    session (tests/deploy_exports.py; tests/test_deploy_hostile.py shares them)."""
    if TORCH_FREE:
        return Path(os.environ["RWALK_DEPLOY_EXPORTS"])
    root = tmp_path_factory.getbasetemp() / "deploy_exports"
    if not (root / "made").is_file():
        from deploy_exports import make_exports

        root.mkdir(exist_ok=True)
        make_exports(root)
        (root / "made").touch()
    return root


@pytest.fixture(scope="module")
def exports(tmp_path_factory) -> Path:
    return export_folders(tmp_path_factory)


@pytest.fixture
def readings(exports) -> np.ndarray:
    return np.load(exports / "readings.npy")[0]


def _copy(exports: Path, tmp_path: Path, actor: str = "mlp") -> Path:
    return Path(shutil.copytree(exports / actor, tmp_path / actor))


def _edit(folder: Path, change) -> None:
    layout = json.loads((folder / "policy.json").read_text())
    change(layout)
    (folder / "policy.json").write_text(json.dumps(layout))


def test_torch_is_absent_where_asked():
    if TORCH_FREE:
        assert sys.modules["torch"] is None  # blocked, and nothing imported it before
        with pytest.raises(ImportError):
            import torch  # noqa: F401


def test_the_sensor_layout_is_the_observations_65_values():
    assert sum(width for _, width in SENSOR_LAYOUT) == 65
    assert SENSOR_LAYOUT[0] == ("torso_pos", 3) and SENSOR_LAYOUT[-1] == ("RR_contact", 1)


@pytest.mark.parametrize("actor", ["mlp", "gru"])
def test_a_period_gives_finite_targets_within_the_joint_limits(exports, readings, actor):
    controller = Controller(exports / actor)
    first = controller.reset(readings)
    assert first.shape == (controller.substeps, 12) and controller.control_dt == pytest.approx(0.02)
    targets = controller.step(readings)
    assert targets.shape == (5, 12) and np.isfinite(targets).all() and not controller.held
    lower = np.tile(controller.geometry.joint_lower, 4)
    upper = np.tile(controller.geometry.joint_upper, 4)
    assert (targets >= lower).all() and (targets <= upper).all()
    assert controller.gait.tick == 5
    if actor == "gru":  # the state moves, and reset() clears it
        assert np.abs(controller.state[0]).max() > 0
        controller.reset(readings)
        assert not np.abs(controller.state[0]).any()


def test_the_same_readings_after_reset_give_the_same_bits(exports, readings):
    controller = Controller(exports / "gru")
    controller.reset(readings)
    runs = []
    for _ in range(2):
        controller.reset(readings)
        runs.append(np.stack([controller.step(readings) for _ in range(3)]))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_non_finite_readings_hold_the_last_safe_targets_and_say_so(exports, readings):
    controller = Controller(exports / "mlp")
    controller.reset(readings)
    good = controller.step(readings)
    bad = readings.copy()
    bad[7] = np.nan
    bad[62] = np.inf
    with pytest.warns(UserWarning, match=r"torso_linvel\[0\]=nan, FR_contact\[0\]=inf"):
        held = controller.step(bad)
    assert controller.held and np.isfinite(held).all()
    np.testing.assert_array_equal(held, np.repeat(good[-1:], 5, axis=0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        controller.step(readings)  # finite readings go on
    assert not controller.held and controller.gait.tick == 10


def test_a_non_finite_policy_output_is_held_too(exports, readings, tmp_path):
    controller = Controller(exports / "mlp")
    first = controller.reset(readings)
    huge = readings.copy()
    huge[0] = 1e39  # finite, but the float32 input overflows to inf: the output is NaN
    with pytest.warns(UserWarning, match="non-finite policy output"):
        held = controller.step(huge)
    np.testing.assert_array_equal(held, np.repeat(first[-1:], 5, axis=0))


def test_bad_readings_and_order_are_clear_errors(exports, readings):
    controller = Controller(exports / "mlp")
    with pytest.raises(RuntimeError, match="reset"):
        controller.step(readings)
    with pytest.raises(ValueError, match=r"65 values .* got shape \(64,\)"):
        controller.reset(readings[:64])
    with pytest.raises(ValueError, match=r"finite readings; got torso_pos\[2\]=nan"):
        controller.reset(np.where(np.arange(65) == 2, np.nan, readings))
    with pytest.raises(ValueError, match="tick must be a whole number in \\[0, 150\\), got 150"):
        controller.reset(readings, tick=150)
    controller.reset(readings)
    with pytest.raises(ValueError, match=r"got shape \(2, 65\)"):
        controller.step(np.stack([readings, readings]))


def test_missing_and_mismatched_files_are_named(exports, tmp_path):
    folder = _copy(exports, tmp_path)
    (folder / "policy.onnx").unlink()
    with pytest.raises(FileNotFoundError, match=r"has no policy\.onnx"):
        Controller(folder)
    folder = _copy(exports, tmp_path / "b")
    (folder / "policy.json").write_text("{not json")
    with pytest.raises(ValueError, match="is not JSON"):
        Controller(folder)
    folder = _copy(exports, tmp_path / "c")
    _edit(folder, lambda layout: layout.pop("deploy"))
    with pytest.raises(ValueError, match="has no deploy section"):
        Controller(folder)
    folder = _copy(exports, tmp_path / "d")
    _edit(folder, lambda layout: layout["deploy"].update(task="stand", runtime="hop"))
    with pytest.raises(ValueError, match=r"'stand' policy with deploy\.runtime 'hop'; "):
        Controller(folder)
    folder = _copy(exports, tmp_path / "d1")  # an export from before deploy.runtime: its task's
    _edit(folder, lambda layout: layout["deploy"].pop("runtime"))
    assert Controller(folder).gait.period > 0
    _edit(folder, lambda layout: layout["deploy"].update(task="stand"))
    with pytest.raises(ValueError, match=r"'stand' policy with deploy\.runtime None"):
        Controller(folder)
    folder = _copy(exports, tmp_path / "d2", "adaptive")
    _edit(folder, lambda layout: layout["deploy"]["adaptive"].pop("delta"))
    with pytest.raises(ValueError, match=r"policy\.json': deploy\.adaptive\.delta is missing$"):
        Controller(folder)
    folder = _copy(exports, tmp_path / "e")
    _edit(folder, lambda layout: layout["input"]["shape"].__setitem__(1, 70))
    with pytest.raises(ValueError, match="obs of width 70"):
        Controller(folder)
    folder = _copy(exports, tmp_path / "f")
    _edit(folder, lambda layout: layout["input"]["pieces"].append({"name": "heights"}))
    with pytest.raises(ValueError, match=r"reads \['heights'\] \(privileged"):
        Controller(folder)
    folder = _copy(exports, tmp_path / "g", "gru")
    _edit(folder, lambda layout: layout["recurrent"].update(hidden=9))
    with pytest.raises(ValueError, match=r"h_in has shape .*says \(layers, batch, hidden\)"):
        Controller(folder)
    folder = _copy(exports, tmp_path / "h")
    (folder / "policy.onnx").write_bytes(b"not a model")
    with pytest.raises(ValueError, match="is not a loadable ONNX model"):
        Controller(folder)


def test_a_commanded_policy_needs_its_command(exports, readings, tmp_path):
    folder = _copy(exports, tmp_path)

    def command_instead_of_lateral_offset(layout):
        layout["input"]["pieces"][-1]["name"] = "command"

    _edit(folder, command_instead_of_lateral_offset)
    controller = Controller(folder)
    controller.reset(readings)
    with pytest.raises(ValueError, match=r"set controller\.command"):
        controller.step(readings)
    controller.command = 0.15
    assert controller.policy_input(readings)[-1] == np.float32(0.15)


def test_an_adaptive_policy_moves_its_gait_within_the_bounds(exports, readings):
    controller = Controller(exports / "adaptive")
    gait = controller.gait
    controller.reset(readings, tick=75)
    assert gait.phase.tolist() == [0.5] and gait.gait_action == "target"
    np.testing.assert_array_equal(gait.params, gait.start)
    controller.command = 0.2
    first = gait.params.copy()
    for _ in range(3):
        targets = controller.step(readings)
    assert targets.shape == (5, 12) and np.isfinite(targets).all()
    moved = np.abs(gait.params - first)
    assert moved.any() and (moved <= 3 * gait.delta + 1e-15).all()  # at most delta a period
    assert ((gait.params >= gait.low) & (gait.params <= gait.high)).all()
    assert controller.policy_input(readings)[65:69].tolist() == pytest.approx(
        ((gait.params - gait.centre) / gait.half_width).tolist()
    )


def test_an_export_from_before_the_step_rise_reads_none(exports, tmp_path):
    folder = _copy(exports, tmp_path, "schedule")
    _edit(folder, lambda layout: layout["deploy"]["adaptive"]["schedule"].pop("step_rise"))
    older, current = Controller(folder).gait, Controller(exports / "schedule").gait
    assert older.step_rise == 0.0
    for speed in (0.05, 0.2):
        np.testing.assert_array_equal(older.scheduled(speed), current.scheduled(speed))


def test_a_scheduled_gait_follows_the_command_and_refuses_a_backward_one(exports, readings):
    controller = Controller(exports / "schedule")
    gait = controller.gait
    assert gait.gait_action == "schedule" and gait.stride == 0.06
    np.testing.assert_array_equal(gait.span, [1.0, 0.25, 0.25, 1.0] * gait.half_width)
    # 0.05 m/s: 0.06 / 0.05 = 1.2 s, past the 0.9 s top; the stride 0.05 x 0.9 = 45 mm
    np.testing.assert_allclose(gait.scheduled(0.05), [0.025, 0.045, 0.9, 0.07], rtol=0,
                               atol=1e-15)  # fmt: skip
    np.testing.assert_array_equal(gait.scheduled(None), gait.scheduled(gait.speed))
    controller.reset(readings)
    for command in (0.0, -0.1):
        with pytest.raises(ValueError, match=rf"command a forward speed .*got {command}$"):
            controller.command = command
    assert controller.command is None  # refused, not kept
    controller.command = None  # (the export's own speed)
    controller.command = 0.2
    targets = controller.step(readings)
    assert targets.shape == (5, 12) and np.isfinite(targets).all()
