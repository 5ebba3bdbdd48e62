"""Figures of docs/adaptive.md: an adaptive and a residual policy against the base gait,
and the adaptive policy's gait by kind of ground and level.

    rwalk-adaptive-report --residual logs/residual/model_399.pt \\
        --adaptive logs/adaptive/model_399.pt --out docs

Every row runs the same --episodes paired episodes (episode i starts like a
single env seeded --seed + i): (a) on flat ground, with each gait's servo power
and cost of transport, (b) on the nominal evaluation's rough world
(--terrain-scale), (c) at each commanded speed there: the speed is each
episode's target velocity, which the reward and the velocity error track; only a
policy trained with commands reads it, the base gait and a residual policy walk
as they do. Then the adaptive policy walks --episodes episodes of --gait-steps
steps on each kind of tile (flat, rough, slopes, steps, stones) of a held-out
terrain-levels map at each level: the mean, 95% interval and spread of each gait
parameter it commands, and whether its step height on rough and step tiles at
levels >= 5 is at least 1.5x that on flat ground. Writes adaptive.json (every
row) and adaptive_levels.png, and prints the tables.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from rwalk.adaptive_evaluation import (
    ADAPTATION_FLOOR,
    GaitStats,
    adaptation,
    compare,
    gait_by_terrain,
    gait_table,
    plot_levels,
    table,
)
from rwalk.cli import NATURAL_INT, POSITIVE_INT, UNIT_FLOAT, command, one_line_errors
from rwalk.config import MAX_SETTLE_STEPS
from rwalk.evaluation import Evaluation, check_policy, read_results
from rwalk.rl.checkpoints import atomic_write_text

#: Most steps of an episode here (10^5: 33 minutes of walking).
MAX_STEPS = 100_000


def _print(tables: dict[str, list[Evaluation]], stats: list[GaitStats]) -> None:
    for label, rows in tables.items():
        print(f"\n({label})\n{table(rows)}")
    if stats:
        print(f"\n(d) the adaptive policy's gait by terrain\n{gait_table(stats)}")
        a = adaptation(stats)
        print(
            f"\nstep height on rough and step tiles at levels >= 5: {a['hard'][0] * 1000:.2f} ± "
            f"{a['hard'][1] * 1000:.2f} mm; on flat ground: {a['flat'][0] * 1000:.2f} ± "
            f"{a['flat'][1] * 1000:.2f} mm; ratio {a['ratio']:.2f} (floor {ADAPTATION_FLOOR}, "
            f"intervals apart): {'met' if a['met'] else 'missed'}"
        )


def _read(path: Path) -> tuple[dict[str, list[Evaluation]], list[GaitStats]]:
    data = read_results(path)
    tables = {label: [Evaluation.from_json(row) for row in data[label]]
              for label in ("a", "b", "c")}  # fmt: skip
    stats = []
    for row in data.get("gait", []):
        if not isinstance(row, dict) or set(row) != {f.name for f in dataclasses.fields(GaitStats)}:
            raise ValueError("a gait row must hold the fields of GaitStats")
        stats.append(GaitStats(str(row["kind"])[:50], int(row["level"]), int(row["episodes"]),
                               float(row["fall_rate"]),
                               *(tuple(float(v) for v in row[k][:4])
                                 for k in ("mean", "interval", "spread"))))  # fmt: skip
    return tables, stats


@one_line_errors("rwalk.runners.adaptive_report")
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog=command("rwalk.runners.adaptive_report"), description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    add = parser.add_argument
    add("--residual", type=Path, help="residual checkpoint")
    add("--adaptive", type=Path, help="adaptive checkpoint")
    add("--episodes", type=POSITIVE_INT, default=100, help="paired episodes per row")
    add("--seed", type=NATURAL_INT, default=1000, help="first episode's seed")
    add("--terrain-scale", type=UNIT_FLOAT, default=1.0, help="the nominal rough world")
    add("--max-steps", type=POSITIVE_INT, default=1000, help="episode length of (a)-(c)")
    add("--settle-steps", type=NATURAL_INT, default=500, help="settling before each episode")
    add("--gait-steps", type=POSITIVE_INT, default=500, help="steps of each gait episode")
    add("--out", type=Path, default=Path("docs"), help="output folder")
    add("--tables", type=Path, help="only print the tables of an adaptive.json")
    args = parser.parse_args(argv)
    if args.tables:
        try:
            tables, stats = _read(args.tables)
        except (OSError, ValueError, KeyError, TypeError) as error:
            parser.error(f"--tables: not an adaptive.json of this report ({error})")
        _print(tables, stats)
        return
    if args.residual is None or args.adaptive is None:
        parser.error("give --residual and --adaptive checkpoints (or --tables)")
    for name in ("gait_steps", "max_steps"):
        if not getattr(args, name) <= MAX_STEPS:
            parser.error(f"--{name.replace('_', '-')} must be at most {MAX_STEPS}, got "
                         f"{getattr(args, name)}")  # fmt: skip
    if not args.settle_steps <= MAX_SETTLE_STEPS:
        parser.error(f"--settle-steps must be at most {MAX_SETTLE_STEPS}, got {args.settle_steps}")
    for flag, path, task in (("--residual", args.residual, "residual_walk"),
                             ("--adaptive", args.adaptive, "adaptive_gait")):  # fmt: skip
        try:  # every file, before any row runs
            check_policy(path, task)
        except (OSError, ValueError) as error:
            parser.error(f"{flag}: {error}")
    policies = {"base gait": None, "residual": args.residual, "adaptive": args.adaptive}
    tables = compare(policies, args.episodes, args.seed, args.terrain_scale,
                     max_steps=args.max_steps, settle_steps=args.settle_steps)  # fmt: skip
    stats = gait_by_terrain(args.adaptive, args.episodes, args.seed, args.gait_steps)
    _print(tables, stats)
    args.out.mkdir(parents=True, exist_ok=True)
    data = {k: [dataclasses.asdict(r) for r in rows] for k, rows in tables.items()}
    data["gait"] = [dataclasses.asdict(s) for s in stats]
    data["adaptation"] = adaptation(stats)
    atomic_write_text(args.out / "adaptive.json", json.dumps(data, indent=2))
    plot_levels(stats, args.out / "adaptive_levels.png")


if __name__ == "__main__":
    main()
