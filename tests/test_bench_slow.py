"""The throughput floor, measured by the benchmark (slow: run with `pytest -m slow`).

CI does not run this: its figures depend on the machine and its load."""

import pytest

from rwalk.runners.bench import bench


@pytest.mark.slow
def test_env_runs_near_its_physics_floor():
    results = bench(["--only", "b,1024,2", "--seconds", "8"])  # b also measures its floor a
    by_mode = {r["mode"]: r for r in results}
    # The floor is 0.90; the margin absorbs noise of a loaded machine.
    assert by_mode["b"]["ratio_to_floor"] >= 0.8
    assert by_mode["b"]["time_in_mujoco"] >= 0.85
