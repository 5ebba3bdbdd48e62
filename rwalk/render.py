"""Offscreen frames of a simulated robot.

Rendering is optional and its OpenGL backend is chosen only when a frame is
first asked for, never at import: ``import rwalk`` and everything but
rendering work on a machine without any OpenGL library. ``MUJOCO_GL`` set by
the user is obeyed as MuJoCo reads it; unset on a machine without a display,
the first offscreen backend whose library loads is taken (EGL, then OSMesa),
and with none a ``RuntimeError`` says what to install or set.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
from pathlib import Path

import mujoco
import numpy as np

from rwalk.constants import TORSO_BODY
from rwalk.sim import BatchedSim

#: Offscreen backends in order of preference, with the library each needs.
OFFSCREEN_BACKENDS: tuple[tuple[str, str], ...] = (("egl", "EGL"), ("osmesa", "OSMesa"))

NO_BACKEND_HELP = (
    "no OpenGL backend for offscreen rendering: install one (Debian/Ubuntu: apt-get install "
    "libosmesa6, then MUJOCO_GL=osmesa) or use a GPU driver's EGL (MUJOCO_GL=egl)"
)

_chosen: str | None = None


def _library_loads(name: str) -> bool:
    path = ctypes.util.find_library(name)
    if path is None:
        return False
    try:
        ctypes.CDLL(path)
    except OSError:
        return False
    return True


def ensure_gl_backend() -> str:
    """Choose MuJoCo's OpenGL backend for offscreen rendering, once per process.

    Returns:
        The backend: ``MUJOCO_GL`` when set, else "glfw" with a display, else
        the first of ``OFFSCREEN_BACKENDS`` whose library loads.

    Raises:
        RuntimeError: no backend is available, saying what to install or set.
    """
    global _chosen
    if _chosen is not None:
        return _chosen
    requested = os.environ.get("MUJOCO_GL", "").strip().lower()
    if requested in ("disable", "disabled", "off", "false", "0"):
        raise RuntimeError(f"rendering is disabled (MUJOCO_GL={requested!r}); {NO_BACKEND_HELP}")
    if requested or os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        _chosen = requested or "glfw"  # MuJoCo picked it at import
        return _chosen
    for backend, library in OFFSCREEN_BACKENDS:
        if not _library_loads(library):
            continue
        platform = os.environ.get("PYOPENGL_PLATFORM", backend)
        if platform != backend:
            continue  # PyOpenGL is bound to another platform in this process
        os.environ["PYOPENGL_PLATFORM"] = backend
        try:
            if backend == "egl":
                from mujoco.egl import GLContext
            else:
                from mujoco.osmesa import GLContext
        except Exception:  # the library loads but the backend does not initialise
            continue
        from mujoco.rendering.classic import gl_context

        gl_context.GLContext = GLContext  # what mujoco.Renderer instantiates
        os.environ["MUJOCO_GL"] = backend  # for child processes and later checks
        _chosen = backend
        return backend
    raise RuntimeError(NO_BACKEND_HELP)


class FrameRenderer:
    """Renders one row of a ``BatchedSim`` from a camera that follows the torso.

    Args:
        model: the simulated model (its heightfield is uploaded as it is now).
        width, height: frame size in pixels (at most the model's offscreen buffer).

    Raises:
        RuntimeError: no OpenGL backend (see ``ensure_gl_backend``).
    """

    def __init__(self, model: mujoco.MjModel, width: int = 480, height: int = 360) -> None:
        self.renderer = _make_renderer(model, height, width)
        self.model = model
        self.data = mujoco.MjData(model)
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
        self.camera.trackbodyid = model.body(TORSO_BODY).id
        self.camera.distance = 0.7
        self.camera.elevation = -25.0
        self.camera.azimuth = 135.0

    def frame(self, sim: BatchedSim, row: int) -> np.ndarray:
        """RGB image of simulation ``row``. Shape: (height, width, 3) uint8."""
        sim.batch.get_data(row, self.data)
        mujoco.mj_forward(self.model, self.data)
        self.renderer.update_scene(self.data, camera=self.camera)
        return self.renderer.render().copy()

    def close(self) -> None:
        self.renderer.close()


def _make_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    backend = ensure_gl_backend()
    try:
        return mujoco.Renderer(model, height=height, width=width)
    except Exception as error:  # MuJoCo's FatalError, PyOpenGL's AttributeError, ...
        raise RuntimeError(
            f"OpenGL backend {backend!r} failed to make a context "
            f"({type(error).__name__}: {error}); {NO_BACKEND_HELP}"
        ) from error


def gl_available() -> tuple[bool, str]:
    """Whether an offscreen OpenGL context can be made here, and why not if not."""
    try:
        _make_renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 8, 8).close()
    except RuntimeError as error:
        return False, str(error)
    return True, ""


class VideoRecorder:
    """Frames of env 0 of a batched env for its first ``seconds``, written as MP4 or GIF.

    Call it after each step (``rwalk.evaluation.evaluate``'s ``record``), then ``save``.
    """

    def __init__(self, env, path, seconds: float) -> None:
        self.path, self.env = Path(path), env
        self.renderer = FrameRenderer(env.core.model)
        self.frames: list[np.ndarray] = []
        self.limit = round(seconds / env.core.control_dt)

    def __call__(self, step: int) -> None:
        if step < self.limit:
            self.frames.append(self.renderer.frame(self.env.core.sim, 0))

    def save(self) -> None:
        import imageio.v3 as iio

        fps = round(1.0 / self.env.core.control_dt)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.suffix == ".gif":
            iio.imwrite(self.path, self.frames[::2], duration=2000 // fps, loop=0)
        else:
            iio.imwrite(self.path, self.frames, fps=fps, codec="libx264")
        self.renderer.close()
        print(f"wrote {self.path} ({len(self.frames)} frames)")
