"""Mode (s): trainings that share a machine.

A default ``rwalk-train`` of N envs runs alone, then two of them start side by side;
each one's seconds per iteration (rsl-rl's collection plus learning time of every
iteration after the first ``SKIP``, median) are compared with the run alone's. The
runs share the cores (``--share-cores``: torch's threads follow what other processes
leave free, ``rwalk.threads.SharedCores``); the run alone is timed again on fixed threads
(the trainers' default), so that the sharing is seen beside what it costs one training
alone. Every run keeps libgomp's own wait policy
(``OMP_WAIT_POLICY`` is left unset).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

#: Iterations of each training, and those left out of the timing (building, warm-up).
ITERATIONS = 10
SKIP = 2


def _start(n: int, log_dir: Path, iterations: int, env: dict[str, str],
           flags: tuple[str, ...]) -> subprocess.Popen:  # fmt: skip
    command = [sys.executable, "-m", "rwalk.runners.train", "--num-envs", str(n),
               "--max-iterations", str(iterations), "--save-interval", str(iterations),
               "--no-export", "--log-dir", str(log_dir), *flags]  # fmt: skip
    return subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip


def _finish(process: subprocess.Popen) -> None:
    _, err = process.communicate()
    if process.returncode != 0:
        raise RuntimeError(f"a timed training failed: {err[-500:]}")


def seconds_per_iteration(log_dir: Path) -> float:
    """Median collection + learning seconds of the iterations after the first SKIP."""
    from rwalk.tensorboard_events import read_scalars

    scalars = read_scalars(log_dir)
    parts = [dict((step, value) for step, _, value in scalars[tag])
             for tag in ("Perf/collection_time", "Perf/learning_time")]  # fmt: skip
    steps = sorted(set(parts[0]) & set(parts[1]))[SKIP:]
    return statistics.median(parts[0][s] + parts[1][s] for s in steps)


def measure(n: int, iterations: int = ITERATIONS, flags: tuple[str, ...] = ()) -> dict:
    """(s) at N envs: seconds per iteration alone (with --share-cores, and on fixed threads
    as the trainers run by default), of each of two side by side with --share-cores, and
    each one's speed over the alone run's. ``flags``: more rwalk-train flags (the default
    training's: none)."""
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        shared = (*flags, "--share-cores")
        _finish(_start(n, root / "alone", iterations, env, shared))
        _finish(_start(n, root / "alone_fixed", iterations, env, flags))
        pair = [_start(n, root / f"side_{i}", iterations, env, shared) for i in range(2)]
        for process in pair:
            _finish(process)
        alone = seconds_per_iteration(root / "alone")
        fixed = seconds_per_iteration(root / "alone_fixed")
        side = [seconds_per_iteration(root / f"side_{i}") for i in range(2)]
    return {
        "num_envs": n,
        "iterations": iterations,
        "alone_s_per_iteration": alone,
        "alone_fixed_threads_s_per_iteration": fixed,
        "alone_over_fixed_threads": fixed / alone,
        "side_by_side_s_per_iteration": side,
        "side_by_side_speed": [alone / s for s in side],
    }
