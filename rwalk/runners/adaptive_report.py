"""Figures of docs/adaptive.md: an adaptive and a residual policy against the base gait.

    python -m runners.adaptive_report --residual logs/residual/model_399.pt \\
        --adaptive logs/adaptive/model_399.pt --out docs

Every row runs the same --episodes paired episodes (episode i starts like a
single env seeded --seed + i): (a) on the training terrain (--train-scale), (b)
on rougher terrain (--rough-scale), (c) at each commanded speed on the training
terrain: the speed is each episode's target velocity, which the reward and the
velocity error track; only the adaptive policy (trained with commands) reads it,
the base gait and the residual policy walk as they do. Writes adaptive.json
(every row) and adaptive_gait.png (the adaptive policy's gait parameters over
one episode on smooth and rough ground), and prints the tables.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
import torch

from rwalk import ResidualWalkVecEnv, presets
from rwalk.cli import NATURAL_INT, POSITIVE_INT, UNIT_FLOAT
from rwalk.evaluation import Evaluation, evaluate, load_policy, saved_args
from rwalk.tasks.adaptive_gait import ADAPTED

SPEEDS = (0.05, 0.10, 0.15, 0.20, 0.25)


def make_env(task: str, episodes: int, seed: int, scale: float, command: float | None):
    cfg = presets.evaluation_config(
        task, scale, command_range=None if command is None else (command, command)
    )
    return ResidualWalkVecEnv(episodes, cfg, seed=seed, task=task)


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


def plot(traces: dict[str, np.ndarray], path: Path) -> None:
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


def table(rows: list[Evaluation]) -> str:
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


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add = parser.add_argument
    add("--residual", type=Path, help="residual checkpoint")
    add("--adaptive", type=Path, help="adaptive checkpoint")
    add("--episodes", type=POSITIVE_INT, default=100, help="paired episodes")
    add("--seed", type=NATURAL_INT, default=1000, help="first episode's seed")
    add("--train-scale", type=UNIT_FLOAT, default=0.6, help="training terrain")
    add("--rough-scale", type=UNIT_FLOAT, default=1.0, help="rougher terrain")
    add("--out", type=Path, default=Path("docs"), help="output folder")
    add("--tables", type=Path, help="only print the tables of an adaptive.json")
    args = parser.parse_args(argv)
    if args.tables:
        data = json.loads(args.tables.read_text())
        for label in ("a", "b", "c"):
            print(f"\n({label})\n{table([Evaluation(**row) for row in data[label]])}")
        return
    if args.residual is None or args.adaptive is None:
        parser.error("give --residual and --adaptive checkpoints (or --tables)")
    policies = {"base gait": None, "residual": args.residual, "adaptive": args.adaptive}
    out = {}
    for label, scale in (("a", args.train_scale), ("b", args.rough_scale)):
        out[label] = [run_row(n, c, args.episodes, args.seed, scale) for n, c in policies.items()]
    out["c"] = [
        run_row(n, c, args.episodes, args.seed, args.train_scale, speed)
        for speed in SPEEDS
        for n, c in policies.items()
    ]
    for label, rows in out.items():
        print(f"\n({label})\n{table(rows)}")
    args.out.mkdir(parents=True, exist_ok=True)
    from rwalk.rl.checkpoints import atomic_write_text

    data = {k: [dataclasses.asdict(r) for r in rows] for k, rows in out.items()}
    traces = {
        f"terrain {scale:g}": gait_trace(args.adaptive, args.seed, scale, 1000)
        for scale in (0.0, args.train_scale, args.rough_scale)
    }
    data["gait_means"] = {k: v.mean(axis=0).tolist() for k, v in traces.items()}
    print("\nmean gait parameters over the traced episode:", data["gait_means"])
    atomic_write_text(args.out / "adaptive.json", json.dumps(data, indent=2))
    plot(traces, args.out / "adaptive_gait.png")


if __name__ == "__main__":
    main()
