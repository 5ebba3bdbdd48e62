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
parameter it commands and of its swing peaks (how high each swing lifted the foot
above the ground under it), its falls, and whether its step height on rough and step tiles at
levels >= 5 is at least 1.5x that on flat ground. Writes adaptive.json (every
row) and adaptive_levels.png, and prints the tables. Either policy may be left
out: without --adaptive there is no gait by terrain (and no plot).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

from rwalk import presets
from rwalk.adaptive_evaluation import (
    ADAPTATION_FLOOR,
    GAIT_STEPS,
    MEASURED,
    GaitStats,
    adaptation,
    compare,
    gait_by_terrain,
    gait_table,
    plot_levels,
    table,
)
from rwalk.cli import command, one_line_errors, parse, usage_error
from rwalk.config import MAX_ENVS, MAX_SETTLE_STEPS, MAX_STEPS
from rwalk.evaluation import Evaluation, check_policy, read_results
from rwalk.rl.checkpoints import atomic_write_text, check_outputs
from rwalk.validation import require_at_least, require_at_most, require_in

#: Most steps of an episode here (10^5: 33 minutes of walking).
MAX_REPORT_STEPS = 100_000
#: The files the report writes into --out.
FILES = ("adaptive.json", "adaptive_levels.png")
PROG = command("rwalk.runners.adaptive_report")
"""The command in usage lines and error messages."""


@dataclass(frozen=True)
class AdaptiveReportArgs:
    """rwalk-adaptive-report's command line (each field a flag)."""

    residual: Path | None = None
    """residual checkpoint"""
    adaptive: Path | None = None
    """adaptive checkpoint"""
    episodes: int = 100
    """paired episodes per row"""
    seed: int = 1000
    """first episode's seed"""
    terrain_scale: float = 1.0
    """the nominal rough world"""
    max_steps: int = presets.EVALUATION.max_episode_steps
    """episode length of (a)-(c)"""
    settle_steps: int = presets.EVALUATION.settle_steps
    """settling before each episode"""
    gait_steps: int = GAIT_STEPS
    """steps of each gait episode"""
    out: Path = Path("docs")
    """output folder"""
    tables: Path | None = None
    """only print the tables of an adaptive.json"""

    def __post_init__(self) -> None:
        require_at_least(self, 1, "episodes", "max_steps", "gait_steps")
        require_at_least(self, 0, "seed", "settle_steps")
        require_at_most(self, MAX_ENVS, "episodes")
        require_at_most(self, MAX_STEPS, "seed")
        require_at_most(self, MAX_REPORT_STEPS, "gait_steps", "max_steps")
        require_at_most(self, MAX_SETTLE_STEPS, "settle_steps")
        require_in(self, "terrain_scale", 0.0, 1.0)


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
                               *(tuple(float(v) for v in row[k][:len(MEASURED)])
                                 for k in ("mean", "interval", "spread"))))  # fmt: skip
    return tables, stats


def parse_args(argv: list[str] | None = None) -> AdaptiveReportArgs:
    """``argv`` as rwalk-adaptive-report's arguments, every file checked before any row
    runs. Exits 2 with one line naming a bad flag or file."""
    args = parse(AdaptiveReportArgs, argv, prog=PROG, description=__doc__)
    if args.tables:
        return args
    if args.residual is None and args.adaptive is None:
        usage_error(PROG, "give --residual, --adaptive or both checkpoints (or --tables)")
    for name in _outputs(args):  # before any row runs
        check_outputs(PROG, {"--out": args.out / name})
    for flag, path, task in (("--residual", args.residual, "residual_walk"),
                             ("--adaptive", args.adaptive, "adaptive_gait")):  # fmt: skip
        if path is None:
            continue
        try:  # every file, before any row runs
            check_policy(path, task)
        except (OSError, ValueError) as error:
            usage_error(PROG, f"{flag}: {error}")
    return args


@one_line_errors("rwalk.runners.adaptive_report")
def main(argv: list[str] | None = None) -> None:
    """Console script ``rwalk-adaptive-report`` (returns None: its exit status is 0)."""
    args = parse_args(argv)
    if args.tables:
        try:
            tables, stats = _read(args.tables)
        except (OSError, ValueError, KeyError, TypeError) as error:
            usage_error(PROG, f"--tables: not an adaptive.json of this report ({error})")
        _print(tables, stats)
        return
    given = {"residual": args.residual, "adaptive": args.adaptive}
    policies = {"base gait": None, **{name: path for name, path in given.items() if path}}
    tables = compare(policies, args.episodes, args.seed, args.terrain_scale,
                     max_steps=args.max_steps, settle_steps=args.settle_steps)  # fmt: skip
    stats = []
    if args.adaptive is not None:
        stats = gait_by_terrain(args.adaptive, args.episodes, args.seed, args.gait_steps)
    _print(tables, stats)
    args.out.mkdir(parents=True, exist_ok=True)
    data = {k: [dataclasses.asdict(r) for r in rows] for k, rows in tables.items()}
    if stats:
        data["gait"] = [dataclasses.asdict(s) for s in stats]
        data["adaptation"] = adaptation(stats)
        plot_levels(stats, args.out / FILES[1])
    atomic_write_text(args.out / FILES[0], json.dumps(data, indent=2))


def _outputs(args: AdaptiveReportArgs) -> tuple[str, ...]:
    """The files the report writes into --out: the gait plot only with an adaptive policy."""
    return FILES if args.adaptive is not None else FILES[:1]


if __name__ == "__main__":  # through the module by name, where tyro reads the Args' types
    from rwalk.runners.adaptive_report import main as report_main

    report_main()
