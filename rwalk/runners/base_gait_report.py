"""Figures and numbers of the fixed base gait for docs/base_gait.md.

    python -m runners.base_gait_report --out docs

Writes base_gait_foot.png (one foot's commanded vs actual path over two gait
cycles on flat ground) and base_gait_paths.png (64 robots' paths on flat and
rough ground), and prints the table of docs/base_gait.md.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import torch

from rwalk.analysis import walk
from rwalk.constants import OBS_FOOT_POS, OBS_POS
from rwalk.core import ResidualWalkCore
from rwalk.presets import base_gait_config

WORLDS = {"flat": "model/world_flat.xml", "rough": "model/world_train.xml"}


def foot_track(seconds_settle: float = 3.0, cycles: int = 2, leg: int = 0) -> dict[str, np.ndarray]:
    """Commanded and measured FL foot positions (torso frame) at every physics substep."""
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


def paths(world: str, envs: int, steps: int) -> tuple[dict[str, float], np.ndarray]:
    """Walk ``envs`` robots; return the summary and their (steps, envs, 2) xy paths."""
    core = ResidualWalkCore(base_gait_config(world), envs, seed=0)
    track: list[np.ndarray] = []

    def record(obs: torch.Tensor) -> torch.Tensor:
        track.append(obs[:, OBS_POS][:, :2].numpy().copy())
        return torch.zeros(envs, 12, dtype=torch.float64)

    summary = walk(core, steps, policy=record).summary()
    return summary, np.array(track)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs"))
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--seconds", type=float, default=20.0)
    args = parser.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    args.out.mkdir(parents=True, exist_ok=True)
    track = foot_track()
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
    fig.savefig(args.out / "base_gait_foot.png", dpi=110)
    error = np.abs(track["actual"] - track["commanded"]).mean(axis=0) * 1000
    print(f"mean |actual - commanded| FL foot (x, y, z) mm: {np.round(error, 2)}")

    steps = round(args.seconds / 0.02)
    fig, axes = plt.subplots(2, 1, figsize=(9, 7), height_ratios=(1, 2))
    print(
        "| world | robots | falls | speed (m/s) | speed / v* | mean abs heading change (rad) "
        "| mean abs sideways drift (m) | mean abs(v_x - v*) (m/s) |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for ax, (name, world) in zip(axes, WORLDS.items(), strict=True):
        summary, xy = paths(world, args.envs, steps)
        print(
            f"| {name} | {args.envs} | {summary['fall_rate']:.1%} | {summary['speed']:.4f} | "
            f"{summary['speed_ratio']:.2f} | {summary['abs_heading_change']:.4f} | "
            f"{summary['abs_sideways_drift']:.4f} | {summary['velocity_error']:.4f} |"
        )
        for i in range(xy.shape[1]):
            ax.plot(xy[:, i, 0], xy[:, i, 1], lw=0.7)
        ax.set(
            title=f"{name}: {args.envs} robots, {args.seconds:.0f} s",
            ylabel="y (m)",
            xlim=(-4.2, -0.8),
        )
        ax.set_aspect("equal")
    axes[-1].set_xlabel("x (m)")
    fig.tight_layout()
    fig.savefig(args.out / "base_gait_paths.png", dpi=110)


if __name__ == "__main__":
    main()
