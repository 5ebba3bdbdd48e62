"""rwalk-play --viewer: the live viewer's loop on a stand-in for mujoco.viewer, its speed
keys, its camera on the torso, its one-line refusal without a display (or with one that
cannot open), and the real viewer under Xvfb where Xvfb is installed."""

import contextlib
import itertools
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from conftest import write_run

from rwalk import viewer as viewer_module
from rwalk.config import EnvConfig
from rwalk.constants import TORSO_BODY
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.runners import play
from rwalk.viewer import KEY_DOWN, KEY_UP, SpeedKeys, display_missing, watch

TRACKING = mujoco.mjtCamera.mjCAMERA_TRACKING

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="display variables are X11's")


class FakeViewer:
    """``mujoco.viewer.launch_passive``'s handle: open for ``frames`` syncs, pressing
    ``presses[k]`` at sync k; records env 0's torso position and the camera at every sync."""

    def __init__(self, frames: int, presses: dict[int, int]) -> None:
        self.frames, self.presses, self.synced, self.torso = frames, presses, 0, []
        self.cam, self.cameras = mujoco.MjvCamera(), []

    def __call__(self, model, data, key_callback=None, **ui):
        self.model, self.data, self.keys, self.ui = model, data, key_callback, ui
        return self

    def lock(self):
        return contextlib.nullcontext()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def is_running(self) -> bool:
        return self.synced < self.frames

    def sync(self) -> None:
        self.torso.append(self.data.qpos[:3].copy())
        cam = self.cam
        self.cameras.append((cam.type, cam.trackbodyid, cam.distance, cam.elevation))
        if self.synced in self.presses:
            self.keys(self.presses[self.synced])
        self.synced += 1


def small_env(**changes) -> BatchedEnv:
    config = EnvConfig(settle_steps=5, max_episode_steps=8, **changes)
    return BatchedEnv(1, config, seed=3)


def test_display_missing_names_both_variables(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    message = display_missing()
    assert "DISPLAY" in message and "WAYLAND_DISPLAY" in message
    monkeypatch.setenv("WAYLAND_DISPLAY", "wayland-0")
    monkeypatch.setattr(viewer_module, "window_error", lambda: None)
    assert display_missing() is None
    monkeypatch.setattr(viewer_module, "window_error", lambda: "X11: Failed to open display")
    message = display_missing()
    assert "cannot open a window on WAYLAND_DISPLAY=wayland-0 (X11: Failed" in message


def dead_display() -> str:
    """An X display name that no server answers on."""
    number = next(n for n in range(150, 1000) if not Path(f"/tmp/.X11-unix/X{n}").exists()
                  and not Path(f"/tmp/.X{n}-lock").exists())  # fmt: skip
    return f":{number}"


def display_env(display: str) -> dict:
    """This environment with ``display`` as its only display, and MuJoCo's default GL."""
    names = ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL", "PYOPENGL_PLATFORM")
    env = {k: v for k, v in os.environ.items() if k not in names}
    return {**env, "DISPLAY": display, "MUJOCO_GL": "glfw"}


def test_play_viewer_on_a_display_that_cannot_open_is_one_line_and_writes_nothing(tmp_path):
    display = dead_display()
    done = subprocess.run(
        [sys.executable, "-m", "rwalk.runners.play", "--base-gait", "--viewer"], cwd=tmp_path,
        env=display_env(display), capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 1, done.stderr
    err = done.stderr.strip().splitlines()
    assert len(err) == 1, err
    assert f"cannot open a window on DISPLAY={display}" in err[0]
    assert list(tmp_path.iterdir()) == []  # no MUJOCO_LOG.TXT


def test_play_viewer_without_display_is_one_line(monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(SystemExit) as exit_:
        play.main(["--base-gait", "--viewer"])
    assert exit_.value.code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs a display" in err[0] and "DISPLAY" in err[0]


def test_viewer_refuses_video_and_json(capsys):
    with pytest.raises(SystemExit):
        play.parse_args(["--base-gait", "--viewer", "--json", "x.json"])
    assert "--viewer" in capsys.readouterr().err


def test_speed_keys_step_and_clamp():
    keys = SpeedKeys(0.24, (0.05, 0.25))
    keys(KEY_UP)
    assert keys.speed == 0.25  # clamped at the top
    keys(KEY_DOWN)
    assert keys.speed == pytest.approx(0.225)
    keys(65)  # another key: nothing
    assert keys.speed == pytest.approx(0.225)
    assert SpeedKeys(0.0, (0.05, 0.25)).speed == 0.05


def test_watch_shows_env_zero_through_episode_ends():
    env = small_env()
    viewer = FakeViewer(frames=20, presses={})
    steps = watch(env, None, launch=viewer, realtime=False)
    assert steps == 20 and viewer.synced == 20  # 8-step episodes: two resets on the way
    assert isinstance(viewer.model, mujoco.MjModel)
    np.testing.assert_array_equal(viewer.data.qpos, env.core.sim.batch.qpos[0])
    first = viewer.torso[:8]  # the first episode: every frame shows the robot moved
    assert all(np.any(a != b) for a, b in itertools.pairwise(first))


def test_watch_tracks_the_torso_from_the_first_frame_and_hides_the_panels():
    env = small_env()
    viewer = FakeViewer(frames=3, presses={})
    watch(env, None, launch=viewer, realtime=False)
    torso = env.core.model.body(TORSO_BODY).id
    assert viewer.cameras[0] == (TRACKING, torso, viewer_module.FOLLOW_DISTANCE, -20.0)
    assert 0.3 <= viewer_module.FOLLOW_DISTANCE <= 0.8  # a 6 cm robot fills the view
    assert viewer.ui == {"show_left_ui": False, "show_right_ui": False}


def test_watch_says_what_the_keys_do_in_one_line(capsys):
    watch(small_env(), None, launch=FakeViewer(frames=1, presses={}), realtime=False)
    (line,) = capsys.readouterr().out.splitlines()
    assert "camera follows the robot" in line and "Up/Down" not in line
    speeds = (0.05, 0.25)
    watch(small_env(), None, speeds, launch=FakeViewer(frames=1, presses={}), realtime=False)
    (line,) = capsys.readouterr().out.splitlines()
    assert "Up/Down: speed -/+0.025 m/s within (0.05, 0.25)" in line and "Esc" in line


def test_watch_stops_after_seconds():
    env = small_env()
    viewer = FakeViewer(frames=1000, presses={})
    assert watch(env, None, seconds=5 * env.core.control_dt, launch=viewer, realtime=False) == 5


def test_keys_set_the_command_the_policy_reads_and_it_survives_resets():
    env = small_env(command_range=(0.1, 0.1))
    seen = []

    def policy():  # records env 0's command when it acts
        seen.append(float(env.core.task.target[0]))
        return torch.zeros(1, env.core.task.action_dim)

    viewer = FakeViewer(frames=20, presses={2: KEY_UP, 3: KEY_UP, 12: KEY_DOWN})
    watch(env, policy, speeds=(0.05, 0.25), launch=viewer, realtime=False)
    assert seen[:3] == [0.1] * 3
    assert seen[4:13] == [pytest.approx(0.15)] * 9  # through the reset after step 8
    assert seen[13:] == [pytest.approx(0.125)] * 7


def test_play_view_runs_a_commanded_policy(tmp_path, capsys):
    checkpoint = write_run(tmp_path, task="adaptive_gait", command_range=(0.05, 0.25))
    args = play.parse_args(["--checkpoint", str(checkpoint), "--viewer", "--settle-steps", "5"])
    viewer = FakeViewer(frames=3, presses={0: KEY_UP})
    assert play.view(args, launch=viewer) == 3
    out = capsys.readouterr().out
    assert "Up/Down" in out and "command 0.158 m/s" in out


def test_watch_refuses_a_display_that_cannot_open(monkeypatch):
    from mujoco import viewer

    def launch_passive(*args, **kwargs):  # the real one would end this process
        raise AssertionError("the viewer was launched")

    monkeypatch.setattr(viewer, "launch_passive", launch_passive)
    display = dead_display()
    monkeypatch.setenv("DISPLAY", display)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(OSError, match=f"cannot open a window on DISPLAY={display}"):
        watch(small_env(), None)


@pytest.fixture
def xvfb():
    """The display name of a fresh Xvfb server (skips where Xvfb is not installed)."""
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (apt-get install xvfb)")
    server = subprocess.Popen(
        ["Xvfb", "-displayfd", "1", "-screen", "0", "800x600x24", "-nolisten", "tcp"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    number = server.stdout.readline().strip()  # Xvfb writes it once it listens
    if not number:
        pytest.skip(f"Xvfb did not start (exit status {server.wait(10)})")
    yield f":{number}"
    server.terminate()
    server.wait(10)


#: Runs watch() in MuJoCo's real viewer; at the third frame it waits until the viewer's
#: thread has drawn the synced state (a tracking camera moves its lookat to the tracked
#: body's centre of mass as it draws), renders the viewer's camera offscreen as a
#: segmentation image, prints what it saw as JSON and ends the process at once (MuJoCo's
#: viewer can crash when it is closed and the process exits right after).
REAL_VIEWER = """
import json, os, time
import mujoco, numpy as np
from mujoco import viewer
from rwalk.config import EnvConfig
from rwalk.constants import TORSO_BODY
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.viewer import display_missing, watch

assert display_missing() is None, display_missing()
env = BatchedEnv(1, EnvConfig(settle_steps=5, max_episode_steps=50), seed=3)
model = env.core.model
torso = model.body(TORSO_BODY).id
renderer = mujoco.Renderer(model, 240, 320)  # its GLFW window before the viewer's thread
renderer.enable_segmentation_rendering()


def seen(handle, data):
    deadline = time.monotonic() + 10
    drawn = False
    while not drawn and time.monotonic() < deadline:
        time.sleep(0.02)
        drawn = np.allclose(handle.cam.lookat, data.subtree_com[torso], atol=1e-9)
    with handle.lock():
        cam = handle.cam
        camera = dict(type=int(cam.type), body=cam.trackbodyid, distance=cam.distance)
        renderer.update_scene(data, camera=cam)
    ids, kinds = renderer.render().transpose(2, 0, 1)
    geoms = np.where(kinds == mujoco.mjtObj.mjOBJ_GEOM, ids, -1)
    body = np.where(geoms >= 0, model.geom_bodyid[geoms], -1)
    robot = (body >= 0) & (model.body_rootid[body] == model.body_rootid[torso])
    rows, cols = np.nonzero(robot)
    centre = [rows.mean() / robot.shape[0], cols.mean() / robot.shape[1]] if robot.any() else []
    return dict(camera, drawn=drawn, robot=float(robot.mean()),
                torso=int((body == torso).sum()), centre=centre, torso_id=torso)


class Checked:
    def __init__(self, handle, data):
        self.handle, self.data, self.synced = handle, data, 0

    def __getattr__(self, name):
        return getattr(self.handle, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def sync(self):
        self.handle.sync()
        self.synced += 1
        if self.synced == 3:
            print(json.dumps(seen(self.handle, self.data)), flush=True)
            os._exit(0)


def launch(model, data, **kwargs):
    return Checked(viewer.launch_passive(model, data, **kwargs), data)


watch(env, None, launch=launch, realtime=False)
"""


def test_real_viewer_shows_the_robot_under_xvfb(xvfb, tmp_path):
    done = subprocess.run(
        [sys.executable, "-c", REAL_VIEWER], cwd=tmp_path, env=display_env(xvfb),
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert "camera follows the robot" in lines[0]
    seen = json.loads(lines[-1])
    assert seen["type"] == TRACKING and seen["body"] == seen["torso_id"], seen
    assert seen["drawn"], seen  # the viewer drew with its lookat on the torso
    assert 0.3 <= seen["distance"] <= 0.8, seen
    assert seen["robot"] > 0.02 and seen["torso"] > 0, seen  # the robot fills part of it
    assert seen["centre"] == pytest.approx([0.5, 0.5], abs=0.2), seen
    assert list(tmp_path.iterdir()) == []
