"""Threads that share a machine: how many cores this process may use, and torch's
threads following what other processes leave free.

Torch's intra-op threads are OpenMP's (libgomp); an idle one spins for a while before it
sleeps. Alone, that spinning is what makes a training fast; beside another training on
the same cores the spinning threads of both fight (each ran at 0.08–0.33x of its speed
alone), and threads that always sleep cost a training alone 5–17% (docs/performance.md).
So with --share-cores the trainers keep libgomp's spinning and poll ``SharedCores``: while
other processes keep this process's cores busy, torch runs on one thread. Opt-in, because
on some CPUs one thread and two round differently and the run then learns what the
machine's load decided (docs/performance.md). Imports nothing heavy.
"""

from __future__ import annotations

import os
import time


def cores() -> int:
    """The cores this process may run on (its CPU affinity: ``taskset`` and cgroups
    limit it), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


class SharedCores:
    """Torch's threads follow what other processes leave of this process's cores.

    At most every ``interval`` seconds (``poll`` is cheap between), the busy time of the
    cores this process may run on (``/proc/stat``) less this process's own CPU time
    (``/proc/self/stat``) says how many cores other processes used meanwhile. Above
    ``busy`` cores, torch runs on one thread (its idle OpenMP threads soon sleep, and the
    cores are shared); below ``free`` cores, on ``threads`` again (opt-in: the module's
    docstring says why). Where ``/proc`` cannot be read, nothing changes.
    """

    def __init__(self, threads: int, interval: float = 2.0, busy: float = 0.5,
                 free: float = 0.25) -> None:  # fmt: skip
        if not 0 <= free <= busy:
            raise ValueError(f"free ({free!r}) must be in [0, busy ({busy!r})]")
        self.threads, self.interval, self.busy, self.free = threads, interval, busy, free
        self.shared = False
        """Whether torch runs on one thread now because other processes are busy."""
        try:
            self._cpus = {f"cpu{c}" for c in os.sched_getaffinity(0)}
            self._tick = os.sysconf("SC_CLK_TCK")
        except (AttributeError, ValueError, OSError):  # not on Linux
            self._cpus, self._tick = set(), 100
        self._last = self._sample()

    def _sample(self) -> tuple[float, int, int] | None:
        """(monotonic seconds, busy ticks of this process's cores, this process's ticks)."""
        try:
            with open("/proc/stat") as f:  # cpuN user nice system idle iowait irq softirq ...
                busy = sum(
                    sum(int(words[i]) for i in (1, 2, 3, 6, 7))
                    for words in (line.split() for line in f)
                    if words and words[0] in self._cpus
                )
            with open("/proc/self/stat") as f:  # utime and stime: fields 14 and 15
                fields = f.read().rsplit(")", 1)[1].split()
            return time.monotonic(), busy, int(fields[11]) + int(fields[12])
        except (OSError, ValueError, IndexError):
            return None

    def others(self) -> float | None:
        """Cores other processes used since the last sample; None when the next sample
        is not due yet or ``/proc`` cannot be read."""
        if self._last is None or time.monotonic() - self._last[0] < self.interval:
            return None
        now = self._sample()
        last, self._last = self._last, now
        if now is None:
            return None
        return ((now[1] - last[1]) - (now[2] - last[2])) / self._tick / (now[0] - last[0])

    def poll(self) -> None:
        """Set torch's threads by what the others used since the last sample."""
        if self.threads <= 1:  # nothing to give back: no need to read /proc
            return
        others = self.others()
        if others is None:
            return
        if others < self.free if self.shared else others > self.busy:
            import torch  # here, not at every step

            self.shared = not self.shared
            torch.set_num_threads(1 if self.shared else self.threads)
