"""Learning-curve figure of training runs (docs/learning_curve.png, ``rwalk-plot-training``).

Four panels per iteration, each the mean over the episodes that ended: forward
velocity, velocity-tracking error, fall rate and episode length, with runs
overlaid and the base gait's evaluated levels as dashed lines when given.
"""

from __future__ import annotations

from pathlib import Path

#: (TensorBoard tag, axis label, key of the base gait's evaluation drawn on it or None).
PANELS = (
    ("Episode/forward_velocity", "forward velocity (m/s)", "forward_velocity"),
    ("Episode/velocity_error", "|mean v_x - v*| per episode (m/s)", None),
    ("Episode/fall_rate", "share of ended episodes that fell", None),
    ("Train/mean_episode_length", "episode length (steps)", "mean_length"),
)

Series = dict[str, list[tuple[int, float, float]]]
"""A run's scalars: tag -> [(step, wall_time, value)] (``rwalk.tensorboard_events``)."""


def plot(
    runs: dict[str, Series],
    path: Path,
    base: dict | None = None,
    by_iteration: bool = False,
    title: str | None = None,
    paces: dict[str, float] | None = None,
) -> None:
    """Draw the panels of ``runs`` (name -> scalars) and save the PNG at ``path``.

    Args:
        base: the base gait's row of an evaluation JSON (``rwalk-play --json``), or None.
        by_iteration: x axis in PPO iterations; else wall-clock minutes since each
            run's first scalar.
        title: the figure's title; None = ``Training (<run names>)``.
        paces: seconds per iteration of each run (name -> s), measured alone: the x axis
            is then iteration x pace in minutes, for runs whose own clocks shared the cores.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    for ax, (tag, label, base_key) in zip(axes.flat, PANELS, strict=True):
        for name, series in runs.items():
            values = series.get(tag, [])
            if not values:
                continue
            if by_iteration:
                x = [step for step, _, _ in values]
            elif paces is not None:
                x = [step * paces[name] / 60 for step, _, _ in values]
            else:
                start = min(v[0][1] for v in series.values() if v)
                x = [(t - start) / 60 for _, t, _ in values]
            ax.plot(x, [v for _, _, v in values], lw=1, label=name if len(runs) > 1 else None)
        if base is not None and base_key is not None:
            ax.axhline(base[base_key], color="k", ls="--", lw=1, label="base gait (evaluated)")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
        xlabel = "PPO iteration" if by_iteration else "wall-clock minutes"
        if paces is not None and not by_iteration:
            xlabel = "minutes at the pace measured alone"
        ax.set(xlabel=xlabel, ylabel=label)
        ax.grid(alpha=0.3)
    fig.suptitle(title or f"Training ({', '.join(runs)})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
