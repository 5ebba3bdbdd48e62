"""The benchmark's machinery at tiny sizes: what it measures and reports, not how fast."""

import json

import pytest

from rwalk.runners.bench import bench, main, summary, table


def test_bench_pairs_each_contender_with_its_floor(tmp_path):
    out = tmp_path / "bench.json"
    results = bench(
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


def test_only_the_floor_runs_with_its_env_in_the_tiniest_window(capsys):
    """--only a,N,T used to fail (KeyError in the worker, then max() of no results)."""
    results = bench(["--only", "a,2,1", "--only", "b,2,1", "--seconds", "0.01"])
    out = capsys.readouterr().out
    assert "[1/1] (b)" in out and "failed" not in out  # (a) comes from (b)'s run: one run
    assert sorted(r["mode"] for r in results) == ["a", "b"]
    assert {(r["n"], r["threads"]) for r in results} == {(2, 1)}
    assert summary([]) == [] and table([]).count("\n") == 1


@pytest.mark.parametrize(
    "only", ["x,4,1", "a,64", "b,0,1", "b,4,zero", "b,4,0", "t,4,1", "b,4,1,2", ""]
)
def test_an_invalid_only_is_a_parse_error_naming_it(only, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--only", only])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "argument --only: expected 'mode,N,threads'" in err and f"got {only!r}" in err


@pytest.mark.parametrize("seconds", ["0", "-1", "nan", "inf", "soon"])
def test_the_window_must_be_a_positive_number(seconds, capsys):
    with pytest.raises(SystemExit):
        main(["--seconds", seconds])
    assert f"argument --seconds: expected a number of seconds > 0, got {seconds!r}" in (
        capsys.readouterr().err
    )
