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

import json
from dataclasses import dataclass
from pathlib import Path

from rwalk.cli import command, one_line_errors, parse, usage_error
from rwalk.config import MAX_ENVS, MAX_STEPS
from rwalk.fidelity import (
    CANDIDATES,
    CONTROL_DT,
    WORLDS,
    measure_costs,
    plot,
    run_cases,
    table,
)
from rwalk.rl.checkpoints import atomic_write_text, check_outputs
from rwalk.validation import require_at_least, require_at_most, require_positive

PROG = command("rwalk.runners.fidelity")
#: Longest simulated time of a run, and longest timing turn. Seconds.
MAX_SECONDS = 86_400.0


def _names(text: str) -> tuple[str, ...]:
    """The comma-separated names of ``text`` (empty ones left out)."""
    return tuple(name for name in text.split(",") if name)


@dataclass(frozen=True)
class FidelityArgs:
    """rwalk-fidelity's command line (each field a flag)."""

    robots: int = 256
    """robots per run"""
    seconds: float = 20.0
    """simulated time"""
    only: str = ",".join(CANDIDATES)
    """comma-separated candidates (the reference always runs)"""
    worlds: str = ",".join(WORLDS)
    """comma-separated worlds"""
    checkpoint: Path | None = None
    """also run this policy's closed loop"""
    policy_only: bool = False
    """with --checkpoint: skip the base gait"""
    cost_envs: int = 256
    """envs in cost timing"""
    cost_rounds: int = 3
    """alternating rounds"""
    cost_window: float = 1.0
    """seconds a turn"""
    json: Path | None = None
    """save the results here"""
    plot: Path | None = None
    """save the cost-vs-fidelity PNG here"""

    def __post_init__(self) -> None:
        require_at_least(self, 1, "robots", "cost_envs", "cost_rounds")
        require_at_most(self, MAX_ENVS, "robots", "cost_envs")
        require_at_most(self, MAX_STEPS, "cost_rounds")
        require_positive(self, "seconds", "cost_window")
        require_at_most(self, MAX_SECONDS, "seconds", "cost_window")
        unknown = [name for name in _names(self.only) if name not in CANDIDATES]
        if unknown or not _names(self.only):
            raise ValueError(f"--only: unknown candidate(s) {unknown or self.only!r}; known: "
                             f"{', '.join(CANDIDATES)}")  # fmt: skip
        if not _names(self.worlds) or any(name not in WORLDS for name in _names(self.worlds)):
            raise ValueError(f"--worlds must be some of {', '.join(WORLDS)}, comma-separated, "
                             f"got {self.worlds!r}")  # fmt: skip

    @property
    def candidates(self) -> list[str]:
        """The candidates of --only, the reference first if --only leaves it out."""
        names = list(_names(self.only))
        return names if "reference" in names else ["reference", *names]

    @property
    def world_names(self) -> list[str]:
        """The worlds of --worlds."""
        return list(_names(self.worlds))


def parse_args(argv: list[str] | None = None) -> FidelityArgs:
    """``argv`` as rwalk-fidelity's arguments; exits 2 with one line naming a bad flag or
    file."""
    args = parse(FidelityArgs, argv, prog=PROG, description=__doc__)
    if args.checkpoint is not None and not args.checkpoint.is_file():
        usage_error(PROG, f"--checkpoint {str(args.checkpoint)!r} is not a file")
    if args.policy_only and args.checkpoint is None:
        usage_error(PROG, "--policy-only needs --checkpoint")
    check_outputs(PROG, {"--json": args.json, "--plot": args.plot})  # before any run
    return args


def fidelity(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    steps = max(1, round(args.seconds / CONTROL_DT))
    cases = run_cases(
        args.candidates, args.world_names, args.robots, steps, args.checkpoint,
        args.policy_only, log=lambda line: print(line, flush=True),
    )  # fmt: skip
    costs = measure_costs(args.candidates, args.cost_envs, args.cost_rounds, args.cost_window)
    results = {"robots": args.robots, "seconds": steps * CONTROL_DT, "cases": cases, "cost": costs}
    print(table(results))
    if args.json is not None:
        atomic_write_text(args.json, json.dumps(results, indent=1))
    if args.plot is not None:
        plot(results, args.plot)
    return results


@one_line_errors("rwalk.runners.fidelity")
def main(argv: list[str] | None = None) -> None:
    fidelity(argv)


if __name__ == "__main__":  # through the module by name, where tyro reads FidelityArgs's types
    from rwalk.runners.fidelity import main as fidelity_main

    fidelity_main()
