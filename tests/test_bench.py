"""The benchmark's machinery at tiny sizes: what it measures and reports, not how fast."""

import json
import sys

import pytest

from rwalk.bench.envpool import MISSING, check_memory
from rwalk.bench.report import summary, table
from rwalk.runners.bench import bench, main


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
        # every env step is `substeps` physics steps, plus settling
        assert row["physics_steps_per_s"] >= row["substeps"] * row["env_steps_per_s"] * 0.999
    for row in results:
        # the env step's duration comes from the world's timestep, not from a constant
        assert row["control_dt_s"] == pytest.approx(row["substeps"] * row["timestep_s"])
    for row in (a, b, by_mode["c"], by_mode["d"]):
        expected = row["env_steps_per_s"] * row["control_dt_s"] / row["threads"]
        assert row["robot_seconds_per_core_second"] == pytest.approx(expected)
    for row in by_mode["t"]["pairs"].values():
        expected = row["env_steps_per_s"] * row["control_dt_s"] / row["threads"]
        assert row["robot_seconds_per_core_second"] == pytest.approx(expected)
    pairs = by_mode["t"]["pairs"]
    assert {row["threads"] for row in pairs.values()} == {1, 2}
    speedup = pairs["b2"]["env_steps_per_s"] / pairs["b1"]["env_steps_per_s"]
    assert by_mode["t"]["env_speedup"] == speedup
    assert "| b ResidualWalkVecEnv | 4 | 1 |" in table(results)
    header = table(results).splitlines()[0]
    assert "| control period | robot s / core s |" in header
    assert f" {b['robot_seconds_per_core_second']:.2f} |" in table(results)
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
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "error: --only must be 'mode,N,threads'" in err
    assert err.endswith(f"got {only!r}")


@pytest.mark.parametrize("seconds", ["0", "-1", "nan", "inf", "3601", "soon"])
def test_the_window_must_be_a_positive_number(seconds, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--seconds", seconds])
    err = capsys.readouterr().err.strip()
    assert exit_info.value.code == 2 and "\n" not in err
    shown = "['soon']" if seconds == "soon" else str(float(seconds))  # the value, as parsed
    assert "error: --seconds must be " in err and err.endswith(f"got {shown}")
    if seconds != "soon":
        assert "a number of seconds > 0 and at most 3600" in err


def test_an_unwritable_json_is_refused_before_the_sweep(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    with pytest.raises(SystemExit) as exit_info:
        main(["--only", "b,1,1", "--json", str(tmp_path / "file" / "bench.json")])
    printed = capsys.readouterr()
    assert exit_info.value.code == 2 and "error: --json " in printed.err
    assert "file' is not a folder" in printed.err and printed.out == ""  # no run started


def _row(mode, n, threads, env_steps_per_s, **extra):
    """A crafted result row: 20 ms env steps of 5 x 4 ms substeps."""
    return {
        "mode": mode, "n": n, "threads": threads, "env_steps_per_s": env_steps_per_s,
        "physics_steps_per_s": 5 * env_steps_per_s, "control_dt_s": 0.02, "substeps": 5,
        "timestep_s": 0.004, "robot_seconds_per_core_second": env_steps_per_s * 0.02 / threads,
        "settle_share": 0.0, "peak_rss_mb": 400.0, **extra,
    }  # fmt: skip


def test_the_summary_gives_robot_seconds_per_core_second_at_n_1024_on_one_thread():
    rows = [
        _row("b", 1024, 1, 5000.0, ratio_to_floor=0.95, floor_physics_steps_per_s=26000.0),
        _row("a", 1024, 1, 5200.0, ratio_to_floor=1.0),
        _row("b", 1024, 2, 9000.0, ratio_to_floor=0.95),
        _row("b", 16, 1, 2000.0, ratio_to_floor=0.8),
    ]
    lines = [line for line in summary(rows) if line.startswith("robot-seconds")]
    assert lines == [
        "robot-seconds per core-second at N=1024, 1 thread: (b) 100.00, (a) 104.00 "
        "(control period 20 ms (5 x 4 ms))"
    ]
    assert "| 20 ms (5 x 4 ms) | 100.00 |" in table(rows)
    one_thread = summary(rows[:2] + rows[3:])  # cores = 1: each line once, not for 1 and 1
    assert one_thread.count("(b)/(a) physics steps/s at N=1024, 1 thread(s): 0.950") == 1


def test_the_envpool_mode_is_skipped_in_one_line_without_envpool(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "envpool", None)  # `import envpool` raises ImportError
    assert main(["--only", "e,4,1", "--only", "e,8,1", "--seconds", "0.01"]) == 0
    out = capsys.readouterr().out
    skips = [line for line in out.splitlines() if "skipped" in line]
    assert skips == [
        f"[{i}/2] (e) rwalk vs EnvPool Go1 joystick, N={n}, threads=1 ... skipped: {MISSING}"
        for i, n in ((1, 4), (2, 8))
    ]
    assert "failed" not in out and "Traceback" not in out


def test_the_envpool_contest_table_and_summary():
    ours = _row("e", 256, 1, 6000.0, terrain="rough", contender="rwalk", task="world_train",
                cores_busy=1.0, resets_per_step=2.56, memory_per_env_mb=0.25,
                ratio_to_envpool=1.5)  # fmt: skip
    theirs = _row("e", 256, 1, 4000.0, terrain="rough", contender="envpool", task="Go1Rough",
                  cores_busy=0.95, resets_per_step=5.12, memory_per_env_mb=40.0)  # fmt: skip
    text = table([theirs, ours])
    assert text.splitlines()[0].startswith("| terrain | env | N | threads |")
    assert "| rough | rwalk world_train | 256 | 1 | 6,000 | 20 ms (5 x 4 ms) | 120.00 |" in text
    assert text.index("rwalk world_train") < text.index("EnvPool Go1Rough")
    (line,) = summary([ours, theirs])
    assert line.startswith(
        "(e) rough, N=256, 1 thread(s), alternating: rwalk world_train 120.00 vs EnvPool "
        "Go1Rough 80.00 robot-seconds per core-second: 1.50x; memory per env 0.25 vs 40.0 MB"
    )


def test_envpool_is_refused_an_n_that_would_not_fit():
    check_memory(256, 24 * 1024.0)
    check_memory(10**6, None)  # nothing known: no refusal
    with pytest.raises(MemoryError, match=r"N=1024: EnvPool's Go1 needs about 50\.5 GB"):
        check_memory(1024, 24 * 1024.0)


def test_rwalk_against_envpool_when_installed():
    pytest.importorskip("envpool")  # the bench extra: not in CI
    results = bench(["--only", "e,2,1", "--seconds", "0.2"])
    pairs = {(r["terrain"], r["contender"]): r for r in results}
    assert set(pairs) == {(t, c) for t in ("rough", "flat") for c in ("rwalk", "envpool")}
    for terrain in ("rough", "flat"):
        ours, theirs = pairs[(terrain, "rwalk")], pairs[(terrain, "envpool")]
        assert theirs["control_dt_s"] == pytest.approx(theirs["substeps"] * theirs["timestep_s"])
        assert ours["ratio_to_envpool"] == pytest.approx(
            ours["robot_seconds_per_core_second"] / theirs["robot_seconds_per_core_second"]
        )
        assert theirs["memory_per_env_mb"] > 0 and 0 < theirs["cores_busy"] < 1.5


def test_the_adaptive_task_runs_against_a_floor_of_its_own():
    results = bench(["--only", "g,4,1", "--seconds", "0.2"])
    by_mode = {r["mode"]: r for r in results}
    assert set(by_mode) == {"a", "g"}
    g = by_mode["g"]
    assert g["ratio_to_floor"] == g["physics_steps_per_s"] / g["floor_physics_steps_per_s"]
    assert 0.0 < g["time_in_mujoco"] <= 1.0
    assert "| g AdaptiveGaitVecEnv | 4 | 1 |" in table(results)


def test_the_robust_world_is_timed_against_the_plain_and_map_only_envs():
    results = bench(["--only", "r,4,1", "--seconds", "0.3"])
    (r,) = results
    assert r["mode"] == "r" and r["n"] == 4
    pairs = r["pairs"]
    fps = {name: pairs[name]["env_steps_per_s"] for name in ("plain", "map", "robust")}
    assert all(value > 0 for value in fps.values())
    assert r["robust_over_plain"] == fps["robust"] / fps["plain"]
    assert r["robust_over_map"] == fps["robust"] / fps["map"]
    assert r["env_steps_per_s"] == fps["robust"]
    assert any(line.startswith("(r) robust training env at N=4") for line in summary(results))


@pytest.mark.slow
def test_sharing_times_a_training_alone_and_two_side_by_side():
    from rwalk.bench import sharing

    tiny = ("--num-steps-per-env", "4", "--settle-steps", "2", "--max-episode-steps", "20",
            "--hidden-dims", "8")  # fmt: skip
    row = sharing.measure(8, iterations=4, flags=tiny)
    assert row["alone_s_per_iteration"] > 0 and len(row["side_by_side_speed"]) == 2
    assert all(speed > 0 for speed in row["side_by_side_speed"])
