"""Progress lines for long work (settling thousands of starts, long evaluations), by tqdm.

    report = Progress("settling starts", unit="physics steps")
    report(0, total)          # a run starts
    report(done, total)       # after each piece of work

Each run is one tqdm bar on stderr (``settling starts:  40%|████      | 400/1000
[00:04<00:06, 100.00 physics steps/s]``), redrawn at most every ``interval``
seconds, and left as a last line when a run that drew anything finishes; work
shorter than ``interval`` draws nothing. Bars are drawn only when the stream is
a terminal (logs and pipes stay clean) unless ``enabled=True`` forces them.
This module only maps the ``(done, total)`` calls the core and the evaluation
make onto tqdm's bars.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO

from tqdm import tqdm

#: Seconds between two redraws of a bar (and before the first one).
INTERVAL = 2.0

#: tqdm's default layout, with the rate always in units per second (tqdm would switch
#: to seconds per unit below 1/s).
BAR_FORMAT = "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}<{remaining}, {rate_noinv_fmt}]"


class Progress:
    """Callable ``(done, total)`` that draws a tqdm bar per run of work.

    A call with ``done == 0`` (or fewer done than the last call) starts a new
    run: its clock restarts, so the rate and the remaining time are the run's own.

    Args:
        label: what is being done ("settling starts").
        unit: what ``done`` counts ("steps").
        stream: where bars go; None = ``sys.stderr`` when a run starts.
        enabled: True draws whatever the stream; None draws only if the
            stream is a terminal; False never draws.
        interval: most redraws per run = one per ``interval`` seconds, plus the last;
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
        self._bar: tqdm | None = None
        self._done = 0

    @property
    def stream(self) -> TextIO:
        return sys.stderr if self._stream is None else self._stream

    def active(self) -> bool:
        """Whether bars are drawn (forced, or the stream is a terminal)."""
        if self.enabled is not None:
            return self.enabled
        isatty = getattr(self.stream, "isatty", None)
        try:
            return bool(isatty and isatty())
        except ValueError:  # a closed stream
            return False

    def __call__(self, done: int, total: int) -> None:
        if done == 0 or done < self._done:  # a new run
            self._finish()
            self._done = done
            self._bar = self._start(total) if self.active() else None
            return
        if done == self._done:  # nothing new (e.g. the finished run reported again)
            return
        self._done = done
        if self._bar is None:
            return
        self._bar.update(done - self._bar.n)
        if done >= total:
            self._finish()

    def _start(self, total: int) -> tqdm:
        """A bar that stays silent for its first ``interval`` seconds."""
        bar = tqdm(
            total=total,
            desc=self.label,
            unit=f" {self.unit}",  # the rate reads "100.00 steps/s"
            file=self.stream,
            mininterval=self.interval,
            delay=self.interval,
            miniters=1,  # any progress may be drawn once the interval has passed
            bar_format=BAR_FORMAT,
        )
        # tqdm reads time through its _time attribute; its own tests swap the clock the same way.
        bar._time = self.clock
        bar.start_t = bar.last_print_t = self.clock()
        return bar

    def _finish(self) -> None:
        """Close the current bar: its last line stays if it drew anything."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
