"""Learning curves of a training run from its TensorBoard events.

    python -m runners.plot_training logs/rwalk --out docs/learning_curve.png \
        --base-gait-json docs/eval.json

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
    parser.add_argument("log_dir", type=Path)
    parser.add_argument("--out", type=Path, default=Path("docs/learning_curve.png"))
    parser.add_argument("--base-gait-json", type=Path, help="play.py --json output")
    args = parser.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = read_scalars(args.log_dir)
    base = None
    if args.base_gait_json:
        rows = json.loads(args.base_gait_json.read_text())
        base = next((r for r in rows if r["name"] == "base gait"), None)
    start = min(v[0][1] for v in series.values() if v)
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    for ax, (tag, label, base_key) in zip(axes.flat, PANELS, strict=True):
        values = series.get(tag, [])
        if values:
            minutes = [(t - start) / 60 for _, t, _ in values]
            ax.plot(minutes, [v for _, _, v in values], lw=1)
        if base is not None and base_key is not None:
            ax.axhline(base[base_key], color="k", ls="--", lw=1, label="base gait (evaluated)")
            ax.legend(fontsize=8)
        ax.set(xlabel="wall-clock minutes", ylabel=label)
        ax.grid(alpha=0.3)
    fig.suptitle(f"Training on world_train at full roughness ({args.log_dir})")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
