"""Figures and numbers of the fixed base gait for docs/base_gait.md.

    python -m runners.base_gait_report --out docs

Writes base_gait_foot.png (one foot's commanded vs actual path over two gait
cycles on flat ground) and base_gait_paths.png (64 robots' paths on flat and
rough ground), and prints the table of docs/base_gait.md.
"""

from __future__ import annotations

from dataclasses import dataclass
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
from rwalk.cli import command, one_line_errors, parse
from rwalk.config import MAX_ENVS
from rwalk.validation import require_at_least, require_at_most, require_positive

#: Longest simulated time a report walks (a day). Seconds.
MAX_SECONDS = 86_400.0


@dataclass(frozen=True)
class BaseGaitReportArgs:
    """rwalk-base-gait-report's command line (each field a flag)."""

    out: Path = Path("docs")
    """folder of the figures"""
    envs: int = 64
    """robots walked at once"""
    seconds: float = 20.0
    """simulated time"""

    def __post_init__(self) -> None:
        require_at_least(self, 1, "envs")
        require_at_most(self, MAX_ENVS, "envs")
        require_positive(self, "seconds")
        require_at_most(self, MAX_SECONDS, "seconds")


def parse_args(argv: list[str] | None = None) -> BaseGaitReportArgs:
    """``argv`` as rwalk-base-gait-report's arguments; exits 2 with one line naming a bad
    flag."""
    prog = command("rwalk.runners.base_gait_report")
    return parse(BaseGaitReportArgs, argv, prog=prog, description=__doc__)


@one_line_errors("rwalk.runners.base_gait_report")
def main(argv: list[str] | None = None) -> None:
    """Console script ``rwalk-base-gait-report``."""
    args = parse_args(argv)
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


if __name__ == "__main__":  # through the module by name, where tyro reads the Args' types
    from rwalk.runners.base_gait_report import main as report_main

    report_main()
