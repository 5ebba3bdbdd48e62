"""Watch a policy (or the base gait) walk in real time in MuJoCo's own viewer.

``watch(env, policy)`` steps env 0 of a batched env at the control rate, shows
it in ``mujoco.viewer.launch_passive`` and starts a new episode when one ends.
For a policy that reads a speed command, Up and Down change the command by
``SPEED_STEP`` within the run's command range while it walks. The viewer needs a
display: where none exists (no ``DISPLAY`` or ``WAYLAND_DISPLAY`` on Linux),
``display_missing`` names what is missing before anything opens.
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

#: GLFW's key codes, which ``launch_passive`` hands to its key callback.
KEY_UP, KEY_DOWN = 265, 264
SPEED_STEP = 0.025
"""m/s per key press."""


def display_missing() -> str | None:
    """What the viewer lacks here (None: a display is there to open a window on)."""
    if sys.platform in ("darwin", "win32"):
        return None
    if any(os.environ.get(name) for name in ("DISPLAY", "WAYLAND_DISPLAY")):
        return None
    return (
        "--viewer needs a display, and neither DISPLAY nor WAYLAND_DISPLAY is set "
        "(run it on a desktop or over ssh -X; --video films an episode without one)"
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
    """
    if launch is None:
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
    with launch(model, data, key_callback=keys) as viewer, torch.inference_mode():
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
