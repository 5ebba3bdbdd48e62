"""Figures and numbers of the fixed base gait (zero residuals), for docs/base_gait.md.

``foot_track`` follows one foot's commanded and measured path at every physics
substep; ``paths`` walks many robots and keeps their xy paths; ``table_row`` and
``summary_lines`` write a walk's summary (``rwalk.analysis.WalkReport.summary``)
as the docs' table row and the demo's lines. ``rwalk-base-gait-report`` and
``rwalk-walk-demo`` are the command lines.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from rwalk.analysis import walk
from rwalk.constants import OBS_FOOT_POS, OBS_POS
from rwalk.core import ResidualWalkCore
from rwalk.presets import BASE_GAIT_WORLDS, base_gait_config

#: The worlds of the report, by name.
WORLDS = BASE_GAIT_WORLDS

#: The head of the docs' table (``table_row`` writes its rows).
TABLE_HEADER = (
    "| world | robots | falls | speed (m/s) | speed / v* | mean abs heading change (rad) "
    "| mean abs sideways drift (m) | mean abs(v_x - v*) (m/s) |\n"
    "| --- | --- | --- | --- | --- | --- | --- | --- |"
)


def foot_track(seconds_settle: float = 3.0, cycles: int = 2, leg: int = 0) -> dict[str, np.ndarray]:
    """Commanded and measured positions of one foot (torso frame) at every physics substep,
    one robot on flat ground after ``seconds_settle`` of walking.

    Returns:
        "t": substep times, shape (T,), seconds; "commanded", "actual": shape (T, 3),
        metres; "swing": whether the foot's gait phase is swing, shape (T,).
    """
    config = dataclasses.replace(
        base_gait_config(WORLDS["flat"]), decimation=1, control_dt=None, randomize=False
    )
    core = ResidualWalkCore(config, 1, seed=0)
    core.reset()
    settle = round(seconds_settle / core.dt)
    for _ in range(settle):
        core.step(torch.zeros(1, 12))
    n = round(cycles * config.gait.cycle_time / core.dt)
    hips = core.geometry.hip_tensor()
    commanded, actual, times, swing = [], [], [], []
    for k in range(n):
        # Sensors come from the start of the substep: compare with that substep's target.
        tick = int(core.tick[0])
        commanded.append((core.controller.target_table[tick, leg] + hips[leg]).numpy())
        swing.append(bool(core.controller.swing_table[tick, leg]))
        core.step(torch.zeros(1, 12))
        actual.append(core.obs[0, OBS_FOOT_POS].view(4, 3)[leg].numpy().copy())
        times.append(k * core.dt)
    return {
        "t": np.array(times),
        "commanded": np.array(commanded),
        "actual": np.array(actual),
        "swing": np.array(swing),
    }


def foot_tracking_error(track: dict[str, np.ndarray]) -> np.ndarray:
    """Mean |actual - commanded| of a ``foot_track`` per axis. Shape: (3,), millimetres."""
    return np.abs(track["actual"] - track["commanded"]).mean(axis=0) * 1000


def paths(world: str, envs: int, steps: int) -> tuple[dict[str, float], np.ndarray]:
    """Walk ``envs`` robots ``steps`` env steps on ``world`` (an MJCF path).

    Returns:
        The walk's summary and the robots' xy paths, shape (steps, envs, 2), metres.
    """
    core = ResidualWalkCore(base_gait_config(world), envs, seed=0)
    track: list[np.ndarray] = []

    def record(obs: torch.Tensor) -> torch.Tensor:
        track.append(obs[:, OBS_POS][:, :2].numpy().copy())
        return torch.zeros(envs, 12, dtype=torch.float64)

    summary = walk(core, steps, policy=record).summary()
    return summary, np.array(track)


def table_row(world: str, robots: int, summary: dict[str, float]) -> str:
    """One row of the docs' table (``TABLE_HEADER``) from a walk's summary."""
    return (
        f"| {world} | {robots} | {summary['fall_rate']:.1%} | {summary['speed']:.4f} | "
        f"{summary['speed_ratio']:.2f} | {summary['abs_heading_change']:.4f} | "
        f"{summary['abs_sideways_drift']:.4f} | {summary['velocity_error']:.4f} |"
    )


def summary_lines(summary: dict[str, float]) -> list[str]:
    """The walk demo's lines: falls, speed against v*, tracking error, heading, drift."""
    return [
        f"  fall rate            {summary['fall_rate']:.1%}",
        f"  forward speed        {summary['speed']:.4f} m/s  "
        f"(expected {summary['expected_velocity']:.4f}, ratio {summary['speed_ratio']:.2f})",
        f"  |v_x - v*| per step  {summary['velocity_error']:.4f} m/s",
        f"  |heading change|     {summary['abs_heading_change']:.4f} rad (mean)",
        f"  |sideways drift|     {summary['abs_sideways_drift']:.4f} m (mean)",
    ]


def plot_foot_track(track: dict[str, np.ndarray], path: Path) -> None:
    """The FL foot's path (x-z) and its x and z over time, commanded vs actual, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for label, key, style in (("commanded", "commanded", "--"), ("actual", "actual", "-")):
        axes[0].plot(track[key][:, 0] * 1000, track[key][:, 2] * 1000, style, label=label)
        axes[1].plot(track["t"], track[key][:, 0] * 1000, style, label=f"x {label}")
        axes[1].plot(track["t"], track[key][:, 2] * 1000, style, label=f"z {label}")
    axes[0].set(
        xlabel="x in torso frame (mm)", ylabel="z in torso frame (mm)", title="FL foot path"
    )
    axes[0].axis("equal")
    axes[0].legend()
    swing = track["swing"]
    axes[1].fill_between(track["t"], -80, 90, where=swing, color="0.9", label="swing")
    axes[1].set(xlabel="time (s)", ylabel="mm", title="FL foot over two gait cycles")
    axes[1].legend(fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_paths(paths_by_world: dict[str, np.ndarray], seconds: float, path: Path) -> None:
    """Every robot's xy path, one panel per world (``paths``' (steps, envs, 2)), as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(9, 7), height_ratios=(1, 2))
    for ax, (name, xy) in zip(axes, paths_by_world.items(), strict=True):
        for i in range(xy.shape[1]):
            ax.plot(xy[:, i, 0], xy[:, i, 1], lw=0.7)
        ax.set(
            title=f"{name}: {xy.shape[1]} robots, {seconds:.0f} s",
            ylabel="y (m)",
            xlim=(-4.2, -0.8),
        )
        ax.set_aspect("equal")
    axes[-1].set_xlabel("x (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
