"""Progress lines for long work (settling thousands of starts, long evaluations).

    report = Progress("settling starts", unit="physics steps")
    report(0, total)          # a run starts
    report(done, total)       # after each piece of work

A line ``label: done/total unit (pct), rate unit/s, ETA 1m05s`` goes to stderr
at most every ``interval`` seconds, and a last one when a run that printed
anything finishes; work shorter than ``interval`` prints nothing. Lines are
written only when the stream is a terminal (logs and pipes stay clean) unless
``enabled=True`` forces them. No dependency: tqdm is not installed here.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO

#: Seconds between two progress lines.
INTERVAL = 2.0


def format_seconds(seconds: float) -> str:
    """``42s``, ``3m05s``, ``1h02m``."""
    seconds = max(0, round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"


class Progress:
    """Callable ``(done, total)`` that prints periodic progress lines.

    A call with ``done == 0`` (or fewer done than the last call) starts a new
    run: its clock restarts, so the rate and ETA are the run's own.

    Args:
        label: what is being done ("settling starts").
        unit: what ``done`` counts ("steps").
        stream: where lines go; None = ``sys.stderr`` at call time.
        enabled: True prints whatever the stream; None prints only if the
            stream is a terminal; False never prints.
        interval: most lines per run = one per ``interval`` seconds, plus the last;
            None = ``INTERVAL``.
        clock: seconds from an arbitrary origin (tests pass a fake one).
    """

    def __init__(
        self,
        label: str,
        unit: str = "steps",
        *,
        stream: TextIO | None = None,
        enabled: bool | None = None,
        interval: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        interval = INTERVAL if interval is None else interval
        if not interval >= 0:
            raise ValueError(f"interval must be >= 0 seconds, got {interval!r}")
        self.label, self.unit = label, unit
        self._stream, self.enabled = stream, enabled
        self.interval, self.clock = interval, clock
        self._start = self._last = clock()
        self._done = 0
        self._printed = False

    @property
    def stream(self) -> TextIO:
        return sys.stderr if self._stream is None else self._stream

    def active(self) -> bool:
        """Whether lines are written (forced, or the stream is a terminal)."""
        if self.enabled is not None:
            return self.enabled
        isatty = getattr(self.stream, "isatty", None)
        try:
            return bool(isatty and isatty())
        except ValueError:  # a closed stream
            return False

    def __call__(self, done: int, total: int) -> None:
        now = self.clock()
        if done == 0 or done < self._done:  # a new run
            self._start = self._last = now
            self._printed = False
            self._done = done
            return
        if done == self._done:  # nothing new (e.g. the finished run reported again)
            return
        self._done = done
        finished = done >= total
        due = now - self._last >= self.interval
        if not (due or (finished and self._printed)) or not self.active():
            return
        self._last, self._printed = now, True
        self.stream.write(self.line(done, total, now - self._start) + "\n")
        self.stream.flush()

    def line(self, done: int, total: int, elapsed: float) -> str:
        """``label: done/total unit (pct), rate unit/s, ETA ...`` (or ``took ...`` when done)."""
        rate = done / elapsed if elapsed > 0 else float("inf")
        text = f"{self.label}: {done:,}/{total:,} {self.unit} ({done / max(total, 1):.0%}), "
        text += f"{rate:,.0f} {self.unit}/s, "
        if done >= total:
            return text + f"took {format_seconds(elapsed)}"
        return text + f"ETA {format_seconds((total - done) / rate)}"
