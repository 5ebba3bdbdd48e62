"""Rendering is optional: its OpenGL backend is chosen only when a frame is asked for,
and a machine without one gets a clear message instead of MuJoCo's raw errors."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rwalk import EnvConfig, ResidualWalkEnv, render

ROOT = Path(__file__).resolve().parents[1]
QUICK = EnvConfig(settle_steps=2, max_episode_steps=10)
#: Pretends this machine has no OpenGL library at all, before rwalk is imported.
NO_GL_LIBRARIES = "import ctypes.util; ctypes.util.find_library = lambda name: None; "


def _clean_env() -> dict:
    """The environment of a fresh shell on a machine without a display."""
    names = ("MUJOCO_GL", "PYOPENGL_PLATFORM", "DISPLAY", "WAYLAND_DISPLAY")
    return {k: v for k, v in os.environ.items() if k not in names}


def _python(code: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code, *args], cwd=ROOT, capture_output=True, text=True,
        timeout=300, check=False, env=_clean_env(),
    )  # fmt: skip


def test_importing_the_runners_leaves_the_environment_alone():
    # the libraries they build on set variables of their own on import (torchrl
    # LAZY_LEGACY_OP, torch TORCHINDUCTOR_CACHE_DIR, gymnasium PYGAME_HIDE_SUPPORT_PROMPT):
    # imported first, so that what is compared is rwalk's own doing, whatever ran before
    done = _python(
        "import os, gymnasium, mujoco, rsl_rl, tensordict, torch, torchrl; "
        "before = dict(os.environ); import rwalk.runners.play, rwalk.runners.train; "
        "assert dict(os.environ) == before, set(os.environ.items()) ^ set(before.items())"
    )
    assert done.returncode == 0, done.stderr


def test_play_evaluates_on_a_machine_without_any_opengl_library(tmp_path):
    code = NO_GL_LIBRARIES + "import sys; from rwalk.runners.play import main; sys.exit(main())"
    video = tmp_path / "episode.mp4"
    done = _python(code, "--base-gait", "--episodes", "2", "--max-steps", "5",
                   "--settle-steps", "2", "--video", str(video))  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "| base gait | 2 |" in done.stdout
    assert "no video: no OpenGL backend for offscreen rendering: install one" in done.stderr
    assert "libosmesa6" in done.stderr
    assert not video.exists()


def test_render_without_a_backend_says_what_to_install():
    code = NO_GL_LIBRARIES + (
        "from rwalk import EnvConfig, ResidualWalkEnv\n"
        "env = ResidualWalkEnv(config=EnvConfig(settle_steps=2), render_mode='rgb_array')\n"
        "env.reset(seed=0)\n"
        "try:\n"
        "    env.render()\n"
        "except RuntimeError as error:\n"
        "    print('RuntimeError:', error)\n"
    )
    done = _python(code)
    assert done.returncode == 0, done.stderr
    assert "RuntimeError: no OpenGL backend for offscreen rendering" in done.stdout
    assert "apt-get install libosmesa6" in done.stdout


def test_disabled_rendering_is_a_clear_error(monkeypatch):
    monkeypatch.setattr(render, "_chosen", None)
    monkeypatch.setenv("MUJOCO_GL", "disable")
    with pytest.raises(RuntimeError, match=r"rendering is disabled \(MUJOCO_GL='disable'\)"):
        render.ensure_gl_backend()


def _gl_works() -> bool:
    code = (
        "import sys; from rwalk.render import gl_available; sys.exit(0 if gl_available()[0] else 1)"
    )
    return _python(code).returncode == 0


@pytest.mark.skipif(not _gl_works(), reason="no OpenGL backend (apt-get install libosmesa6)")
def test_render_picks_a_backend_by_itself_and_returns_a_frame():
    code = (
        "import os; from rwalk import EnvConfig, ResidualWalkEnv\n"
        "env = ResidualWalkEnv(config=EnvConfig(settle_steps=2), render_mode='rgb_array')\n"
        "env.reset(seed=0)\n"
        "frame = env.render()\n"
        "print(frame.shape, frame.dtype, frame.std() > 0, os.environ['MUJOCO_GL'])\n"
    )
    done = _python(code)
    assert done.returncode == 0, done.stderr
    shape, dtype, varied, backend = done.stdout.split(") ")[0] + ")", *done.stdout.split()[-3:]
    assert shape == "(360, 480, 3)" and dtype == "uint8" and varied == "True"
    assert backend in ("egl", "osmesa")


def test_render_without_render_mode_warns_and_returns_none():
    env = ResidualWalkEnv(config=QUICK)
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None
    assert np.isfinite(env.core.obs.numpy()).all()
