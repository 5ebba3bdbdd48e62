"""Threads that share a machine: how many cores this process may use, and idle OpenMP
threads that sleep instead of spinning.

Torch's intra-op threads are OpenMP's; by default an idle one spins for a while before
it sleeps, which on a machine shared with another training (or an evaluation, or a
torchrun group) takes the cores the other one needs. The console scripts that train
call ``share_cores()`` before torch is imported. Imports nothing heavy.
"""

from __future__ import annotations

import os


def cores() -> int:
    """The cores this process may run on (its CPU affinity: ``taskset`` and cgroups
    limit it), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def share_cores() -> None:
    """Idle OpenMP threads sleep (``OMP_WAIT_POLICY=PASSIVE``) unless the environment says
    otherwise. Takes effect only before torch (and its OpenMP runtime) is imported."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
