"""Throughput and memory of the env beside its physics floor, measured in one run.

    rwalk-bench                      # the full sweep (about 35 minutes on 2 cores, plus (e))
    rwalk-bench --quick              # N in {16, 1024}, short windows
    rwalk-bench --json bench.json --plot docs/performance.png
    rwalk-bench --only b,1024,2 --only a,64,1 --seconds 4
    rwalk-bench --only b,1024,1      # robot-seconds per core-second of the env at N=1024

    pip install -e ".[bench]"        # EnvPool (optional extra), for mode e:
    rwalk-bench --only e,256,1 --seconds 8   # rwalk vs EnvPool's Go1, rough and flat

In a checkout, ``python -m runners.bench`` takes the same arguments. Without envpool,
mode e is skipped with a one-line message; the other modes run as usual.

The modes below are measured by ``rwalk.bench`` (``meters``, ``modes``, ``envpool``);
this command plans the runs, starts one worker process per run and reports.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from rwalk.bench import sharing
from rwalk.bench.envpool import envpool_missing
from rwalk.bench.modes import MODES_HELP, ONLY_MODES, WorkerFailed, run_worker, worker_runs
from rwalk.bench.report import LABELS, add_ratios_to_floor, plot, summary, table, worker_line
from rwalk.cli import command, one_line_errors, parse
from rwalk.config import MAX_ENVS, MAX_THREADS
from rwalk.rl.checkpoints import atomic_write_text, check_outputs

SIZES = (1, 16, 256, 1024, 4096, 8192)
QUICK_SIZES = (16, 1024)
GYM_SYNC_SIZES = (1, 16)
ENVPOOL_N = 256
#: Longest timing window. Seconds.
MAX_WINDOW = 3600.0


def parse_only(text: str) -> tuple[str, int, int]:
    """One --only: ``mode,N,threads`` -> (mode, N, threads).

    Raises:
        ValueError: naming the flag, what it takes and ``text``.
    """
    wanted = (
        f"'mode,N,threads' with mode in {', '.join(ONLY_MODES)}, N >= 1 and threads >= 1 "
        f"(>= 2 for t), e.g. b,1024,2"
    )
    parts = text.split(",")
    try:
        mode, n, threads = parts[0].strip(), int(parts[1]), int(parts[2])
    except (IndexError, ValueError):
        raise ValueError(f"--only must be {wanted}, got {text!r}") from None
    bad = n < 1 or n > MAX_ENVS or threads < (2 if mode == "t" else 1) or threads > MAX_THREADS
    if len(parts) != 3 or mode not in ONLY_MODES or bad:
        raise ValueError(f"--only must be {wanted}, got {text!r}")
    return mode, n, threads


@dataclass(frozen=True)
class BenchArgs:
    """rwalk-bench's command line (each field a flag)."""

    quick: bool = False
    """N in {16, 1024}, 2 s windows"""
    seconds: float | None = None
    """timing window per measurement (None: 2 with --quick, else 8)"""
    json: Path | None = None
    """save the results here"""
    plot: Path | None = None
    """save a throughput-vs-N PNG here"""
    only: Annotated[tuple[str, ...], tyro.conf.UseAppendAction] = ()
    """measure only 'mode,N,threads' (repeatable, e.g. b,1024,2; a comes with b)"""

    def __post_init__(self) -> None:
        seconds = self.seconds
        if seconds is not None and not (math.isfinite(seconds) and 0 < seconds <= MAX_WINDOW):
            raise ValueError(f"--seconds must be a number of seconds > 0 and at most "
                             f"{MAX_WINDOW:g}, got {seconds}")  # fmt: skip
        self.runs()  # each --only parses

    def runs(self) -> list[tuple[str, int, int]]:
        """The --only runs as (mode, N, threads)."""
        return [parse_only(text) for text in self.only]

    @property
    def window(self) -> float:
        """The timing window of each measurement. Seconds."""
        return self.seconds or (2.0 if self.quick else 8.0)


def plan(quick: bool) -> list[tuple[str, int, int]]:
    """The worker runs of the full sweep (or the --quick one) on this machine's cores."""
    cores = os.cpu_count() or 1
    sizes = QUICK_SIZES if quick else SIZES
    thread_counts = sorted({1, cores})
    runs = [(mode, n, t) for n in sizes for t in thread_counts for mode in "bc"]
    runs += [("g", QUICK_SIZES[-1], t) for t in thread_counts]  # the adaptive task at N=1024
    runs.append(("r", QUICK_SIZES[-1], cores))  # the robust training's world at N=1024
    runs += [("d", n, 1) for n in (GYM_SYNC_SIZES[-1:] if quick else GYM_SYNC_SIZES)]
    if cores > 1:
        runs.append(("d", cores, cores))  # AsyncVectorEnv: one worker process per core
        runs.append(("t", QUICK_SIZES[-1] if quick else 4096, cores))
    # EnvPool's Go1 holds 40-50 MB per env: N=256 at most (11-13 GB peak).
    runs += [("e", QUICK_SIZES[0] if quick else ENVPOOL_N, t) for t in thread_counts]
    return worker_runs(runs)


def parse_args(argv: list[str] | None = None) -> BenchArgs:
    """``argv`` as rwalk-bench's arguments; exits 2 with one line naming a bad flag."""
    prog = command("rwalk.runners.bench")
    args = parse(BenchArgs, argv, prog=prog, description=f"{__doc__}\n{MODES_HELP}")
    check_outputs(prog, {"--json": args.json, "--plot": args.plot})  # before the sweep
    return args


def bench(argv: list[str] | None = None) -> list[dict]:
    """Run the sweep of the command line ``argv``; returns the result rows (a failed
    or skipped measurement has none)."""
    return _sweep(parse_args(argv))[0]


def _sweep(args: BenchArgs) -> tuple[list[dict], int]:
    """Run, report and save the sweep of ``args``; (result rows, failed runs)."""
    window = args.window
    runs = worker_runs(args.runs()) if args.only else plan(args.quick)
    results, failed = [], 0
    started = time.perf_counter()
    for i, (mode, n, threads) in enumerate(runs, 1):
        print(
            f"[{i}/{len(runs)}] ({mode}) {LABELS[mode]}, N={n}, threads={threads} ...",
            end=" ",
            flush=True,
        )
        if mode == "e":  # worker_runs keeps a bare (e) only where envpool is missing
            print(f"skipped: {envpool_missing()}", flush=True)
            continue
        try:
            rows = [sharing.measure(n) | {"mode": "s", "n": n, "threads": threads}] if (
                mode == "s") else run_worker(mode, n, threads, window)  # fmt: skip
        except (WorkerFailed, RuntimeError) as error:
            print(f"failed:\n{error}")
            failed += 1
            continue
        results.extend(rows)
        print(f"{worker_line(rows)} ({time.perf_counter() - started:.0f} s elapsed)", flush=True)
    add_ratios_to_floor(results)
    print()
    print(table(results))
    print()
    for line in summary(results):
        print(line)
    if args.json:
        atomic_write_text(args.json, json.dumps(results, indent=2))
    if args.plot:
        plot(results, args.plot)
    return results, failed


@one_line_errors("rwalk.runners.bench")
def main(argv: list[str] | None = None) -> int:
    """Console script ``rwalk-bench``: exit status 1 if measurements failed and none
    succeeded (a skipped one, such as (e) without envpool, is no failure)."""
    results, failed = _sweep(parse_args(argv))
    return 1 if failed and not results else 0


if __name__ == "__main__":  # through the module by name, where tyro reads BenchArgs's types
    from rwalk.runners.bench import main as bench_main

    sys.exit(bench_main())
