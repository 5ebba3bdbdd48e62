"""Walk the fixed base gait (zero residuals) and print how well it walks.

python -m runners.walk_demo --world model/world_flat.xml --envs 64 --seconds 20
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from rwalk.analysis import walk
from rwalk.base_gait import summary_lines
from rwalk.cli import command, one_line_errors, parse
from rwalk.config import MAX_ENVS, MAX_STEPS
from rwalk.core import ResidualWalkCore
from rwalk.presets import base_gait_config
from rwalk.runners.base_gait_report import MAX_SECONDS
from rwalk.validation import require_at_least, require_at_most, require_in, require_positive


@dataclass(frozen=True)
class WalkDemoArgs:
    """rwalk-walk-demo's command line (each field a flag)."""

    world: str = "model/world_flat.xml"
    """MJCF world"""
    envs: int = 64
    """robots walked at once"""
    seconds: float = 20.0
    """simulated time"""
    terrain_scale: float = 1.0
    """roughness 0..1"""
    seed: int = 0
    """episode seed"""

    def __post_init__(self) -> None:
        require_at_least(self, 1, "envs")
        require_at_least(self, 0, "seed")
        require_at_most(self, MAX_ENVS, "envs")
        require_at_most(self, MAX_STEPS, "seed")
        require_positive(self, "seconds")
        require_at_most(self, MAX_SECONDS, "seconds")
        require_in(self, "terrain_scale", 0.0, 1.0)


def parse_args(argv: list[str] | None = None) -> WalkDemoArgs:
    """``argv`` as rwalk-walk-demo's arguments; exits 2 with one line naming a bad flag."""
    prog = command("rwalk.runners.walk_demo")
    return parse(WalkDemoArgs, argv, prog=prog, description=__doc__)


def demo(argv: list[str] | None = None) -> dict[str, float]:
    """Run the command line ``argv``; returns the walk's summary
    (``rwalk.analysis.WalkReport.summary``)."""
    args = parse_args(argv)
    config = base_gait_config(args.world, terrain_scale=args.terrain_scale)
    core = ResidualWalkCore(config, args.envs, seed=args.seed)
    steps = max(1, round(args.seconds / core.control_dt))
    print(f"walking {args.envs} robots for {steps * core.control_dt:.1f} s on {args.world} ...")
    started = time.perf_counter()
    summary = walk(core, steps).summary()
    elapsed = time.perf_counter() - started
    for line in summary_lines(summary):
        print(line)
    print(f"  wall time            {elapsed:.1f} s")
    return summary


@one_line_errors("rwalk.runners.walk_demo")
def main(argv: list[str] | None = None) -> None:
    """Console script ``rwalk-walk-demo`` (returns None: its exit status is 0)."""
    demo(argv)


if __name__ == "__main__":  # through the module by name, where tyro reads the Args' types
    from rwalk.runners.walk_demo import main as demo_main

    demo_main()
