"""What reading a checkpoint as data costs beside a bare ``torch.load``.

    python -m rwalk.bench.checkpoints logs/rwalk/model_299.pt [--rounds 200]

Times, in alternating rounds in one process, ``torch.load(weights_only=True)`` (all
that loading did before the archive and field checks) and ``load_checkpoint`` +
``check_rsl_rl`` (the archive inspected before unpickling, the fields checked after),
and prints the median of each and their ratio.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import torch
import tyro

from rwalk.cli import command, one_line_errors, parse, usage_error
from rwalk.config import MAX_STEPS
from rwalk.rl.checkpoints import check_rsl_rl, load_checkpoint
from rwalk.validation import require_at_least, require_at_most


@dataclass(frozen=True)
class CheckpointBenchArgs:
    """The checkpoint-loading benchmark's command line (each field a flag)."""

    checkpoint: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="CHECKPOINT")]
    """an rwalk-train checkpoint"""
    rounds: int = 200
    """alternating rounds"""

    def __post_init__(self) -> None:
        require_at_least(self, 1, "rounds")
        require_at_most(self, MAX_STEPS, "rounds")


def measure(path: Path, rounds: int) -> dict[str, float]:
    """Median seconds of a bare ``torch.load`` and of the checked load of ``path``."""
    times: dict[str, list[float]] = {"torch.load": [], "load_checkpoint": []}
    loads = {
        "torch.load": lambda: torch.load(path, map_location="cpu", weights_only=True),
        "load_checkpoint": lambda: check_rsl_rl(load_checkpoint(path), path),
    }
    for _ in range(rounds):
        for name, load in loads.items():
            start = time.perf_counter()
            load()
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(values) for name, values in times.items()}


def parse_args(argv: list[str] | None = None) -> CheckpointBenchArgs:
    """``argv`` as the benchmark's arguments; exits 2 with one line naming a bad flag or
    a checkpoint that is not a file."""
    prog = command("rwalk.bench.checkpoints")
    args = parse(CheckpointBenchArgs, argv, prog=prog, description=__doc__)
    if not args.checkpoint.is_file():
        usage_error(prog, f"CHECKPOINT: {str(args.checkpoint)!r} is not a file")
    return args


def bench(argv: list[str] | None = None) -> dict[str, float]:
    """Run the command line ``argv``; returns the median seconds of each load."""
    args = parse_args(argv)
    medians = measure(args.checkpoint, args.rounds)
    size = args.checkpoint.stat().st_size
    print(f"{args.checkpoint} ({size / 1e6:.2f} MB), median of {args.rounds} alternating rounds:")
    for name, seconds in medians.items():
        print(f"  {name:16} {seconds * 1e3:8.3f} ms")
    ratio = medians["load_checkpoint"] / medians["torch.load"]
    print(f"  checked / bare: {ratio:.3f}")
    return medians


@one_line_errors("rwalk.bench.checkpoints")
def main(argv: list[str] | None = None) -> None:
    """``python -m rwalk.bench.checkpoints`` (returns None: its exit status is 0)."""
    bench(argv)


if __name__ == "__main__":  # through the module by name, where tyro reads the Args' types
    from rwalk.bench.checkpoints import main as checkpoints_main

    checkpoints_main()
