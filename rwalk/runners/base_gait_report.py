"""Figures and numbers of the fixed base gait for docs/base_gait.md.

    python -m runners.base_gait_report --out docs

Writes base_gait_foot.png (one foot's commanded vs actual path over two gait
cycles on flat ground) and base_gait_paths.png (64 robots' paths on flat and
rough ground), and prints the table of docs/base_gait.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from rwalk.base_gait import (
    TABLE_HEADER,
    WORLDS,
    foot_track,
    foot_tracking_error,
    paths,
    plot_foot_track,
    plot_paths,
    table_row,
)
from rwalk.cli import POSITIVE_INT, SECONDS, one_line_errors


@one_line_errors("rwalk.runners.base_gait_report")
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs"))
    parser.add_argument("--envs", type=POSITIVE_INT, default=64, help="robots walked at once")
    parser.add_argument("--seconds", type=SECONDS, default=20.0, help="simulated time")
    args = parser.parse_args(argv)

    args.out.mkdir(parents=True, exist_ok=True)
    track = foot_track()
    plot_foot_track(track, args.out / "base_gait_foot.png")
    error = foot_tracking_error(track)
    print(f"mean |actual - commanded| FL foot (x, y, z) mm: {np.round(error, 2)}")

    steps = round(args.seconds / 0.02)
    print(TABLE_HEADER)
    walked = {}
    for name, world in WORLDS.items():
        summary, walked[name] = paths(world, args.envs, steps)
        print(table_row(name, args.envs, summary))
    plot_paths(walked, args.seconds, args.out / "base_gait_paths.png")


if __name__ == "__main__":
    main()
