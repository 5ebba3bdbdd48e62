"""Walk the fixed base gait (zero residuals) and print how well it walks.

python -m runners.walk_demo --world model/world_flat.xml --envs 64 --seconds 20
"""

from __future__ import annotations

import argparse
import time

from rwalk.analysis import walk
from rwalk.base_gait import summary_lines
from rwalk.cli import NATURAL_INT, POSITIVE_INT, SECONDS, UNIT_FLOAT, one_line_errors
from rwalk.core import ResidualWalkCore
from rwalk.presets import base_gait_config


@one_line_errors("rwalk.runners.walk_demo")
def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", default="model/world_flat.xml", help="MJCF world")
    parser.add_argument("--envs", type=POSITIVE_INT, default=64, help="robots walked at once")
    parser.add_argument("--seconds", type=SECONDS, default=20.0, help="simulated time")
    parser.add_argument("--terrain-scale", type=UNIT_FLOAT, default=1.0, help="roughness 0..1")
    parser.add_argument("--seed", type=NATURAL_INT, default=0, help="episode seed")
    args = parser.parse_args(argv)

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


if __name__ == "__main__":
    main()
