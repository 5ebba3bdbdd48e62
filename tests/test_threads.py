"""rwalk.threads.SharedCores: torch's threads follow what other processes leave of this
process's cores. Hand-computed samples, the switch and its hysteresis, a real busy
process, and a training whose threads switch at every step (--share-cores) that learns
the same bits as one that never switches (the default)."""

import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from test_learning import TINY

from rwalk.rl.checkpoints import load_checkpoint
from rwalk.runners import train
from rwalk.threads import SharedCores


@pytest.fixture
def two_threads():
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(before)


def test_others_are_the_busy_time_of_the_cores_less_this_process_s():
    cores = SharedCores(2, interval=0.0)
    cores._tick = 100
    samples = iter([(12.0, 1400, 150), (13.0, 1420, 160)])
    cores._last, cores._sample = (10.0, 1000, 50), lambda: next(samples)
    # 2 s: the cores were busy 400 ticks, 100 of them this process's: 300 / 100 / 2
    assert cores.others() == pytest.approx(1.5)
    assert cores.others() == pytest.approx(0.1)  # then 1 s: (20 - 10) / 100 / 1
    cores._sample = lambda: None  # /proc could not be read: no reading, now or later
    assert cores.others() is None and cores.others() is None


def test_one_thread_while_others_are_busy_then_all_again(two_threads, monkeypatch):
    cores = SharedCores(2, busy=0.5, free=0.25)
    readings = iter([0.3, 0.6, 0.3, 0.2, None])
    monkeypatch.setattr(cores, "others", lambda: next(readings))
    seen = []
    for _ in range(5):
        cores.poll()
        seen.append((cores.shared, torch.get_num_threads()))
    # 0.3 is between free and busy: no change either way (hysteresis)
    assert seen == [(False, 2), (True, 1), (True, 1), (False, 2), (False, 2)]
    with pytest.raises(ValueError, match=r"free \(0.6\) must be in \[0, busy \(0.5\)\]"):
        SharedCores(2, busy=0.5, free=0.6)


@pytest.mark.skipif(not Path("/proc/stat").exists(), reason="reads Linux's /proc")
def test_a_busy_process_is_seen():
    cores = SharedCores(2, interval=1.0)
    spin = "import time\nend = time.monotonic() + 4\nwhile time.monotonic() < end: pass"
    busy = subprocess.Popen([sys.executable, "-c", spin])
    try:
        time.sleep(0.5)  # it has started
        cores._last = cores._sample()
        time.sleep(1.5)
        others = cores.others()
    finally:
        busy.kill()
        busy.wait()
    assert others is not None and others > 0.5  # about one core


def test_a_training_whose_threads_switch_learns_the_same_bits(tmp_path, monkeypatch):
    """Tiny tensors: this shows that switching mid-run changes nothing in the run's
    order of work. At the default's size torch's math may round differently on 1 and 2
    threads (it does on an AVX-512 Xeon: docs/performance.md), which is why sharing is
    opt-in (--share-cores) and a default run, however busy the machine, never switches."""
    flips = iter(range(10**6))
    monkeypatch.setattr(SharedCores, "others", lambda self: 1.0 if next(flips) % 2 else 0.0)
    calls = []
    real = torch.set_num_threads
    monkeypatch.setattr(torch, "set_num_threads", lambda n: calls.append(n) or real(n))
    base = [*TINY, "--num-envs", "32", "--max-iterations", "3", "--threads", "2"]
    train.main([*base, "--share-cores", "--log-dir", str(tmp_path / "shared")])
    switched = calls[1:]
    assert switched[:4] == [1, 2, 1, 2] and len(switched) > 10  # at every other step
    calls.clear()
    train.main([*base, "--log-dir", str(tmp_path / "fixed")])  # the default: busy or not
    assert calls == [2]  # --threads, then never again
    shared, fixed = (load_checkpoint(tmp_path / run / "model_2.pt") for run in ("shared", "fixed"))
    for part in ("actor_state_dict", "critic_state_dict"):
        assert shared[part].keys() == fixed[part].keys()
        for name, value in shared[part].items():
            assert torch.equal(value, fixed[part][name]), (part, name)
