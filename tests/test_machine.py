"""The machine a run trains on, as its record keeps it."""

import torch

from rwalk import machine

CPUINFO = """processor\t: 0
vendor_id\t: GenuineIntel
model name\t: Example CPU @ 2.00GHz
flags\t\t: fpu sse2 sse4_2 avx avx2 fma avx512f avx512bw avx512vl rdrand

processor\t: 1
model name\t: Example CPU @ 2.00GHz
flags\t\t: fpu sse2 sse4_2 avx avx2 fma avx512f avx512bw avx512vl rdrand
"""


def test_the_cpu_model_and_its_vector_instructions_are_read_from_cpuinfo(tmp_path, monkeypatch):
    path = tmp_path / "cpuinfo"
    path.write_text(CPUINFO)
    monkeypatch.setattr(machine, "CPUINFO", path)
    here = machine.describe()
    assert here["cpu"] == "Example CPU @ 2.00GHz"
    # in VECTOR_FLAGS' order, the other flags left out
    assert here["vector"] == "sse4_2 avx avx2 fma avx512f avx512bw avx512vl"
    assert here["torch_cpu"] == torch.backends.cpu.get_cpu_capability()
    assert here["torch"] == torch.__version__
    assert all(isinstance(value, str) and value for key, value in here.items() if key != "vector")


def test_without_cpuinfo_the_machine_is_still_described(tmp_path, monkeypatch):
    monkeypatch.setattr(machine, "CPUINFO", tmp_path / "absent")
    here = machine.describe()
    assert here["vector"] == "" and isinstance(here["cpu"], str)
    assert "torch_cpu" in machine.shown(here) and here["torch_cpu"] in machine.shown(here)
