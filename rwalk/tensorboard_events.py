"""Scalars of a run's TensorBoard event files (what rwalk-train logs), as plain lists."""

from __future__ import annotations

from pathlib import Path


def read_scalars(log_dir: Path) -> dict[str, list[tuple[int, float, float]]]:
    """Every scalar of every event file in ``log_dir``, sorted by step.

    Returns:
        tag -> [(step, wall_time, value)]; wall_time in seconds since the epoch.
    """
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    series: dict[str, list[tuple[int, float, float]]] = {}
    for events in sorted(Path(log_dir).glob("events.out.tfevents.*")):
        accumulator = EventAccumulator(str(events), size_guidance={"scalars": 0})
        accumulator.Reload()
        for tag in accumulator.Tags()["scalars"]:
            series.setdefault(tag, []).extend(
                (e.step, e.wall_time, e.value) for e in accumulator.Scalars(tag)
            )
    return {tag: sorted(values) for tag, values in series.items()}
