"""An adaptive and a residual policy against the base gait (docs/adaptive.md).

Every row runs the same paired episodes (episode i starts like a single env
seeded seed + i): ``compare`` runs (a) the training terrain, (b) rougher
terrain and (c) each of ``SPEEDS`` commanded on the training terrain. The speed
is each episode's target velocity, which the reward and the velocity error
track; only a policy trained with commands reads it, the base gait and the
residual policy walk as they do. ``gait_traces`` follows the adaptive policy's
gait parameters over one episode per terrain. ``rwalk-adaptive-report`` is the
command line.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from rwalk import presets
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.evaluation import Evaluation, evaluate, load_policy, saved_args
from rwalk.tasks.adaptive_gait import ADAPTED

#: Commanded speeds of the rows (c). m/s.
SPEEDS = (0.05, 0.10, 0.15, 0.20, 0.25)


def make_env(
    task: str, episodes: int, seed: int, scale: float, command: float | None
) -> BatchedEnv:
    """``episodes`` envs of ``task`` on terrain ``scale``, asked for ``command`` m/s
    (None: no command)."""
    cfg = presets.evaluation_config(
        task, scale, command_range=None if command is None else (command, command)
    )
    return BatchedEnv(episodes, cfg, seed=seed, task=task)


def run_row(name, checkpoint, episodes, seed, scale, command=None) -> Evaluation:
    """One row: the base gait (checkpoint None) or a policy, on ``episodes`` paired episodes."""
    saved = {} if checkpoint is None else saved_args(checkpoint)
    task = saved.get("task", "residual_walk")
    if saved.get("command_range") and command is None:
        command = presets.EnvConfig().expected_velocity  # it reads a command: the gait's speed
    env = make_env(task, episodes, seed, scale, command)
    policy = None if checkpoint is None else load_policy(checkpoint, env)
    row = evaluate(name, env, seed, policy)
    asked = "-" if command is None else f"{command:.3f}"
    return dataclasses.replace(row, name=f"{name} | {scale:g} | {asked}")


def compare(
    policies: dict[str, Path | None],
    episodes: int,
    seed: int,
    train_scale: float,
    rough_scale: float,
) -> dict[str, list[Evaluation]]:
    """Rows (a) on ``train_scale``, (b) on ``rough_scale`` and (c) at each of ``SPEEDS`` on
    ``train_scale``, each a row per policy (name -> checkpoint; None = the base gait)."""
    out = {}
    for label, scale in (("a", train_scale), ("b", rough_scale)):
        out[label] = [run_row(n, c, episodes, seed, scale) for n, c in policies.items()]
    out["c"] = [
        run_row(n, c, episodes, seed, train_scale, speed)
        for speed in SPEEDS
        for n, c in policies.items()
    ]
    return out


def gait_trace(checkpoint: Path, seed: int, scale: float, steps: int) -> np.ndarray:
    """The adaptive policy's four parameters at every step of one episode. (steps, 4)."""
    env = make_env("adaptive_gait", 1, seed, scale, None)
    if saved_args(checkpoint).get("command_range"):
        speed = presets.EnvConfig().expected_velocity
        env = make_env("adaptive_gait", 1, seed, scale, speed)
    policy = load_policy(checkpoint, env)
    env.set_seed(seed)
    env.core.reset()
    rows = []
    with torch.inference_mode():
        for _ in range(steps):
            result = env.core.step(policy())
            rows.append(env.core.task.params[0].tolist())
            if bool(result.terminated[0] | result.truncated[0]):
                break
    return np.array(rows)


def gait_traces(
    checkpoint: Path, seed: int, scales: tuple[float, ...], steps: int = 1000
) -> dict[str, np.ndarray]:
    """``gait_trace`` on each terrain scale: "terrain <scale>" -> (steps, 4)."""
    return {f"terrain {scale:g}": gait_trace(checkpoint, seed, scale, steps) for scale in scales}


def plot(traces: dict[str, np.ndarray], path: Path) -> None:
    """Each of ``traces``' (steps, 4) parameters over the episode, one panel each, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    units = {"step_height": 1000, "step_length": 1000, "cycle_time": 1, "body_height": 1000}
    labels = {"step_height": "mm", "step_length": "mm", "cycle_time": "s", "body_height": "mm"}
    fig, axes = plt.subplots(4, 1, figsize=(7, 8), sharex=True)
    for ax, (i, name) in zip(axes, enumerate(ADAPTED), strict=True):
        for terrain, trace in traces.items():
            t = np.arange(len(trace)) * 0.02
            ax.plot(t, trace[:, i] * units[name], label=terrain)
        ax.set_ylabel(f"{name} ({labels[name]})")
        ax.grid(alpha=0.3)
    axes[0].legend()
    axes[-1].set_xlabel("time in episode (s)")
    fig.suptitle("Adaptive policy: gait parameters over one episode (same start)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def table(rows: list[Evaluation]) -> str:
    """The rows as a Markdown table (each row's name holds its policy, terrain and command)."""
    lines = [
        "| policy | terrain | commanded (m/s) | fall rate | forward velocity (m/s) "
        "| velocity error (m/s) | mean return |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        lines.append(
            f"| {r.name} | {r.fall_rate:.0%} | {r.forward_velocity:.3f} | "
            f"{r.velocity_error:.4f} ± {r.velocity_error_se * 1.96:.4f} | {r.mean_return:,.0f} |"
        )
    return "\n".join(lines)
