"""rwalk-play --viewer: the live viewer's loop on a stand-in for mujoco.viewer, its speed
keys, and its one-line refusal without a display."""

import itertools
import sys

import mujoco
import numpy as np
import pytest
import torch
from conftest import write_run

from rwalk.config import EnvConfig
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.runners import play
from rwalk.viewer import KEY_DOWN, KEY_UP, SpeedKeys, display_missing, watch

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="display variables are X11's")


class FakeViewer:
    """``mujoco.viewer.launch_passive``'s handle: open for ``frames`` syncs, pressing
    ``presses[k]`` at sync k; records env 0's torso position at every sync."""

    def __init__(self, frames: int, presses: dict[int, int]) -> None:
        self.frames, self.presses, self.synced, self.torso = frames, presses, 0, []

    def __call__(self, model, data, key_callback=None):
        self.model, self.data, self.keys = model, data, key_callback
        return self

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def is_running(self) -> bool:
        return self.synced < self.frames

    def sync(self) -> None:
        self.torso.append(self.data.qpos[:3].copy())
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
    assert display_missing() is None


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
