"""What reading a checkpoint as data costs beside a bare ``torch.load``.

    python -m rwalk.bench.checkpoints logs/rwalk/model_299.pt [--rounds 200]

Times, in alternating rounds in one process, ``torch.load(weights_only=True)`` (all
that loading did before the archive and field checks) and ``load_checkpoint`` +
``check_rsl_rl`` (the archive inspected before unpickling, the fields checked after),
and prints the median of each and their ratio.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

from rwalk.rl.checkpoints import check_rsl_rl, load_checkpoint


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


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("checkpoint", type=Path, help="an rwalk-train checkpoint")
    parser.add_argument("--rounds", type=int, default=200, help="alternating rounds")
    args = parser.parse_args(argv)
    medians = measure(args.checkpoint, args.rounds)
    size = args.checkpoint.stat().st_size
    print(f"{args.checkpoint} ({size / 1e6:.2f} MB), median of {args.rounds} alternating rounds:")
    for name, seconds in medians.items():
        print(f"  {name:16} {seconds * 1e3:8.3f} ms")
    ratio = medians["load_checkpoint"] / medians["torch.load"]
    print(f"  checked / bare: {ratio:.3f}")
    return medians


if __name__ == "__main__":
    main()
