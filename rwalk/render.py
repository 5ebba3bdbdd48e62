"""Offscreen frames of a simulated robot (needs an OpenGL backend: MUJOCO_GL=egl or osmesa)."""

from __future__ import annotations

import mujoco
import numpy as np

from rwalk.constants import TORSO_BODY
from rwalk.sim import BatchedSim


class FrameRenderer:
    """Renders one row of a ``BatchedSim`` from a camera that follows the torso.

    Args:
        model: the simulated model (its heightfield is uploaded as it is now).
        width, height: frame size in pixels (at most the model's offscreen buffer).
    """

    def __init__(self, model: mujoco.MjModel, width: int = 480, height: int = 360) -> None:
        self.model = model
        self.renderer = mujoco.Renderer(model, height=height, width=width)
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


def gl_available() -> tuple[bool, str]:
    """Whether an offscreen OpenGL context can be made here, and why not if not."""
    try:
        probe = mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 8, 8)
        probe.close()
    except Exception as error:  # any backend failure means no rendering
        return False, f"{type(error).__name__}: {error}"
    return True, ""
