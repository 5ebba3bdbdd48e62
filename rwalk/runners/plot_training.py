"""Learning curves of a training run from its TensorBoard events.

    python -m runners.plot_training logs/rwalk --out docs/learning_curve.png \
        --base-gait-json docs/eval.json
    python -m runners.plot_training logs/a logs/b --by-iteration --out curves.png  # overlaid

Plots, per iteration, the mean over episodes that ended of forward velocity,
velocity-tracking error, fall rate and return per step (rsl-rl's
Train/mean_reward is per episode), with the base gait's evaluated levels as
dashed lines when given.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

PANELS = (
    ("Episode/forward_velocity", "forward velocity (m/s)", "forward_velocity"),
    ("Episode/velocity_error", "|mean v_x - v*| per episode (m/s)", None),
    ("Episode/fall_rate", "share of ended episodes that fell", None),
    ("Train/mean_episode_length", "episode length (steps)", "mean_length"),
)


def read_scalars(log_dir: Path) -> dict[str, list[tuple[int, float, float]]]:
    """Every scalar of every event file in log_dir: tag -> [(step, wall_time, value)]."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    series: dict[str, list[tuple[int, float, float]]] = {}
    for events in sorted(log_dir.glob("events.out.tfevents.*")):
        accumulator = EventAccumulator(str(events), size_guidance={"scalars": 0})
        accumulator.Reload()
        for tag in accumulator.Tags()["scalars"]:
            series.setdefault(tag, []).extend(
                (e.step, e.wall_time, e.value) for e in accumulator.Scalars(tag)
            )
    return {tag: sorted(values) for tag, values in series.items()}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("log_dir", type=Path, nargs="+", help="run folders (overlaid)")
    parser.add_argument(
        "--by-iteration", action="store_true", help="x axis: PPO iteration (default: minutes)"
    )
    parser.add_argument("--title", help="the figure's title")
    parser.add_argument("--out", type=Path, default=Path("docs/learning_curve.png"))
    parser.add_argument("--base-gait-json", type=Path, help="play.py --json output")
    args = parser.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = {str(log_dir): read_scalars(log_dir) for log_dir in args.log_dir}
    base = None
    if args.base_gait_json:
        rows = json.loads(args.base_gait_json.read_text())
        base = next((r for r in rows if r["name"] == "base gait"), None)
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    for ax, (tag, label, base_key) in zip(axes.flat, PANELS, strict=True):
        for name, series in runs.items():
            values = series.get(tag, [])
            if not values:
                continue
            if args.by_iteration:
                x = [step for step, _, _ in values]
            else:
                start = min(v[0][1] for v in series.values() if v)
                x = [(t - start) / 60 for _, t, _ in values]
            ax.plot(x, [v for _, _, v in values], lw=1, label=name if len(runs) > 1 else None)
        if base is not None and base_key is not None:
            ax.axhline(base[base_key], color="k", ls="--", lw=1, label="base gait (evaluated)")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
        ax.set(xlabel="PPO iteration" if args.by_iteration else "wall-clock minutes", ylabel=label)
        ax.grid(alpha=0.3)
    fig.suptitle(args.title or f"Training ({', '.join(runs)})")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
