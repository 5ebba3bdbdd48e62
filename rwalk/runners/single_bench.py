"""How close one ``ResidualWalkEnv.step`` comes to its physics floor.

The measurement, and what its floor is, are ``rwalk.bench.single``'s.

Usage: ``python -m rwalk.runners.single_bench [--steps 200] [--rounds 7]``
"""

from __future__ import annotations

import argparse

from rwalk.bench.single import CASES, SingleBench, measure
from rwalk.cli import POSITIVE_INT, one_line_errors


@one_line_errors("rwalk.runners.single_bench")
def main(argv: list[str] | None = None) -> list[SingleBench]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=POSITIVE_INT, default=200, help="env steps per round")
    parser.add_argument(
        "--rounds", type=POSITIVE_INT, default=7, help="alternating rounds per case"
    )
    args = parser.parse_args(argv)
    results = []
    for label, timestep in CASES:
        result = measure(label, timestep, args.steps, args.rounds)
        results.append(result)
        print(
            f"{result.label}: step {result.step_us:.1f} µs, floor {result.floor_us:.1f} µs, "
            f"floor/step {result.ratio:.2f} ({result.steps} steps, best of {args.rounds} rounds)"
        )
    return results


if __name__ == "__main__":
    main()
