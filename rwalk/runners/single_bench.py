"""How close one ``ResidualWalkEnv.step`` comes to its physics floor.

The measurement, and what its floor is, are ``rwalk.bench.single``'s.

Usage: ``python -m rwalk.runners.single_bench [--steps 200] [--rounds 7]``
"""

from __future__ import annotations

from dataclasses import dataclass

from rwalk.bench.single import CASES, SingleBench, measure
from rwalk.cli import command, one_line_errors, parse
from rwalk.config import MAX_STEPS
from rwalk.validation import require_at_least, require_at_most


@dataclass(frozen=True)
class SingleBenchArgs:
    """The single-env benchmark's command line (each field a flag)."""

    steps: int = 200
    """env steps per round"""
    rounds: int = 7
    """alternating rounds per case"""

    def __post_init__(self) -> None:
        require_at_least(self, 1, "steps", "rounds")
        require_at_most(self, MAX_STEPS, "steps", "rounds")


def parse_args(argv: list[str] | None = None) -> SingleBenchArgs:
    """``argv`` as the benchmark's arguments; exits 2 with one line naming a bad flag."""
    prog = command("rwalk.runners.single_bench")
    return parse(SingleBenchArgs, argv, prog=prog, description=__doc__)


@one_line_errors("rwalk.runners.single_bench")
def main(argv: list[str] | None = None) -> list[SingleBench]:
    args = parse_args(argv)
    results = []
    for label, timestep in CASES:
        result = measure(label, timestep, args.steps, args.rounds)
        results.append(result)
        print(
            f"{result.label}: step {result.step_us:.1f} µs, floor {result.floor_us:.1f} µs, "
            f"floor/step {result.ratio:.2f} ({result.steps} steps, best of {args.rounds} rounds)"
        )
    return results


if __name__ == "__main__":  # through the module by name, where tyro reads the Args' types
    from rwalk.runners.single_bench import main as bench_main

    bench_main()
