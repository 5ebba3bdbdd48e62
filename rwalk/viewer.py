"""Watch a policy (or the base gait) walk in real time in MuJoCo's own viewer.

``watch(env, policy)`` steps env 0 of a batched env at the control rate, shows
it in ``mujoco.viewer.launch_passive`` and starts a new episode when one ends.
For a policy that reads a speed command, Up and Down change the command by
``SPEED_STEP`` within the run's command range while it walks. The camera follows
the torso from ``FOLLOW_DISTANCE`` away (the robot is about 6 cm tall on a 10 m
map), and one line on stdout says what the keys do. The viewer needs a display
that GLFW can open a window on: ``display_missing`` says what is missing, or why
the window cannot open, before anything opens (MuJoCo's own error would end the
process and write ``MUJOCO_LOG.TXT`` into the current directory).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from typing import Any

import mujoco
import torch

from rwalk import episodes
from rwalk.constants import TORSO_BODY

#: GLFW's key codes, which ``launch_passive`` hands to its key callback.
KEY_UP, KEY_DOWN = 265, 264
SPEED_STEP = 0.025
"""m/s per key press."""
FOLLOW_DISTANCE = 0.5
"""m from the torso to the viewer's tracking camera."""
FOLLOW_ELEVATION, FOLLOW_AZIMUTH = -20.0, 135.0
"""degrees: the camera's pitch (down) and heading about the vertical, as --video's."""


def display_missing() -> str | None:
    """What the viewer lacks here, or why its window cannot open (None: it can)."""
    if sys.platform in ("darwin", "win32"):
        return None
    displays = [f"{name}={os.environ[name]}" for name in ("DISPLAY", "WAYLAND_DISPLAY")
                if os.environ.get(name)]  # fmt: skip
    if not displays:
        return (
            "--viewer needs a display, and neither DISPLAY nor WAYLAND_DISPLAY is set "
            "(run it on a desktop or over ssh -X; --video films an episode without one)"
        )
    why = window_error()
    if why is None:
        return None
    return (
        f"--viewer cannot open a window on {' '.join(displays)} ({why}); "
        "--video films an episode without one"
    )


def window_error() -> str | None:
    """Why GLFW, which the viewer draws with, cannot open a hidden OpenGL window here
    (None: it can). It ends in ``glfwTerminate``, which closes every GLFW window of this
    process: ask before opening any."""
    try:
        import glfw  # here, not at import: it loads the GLFW library
    except ImportError as error:
        return f"no GLFW: {error}"
    errors: list[str] = []
    previous = glfw.set_error_callback(lambda code, text: errors.append(text.decode()))
    try:
        if not glfw.init():
            return errors[-1] if errors else "GLFW failed to initialise"
        glfw.default_window_hints()
        glfw.window_hint(glfw.VISIBLE, glfw.FALSE)
        window = glfw.create_window(16, 16, "rwalk", None, None)
        if not window:
            return errors[-1] if errors else "GLFW failed to open a window"
        glfw.destroy_window(window)
        return None
    finally:
        glfw.terminate()
        glfw.set_error_callback(previous)


def follow_torso(camera: mujoco.MjvCamera, model: mujoco.MjModel) -> None:
    """Make ``camera`` track the torso of ``model``'s robot from ``FOLLOW_DISTANCE``."""
    camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    camera.trackbodyid = model.body(TORSO_BODY).id
    camera.distance = FOLLOW_DISTANCE
    camera.elevation, camera.azimuth = FOLLOW_ELEVATION, FOLLOW_AZIMUTH


def keys_help(speeds: tuple[float, float] | None) -> str:
    """The one line that says what the viewer's keys do."""
    speed = f"Up/Down: speed -/+{SPEED_STEP} m/s within {speeds}; " if speeds else ""
    return (
        f"viewer: the camera follows the robot; {speed}mouse: orbit and zoom; "
        "Esc: free camera; Tab: show the panels; close the window to stop"
    )


class SpeedKeys:
    """The key callback: Up/Down move ``speed`` within ``low_high`` (the viewer's thread
    calls it; the stepping loop reads ``speed``)."""

    def __init__(self, speed: float, low_high: tuple[float, float]) -> None:
        self.low, self.high = low_high
        self.speed = min(max(speed, self.low), self.high)

    def __call__(self, key: int) -> None:
        change = {KEY_UP: SPEED_STEP, KEY_DOWN: -SPEED_STEP}.get(key)
        if change is not None:
            self.speed = min(max(self.speed + change, self.low), self.high)
            print(f"command {self.speed:.3f} m/s", flush=True)


def watch(
    env,
    policy: Callable[[], torch.Tensor] | None = None,
    speeds: tuple[float, float] | None = None,
    seconds: float = float("inf"),
    launch: Callable[..., Any] | None = None,
    realtime: bool = True,
) -> int:
    """Show env 0 of ``env`` (a ``BatchedEnv``) walking until the window closes.

    Args:
        policy: as ``rwalk.evaluation.evaluate``'s (None: the base gait).
        speeds: the command range the keys move within (None: no speed keys).
        seconds: stop after this much robot time.
        launch: ``mujoco.viewer.launch_passive`` or a stand-in with its signature.
        realtime: sleep so that one control step takes ``control_dt`` of wall time.

    Returns:
        The control steps shown.

    Raises:
        OSError: (``launch`` None) no window can open here, saying why.
    """
    if launch is None:
        missing = display_missing()
        if missing:
            raise OSError(missing)
        from mujoco import viewer as mujoco_viewer  # here, not at import: it loads GLFW

        launch = mujoco_viewer.launch_passive
    core = env.core
    model, data = core.model, mujoco.MjData(core.model)
    core.reset()  # draws the episode's command, where the keys start
    remembers = policy is not None and hasattr(policy, "reset")  # a recurrent policy
    if remembers:
        policy.reset()
    target = core.task.target  # env 0's commanded speed, which its policy reads
    keys = SpeedKeys(float(target[0]), speeds) if speeds is not None else None
    limit = seconds / core.control_dt
    zeros = torch.zeros(core.num_envs, core.task.action_dim)
    steps = 0
    core.sim.batch.get_data(0, data)  # the first frame shows env 0 where it starts
    print(keys_help(speeds), flush=True)
    with (
        launch(model, data, key_callback=keys, show_left_ui=False, show_right_ui=False) as viewer,
        torch.inference_mode(),
    ):
        with viewer.lock():  # the viewer's thread draws with this camera
            follow_torso(viewer.cam, model)
        while viewer.is_running() and steps < limit:
            started = time.perf_counter()
            if keys is not None:  # also after a reset, which draws the run's own command
                target[0] = keys.speed
            _, end = episodes.step(core, zeros if policy is None else policy())
            if end is not None and remembers:
                dones = torch.zeros(core.num_envs, dtype=torch.bool)
                dones[end.ids] = True
                policy.reset(dones)  # a new episode starts without the old one's memory
            core.sim.batch.get_data(0, data)
            mujoco.mj_forward(model, data)
            viewer.sync()
            steps += 1
            if realtime:
                time.sleep(max(0.0, core.control_dt - (time.perf_counter() - started)))
    return steps
