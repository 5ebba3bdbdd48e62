"""The benchmark's machinery at tiny sizes: what it measures and reports, not how fast."""

import json

from rwalk.runners.bench import main, summary, table


def test_bench_pairs_each_contender_with_its_floor(tmp_path):
    out = tmp_path / "bench.json"
    results = main(
        ["--only", "b,4,1", "--only", "c,4,1", "--only", "t,4,2", "--only", "d,1,1",
         "--seconds", "0.4", "--json", str(out)]
    )  # fmt: skip
    by_mode = {r["mode"]: r for r in results}
    assert set(by_mode) == {"a", "b", "c", "d", "t"}
    assert json.loads(out.read_text()) == results
    b, a = by_mode["b"], by_mode["a"]
    assert b["ratio_to_floor"] == b["physics_steps_per_s"] / b["floor_physics_steps_per_s"]
    assert b["floor_physics_steps_per_s"] == a["physics_steps_per_s"]
    assert by_mode["c"]["ratio_to_floor"] > 0
    for row in (b, by_mode["c"]):
        assert 0.0 <= row["settle_share"] <= 1.0 and 0.0 < row["time_in_mujoco"] <= 1.0
        # every env step is 10 physics steps, plus settling
        assert row["physics_steps_per_s"] >= 10 * row["env_steps_per_s"] * 0.999
    pairs = by_mode["t"]["pairs"]
    assert {row["threads"] for row in pairs.values()} == {1, 2}
    speedup = pairs["b2"]["env_steps_per_s"] / pairs["b1"]["env_steps_per_s"]
    assert by_mode["t"]["env_speedup"] == speedup
    assert "| b ResidualWalkVecEnv | 4 | 1 |" in table(results)
    assert any(line.startswith("(b) 2 threads vs 1 at N=4") for line in summary(results))
