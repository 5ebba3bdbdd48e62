"""Ranks whose torchrun launcher is killed alone (SIGKILL to its pid, not its group) end with
it within 5 s, whenever it dies: while they load torch, while they build their envs, or
while they train; and the next training can take the run folder's lock
(``rwalk.rl.distributed.exit_with_launcher``).

Each case is a 2-rank torchrun training of 8 tiny envs per rank, killed at one point."""

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from test_distributed import ROOT, TINY, TORCHRUN, environment

from rwalk.rl.checkpoints import LOCK_NAME, RunSetupError, run_lock

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="reads /proc; Linux kills the ranks"
)


def ranks_of(launcher: int) -> list[int]:
    """The pids of the training processes ``launcher`` started."""
    ranks = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, IndexError):
            parent = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            command = (stat.parent / "cmdline").read_bytes()
            if parent == launcher and b"rwalk.runners.train" in command:
                ranks.append(int(stat.parent.name))
    return sorted(ranks)


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie waiting to be reaped has ended)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, IndexError):
        return False
    return state not in ("Z", "X")


def loading_torch(ranks: list[int], lines: list[str]) -> bool:
    """Both ranks have mapped torch's library: they are in ``import torch``, which
    ``rwalk.rl.distributed`` starts (before it, a launcher's death cannot be seen)."""
    with contextlib.suppress(FileNotFoundError):
        return all("libtorch_cpu" in Path(f"/proc/{pid}/maps").read_text() for pid in ranks)
    return False


KILL_POINTS = {
    "loading torch": loading_torch,
    # rank 0 holds the folder's lock from here on
    "building envs": lambda ranks, lines: any("building 8 envs" in line for line in lines),
    "training": lambda ranks, lines: any("[rwalk] iteration" in line for line in lines),
}


def lock_taken(run_dir: Path) -> bool:
    """Whether a training could take ``run_dir``'s lock now (a stale one: taken over)."""
    try:
        with run_lock(run_dir, report=lambda _: None):
            return True
    except RunSetupError:  # its holder still runs (or is a zombie not reaped yet)
        return False


SLOW = pytest.mark.slow  # the early kills are the ones that escaped; a later one is slow


@pytest.mark.parametrize(
    "point", [pytest.param(p, marks=SLOW) if p == "training" else p for p in KILL_POINTS]
)
def test_ranks_end_within_5_s_of_their_launcher_killed_alone(tmp_path, point):
    run_dir = tmp_path / "run"
    launcher = subprocess.Popen(
        [*TORCHRUN, "--standalone", "--nproc-per-node", "2", "-m", "rwalk.runners.train",
         *TINY, "--max-iterations", "100000", "--log-dir", str(run_dir)],
        cwd=ROOT, env=environment(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True, start_new_session=True,
    )  # fmt: skip
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(launcher.stdout), daemon=True).start()  # type: ignore[arg-type]
    ranks: list[int] = []
    try:
        deadline = time.monotonic() + 180
        while len(ranks) != 2 or not KILL_POINTS[point](ranks, lines):
            assert launcher.poll() is None, "".join(lines[-40:])
            assert time.monotonic() < deadline, f"not {point} within 180 s: " + "".join(lines)
            ranks = ranks if len(ranks) == 2 else ranks_of(launcher.pid)
            time.sleep(0.02)
        if point != "loading torch":
            assert (run_dir / LOCK_NAME).exists()
        os.kill(launcher.pid, signal.SIGKILL)  # the launcher alone
        launcher.wait()
        deadline = time.monotonic() + 5.0
        while any(alive(pid) for pid in ranks) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not [pid for pid in ranks if alive(pid)], f"ranks outlived their launcher ({point})"
        while not lock_taken(run_dir) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert lock_taken(run_dir), "the folder's lock is held 5 s after the launcher's end"
    finally:
        for pid in ranks:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(launcher.pid, signal.SIGKILL)
