"""Progress lines: their text, their pace, their silence off a terminal, and the core's hook."""

import io
import re

import pytest

from rwalk import EnvConfig, ResidualWalkCore
from rwalk.progress import Progress


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def lines(text: str) -> list[str]:
    """tqdm's redraws of a bar (it returns to the line start with a carriage return)."""
    return [line for line in re.split(r"[\r\n]", text) if line]


def test_lines_every_interval_with_rate_and_remaining_time():
    clock, out = FakeClock(), io.StringIO()
    report = Progress("settling starts", "steps", stream=out, enabled=True, clock=clock)
    report(0, 1000)
    for done in range(100, 1001, 100):  # 100 steps per second
        clock.now += 1.0
        report(done, 1000)
    drawn = lines(out.getvalue())
    assert [line.split("|")[0] for line in drawn] == [
        "settling starts:  20%",
        "settling starts:  40%",
        "settling starts:  60%",
        "settling starts:  80%",
        "settling starts: 100%",
        "settling starts: 100%",  # the bar's last line, left when the run finishes
    ]
    assert [line.split("| ")[1].split(" [")[0] for line in drawn] == [
        "200/1000", "400/1000", "600/1000", "800/1000", "1000/1000", "1000/1000",
    ]  # fmt: skip
    assert all(line.endswith(", 100.00 steps/s]") for line in drawn), drawn
    assert "| 200/1000 [00:02<" in drawn[0]  # elapsed, then the remaining time
    assert drawn[-1].endswith("| 1000/1000 [00:10<00:00, 100.00 steps/s]")
    assert out.getvalue().endswith("\n")


def test_a_new_run_restarts_the_clock_and_short_runs_print_nothing():
    clock, out = FakeClock(), io.StringIO()
    report = Progress("eval", stream=out, enabled=True, clock=clock)
    report(0, 10)
    clock.now += 1.5
    report(10, 10)  # finished before the first interval: silent
    assert out.getvalue() == ""
    clock.now += 60.0  # idle time between runs is not counted
    report(0, 300)
    clock.now += 150.0
    report(100, 300)
    (line,) = lines(out.getvalue())
    assert line.startswith("eval:  33%|") and "| 100/300 [02:30<" in line
    assert line.endswith(" 0.67 steps/s]")


def test_silent_unless_the_stream_is_a_terminal_or_forced():
    for stream, enabled, expected in [
        (io.StringIO(), None, False),
        (Terminal(), None, True),
        (Terminal(), False, False),
        (io.StringIO(), True, True),
    ]:
        clock = FakeClock()
        report = Progress("x", stream=stream, enabled=enabled, clock=clock)
        report(0, 4)
        clock.now += 3.0
        report(1, 4)
        assert bool(stream.getvalue()) is expected, (type(stream).__name__, enabled)


def test_a_bad_interval_is_named():
    with pytest.raises(ValueError, match="interval"):
        Progress("x", interval=float("nan"))


def test_the_core_reports_each_settle_chunk(monkeypatch):
    import rwalk.starts

    monkeypatch.setattr(rwalk.starts, "SETTLE_CTRL_BUDGET", 3 * 12 * 8)  # 8 substeps a chunk
    core = ResidualWalkCore(EnvConfig(settle_steps=4, randomize=False), 3, seed=0)
    calls = []
    core.settle_progress = lambda done, total: calls.append((done, total))
    core.reset()
    # 4 steps x 5 substeps x 3 envs, in chunks of 8 substeps
    assert core.decimation == 5
    assert calls == [(0, 60), (24, 60), (48, 60), (60, 60)]
