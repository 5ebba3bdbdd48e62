"""Physics fidelity: candidate physics settings against a fine reference simulation.

    rwalk-fidelity --json docs/physics.json --plot docs/physics.png        # the full table
    rwalk-fidelity --checkpoint logs/rwalk/model_149.pt --json policy.json  # + a policy
    rwalk-fidelity --robots 32 --seconds 2 --only reference,4ms            # a quick look

Every candidate keeps the 50 Hz control rate (decimation = 20 ms / timestep) and
differs from the reference only in the settings that cost time: timestep, solver
iterations, friction cone, foot contact dimensionality and softness. For each one,
``--robots`` robots walk ``--seconds`` on flat and on rough ground (the base
gait from standing, as in ``docs/base_gait.md``; with ``--checkpoint`` also the
policy's closed loop after 2 s of settling), and the figures of
``rwalk.analysis.WalkReport`` are compared with the reference's.

Faithful: every metric's difference from the reference lies within the
reference's own seed-to-seed noise, 1.96·√2 standard errors of its mean over the
robots (the 95% band of the difference between two reference runs with
independent starts; a second reference run with other seeds shows it), never
narrower than the precision the docs quote (``RESOLUTION``: on flat ground all
robots walk one limit cycle and the seed noise is ~0). The cost
is simulated robot-seconds per core-second at ``--cost-envs`` envs on one thread
on the rough world, every candidate timed in alternating rounds in one process.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rwalk.cli import POSITIVE_FLOAT, POSITIVE_INT, SECONDS, command, one_line_errors
from rwalk.fidelity import (
    CANDIDATES,
    CONTROL_DT,
    WORLDS,
    measure_costs,
    plot,
    run_cases,
    table,
)

PROG = command("rwalk.runners.fidelity")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--robots", type=POSITIVE_INT, default=256, help="robots per run")
    parser.add_argument("--seconds", type=SECONDS, default=20.0, help="simulated time")
    parser.add_argument(
        "--only", type=_names, default=list(CANDIDATES), help="comma-separated candidates"
    )
    parser.add_argument("--worlds", type=_worlds, default=list(WORLDS), help="flat,rough")
    parser.add_argument("--checkpoint", type=Path, help="also run this policy's closed loop")
    parser.add_argument(
        "--policy-only", action="store_true", help="with --checkpoint: skip the base gait"
    )
    parser.add_argument("--cost-envs", type=POSITIVE_INT, default=256, help="envs in cost timing")
    parser.add_argument("--cost-rounds", type=POSITIVE_INT, default=3, help="alternating rounds")
    parser.add_argument("--cost-window", type=POSITIVE_FLOAT, default=1.0, help="seconds a turn")
    parser.add_argument("--json", type=Path, help="save the results here")
    parser.add_argument("--plot", type=Path, help="save the cost-vs-fidelity PNG here")
    args = parser.parse_args(argv)
    if "reference" not in args.only:
        args.only = ["reference", *args.only]
    if args.checkpoint is not None and not args.checkpoint.is_file():
        parser.error(f"--checkpoint {str(args.checkpoint)!r} is not a file")
    if args.policy_only and args.checkpoint is None:
        parser.error("--policy-only needs --checkpoint")
    return args


def _names(text: str) -> list[str]:
    names = [name for name in text.split(",") if name]
    unknown = [name for name in names if name not in CANDIDATES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"unknown candidate(s) {unknown or text!r}; known: {', '.join(CANDIDATES)}"
        )
    return names


def _worlds(text: str) -> list[str]:
    names = [name for name in text.split(",") if name]
    if not names or any(name not in WORLDS for name in names):
        raise argparse.ArgumentTypeError(f"worlds are {', '.join(WORLDS)}, got {text!r}")
    return names


def fidelity(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    steps = max(1, round(args.seconds / CONTROL_DT))
    cases = run_cases(
        args.only, args.worlds, args.robots, steps, args.checkpoint, args.policy_only,
        log=lambda line: print(line, flush=True),
    )  # fmt: skip
    costs = measure_costs(args.only, args.cost_envs, args.cost_rounds, args.cost_window)
    results = {"robots": args.robots, "seconds": steps * CONTROL_DT, "cases": cases, "cost": costs}
    print(table(results))
    if args.json is not None:
        from rwalk.rl.checkpoints import atomic_write_text

        atomic_write_text(args.json, json.dumps(results, indent=1))
    if args.plot is not None:
        plot(results, args.plot)
    return results


@one_line_errors("rwalk.runners.fidelity")
def main(argv: list[str] | None = None) -> None:
    fidelity(argv)


if __name__ == "__main__":
    main()
