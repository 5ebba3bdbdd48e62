"""Progress lines: their text, their pace, their silence off a terminal, and the core's hook."""

import io

import pytest

from rwalk import EnvConfig, ResidualWalkCore
from rwalk.progress import Progress, format_seconds


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_lines_every_interval_with_rate_and_eta():
    clock, out = FakeClock(), io.StringIO()
    report = Progress("settling starts", "steps", stream=out, enabled=True, clock=clock)
    report(0, 1000)
    for done in range(100, 1001, 100):  # 100 steps per second
        clock.now += 1.0
        report(done, 1000)
    assert out.getvalue().splitlines() == [
        "settling starts: 200/1,000 steps (20%), 100 steps/s, ETA 8s",
        "settling starts: 400/1,000 steps (40%), 100 steps/s, ETA 6s",
        "settling starts: 600/1,000 steps (60%), 100 steps/s, ETA 4s",
        "settling starts: 800/1,000 steps (80%), 100 steps/s, ETA 2s",
        "settling starts: 1,000/1,000 steps (100%), 100 steps/s, took 10s",
    ]


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
    assert out.getvalue() == "eval: 100/300 steps (33%), 1 steps/s, ETA 5m00s\n"


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


def test_durations_read_naturally():
    assert [format_seconds(s) for s in (0, 59.4, 61, 3599, 3720)] == [
        "0s", "59s", "1m01s", "59m59s", "1h02m",
    ]  # fmt: skip
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
