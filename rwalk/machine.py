"""The machine a run trains on: what decides how its arithmetic rounds.

A training repeats bit for bit on one machine at one torch thread count (on some CPUs
at any count; docs/learning.md). Another CPU can round differently: torch and numpy
pick their vector kernels when they start (AVX2, AVX-512, ...), and 300 PPO iterations
carry a difference in the last bit into another policy. A run's record
(``rwalk.rl.record``) keeps the machines it trained on, so that such a difference shows.
"""

from __future__ import annotations

import platform
from pathlib import Path

import mujoco
import numpy as np
import torch

#: The CPU flags (as Linux names them) of the vector instructions that math libraries
#: choose between at run time.
VECTOR_FLAGS: tuple[str, ...] = (
    "sse4_2", "avx", "avx2", "fma", "f16c", "avx512f", "avx512dq", "avx512bw", "avx512vl",
    "avx512_vnni", "avx512_bf16", "avx512_fp16", "amx_tile",
)  # fmt: skip
CPUINFO = Path("/proc/cpuinfo")


def _cpuinfo() -> dict[str, str]:
    """Each key of /proc/cpuinfo with its first value ({} where there is none: not Linux)."""
    try:
        text = CPUINFO.read_text(errors="replace")
    except OSError:
        return {}
    info: dict[str, str] = {}
    for line in text.splitlines():
        name, colon, value = line.partition(":")
        if colon:
            info.setdefault(name.strip(), value.strip())
    return info


def describe() -> dict[str, str]:
    """This machine as a run's record keeps it: the CPU's model and vector instructions,
    the vector kernels torch chose, and the versions of the libraries that compute a run."""
    info = _cpuinfo()
    flags = set(info.get("flags", "").split())
    return {
        "cpu": info.get("model name") or platform.processor() or platform.machine(),
        "vector": " ".join(flag for flag in VECTOR_FLAGS if flag in flags),
        "torch_cpu": torch.backends.cpu.get_cpu_capability(),
        "torch": torch.__version__,
        "numpy": np.__version__,
        "mujoco": mujoco.__version__,
        "python": platform.python_version(),
    }


def shown(machine: dict[str, str]) -> str:
    """A machine in a few words, for a message."""
    return ", ".join(f"{key} {machine.get(key, '?')}" for key in ("cpu", "torch_cpu", "torch"))
