"""The benchmark's reports: the markdown tables, the summary lines and the plot.

- ``LABELS``: what each mode times, as the tables and the progress lines name it.
- ``add_ratios_to_floor``: each row's physics steps/s over its floor's (a).
- ``worker_line``: one worker's rows, as the progress lines print them.
- ``table`` (modes a-d, g), ``contest_table`` (mode e), ``summary`` (the floors
  and figures of the sweep, one line each) and ``plot`` (throughput against N).

Pure functions of the result rows the workers print (``rwalk.bench.modes``).
"""

from __future__ import annotations

from pathlib import Path

#: What each mode times; (e)'s worker modes run one terrain each.
LABELS = {
    "a": "raw mujoco.rollout (floor)",
    "b": "ResidualWalkVecEnv",
    "g": "AdaptiveGaitVecEnv",
    "c": "rsl-rl collection",
    "d": "gymnasium vector env",
    "t": "ResidualWalkVecEnv, thread scaling",
    "r": "robust training env vs plain and map-only",
    "s": "two default trainings sharing the machine",
    "e": "rwalk vs EnvPool Go1 joystick",
    "e/rough": "world_train vs EnvPool Go1JoystickRoughTerrain-v1",
    "e/flat": "world_flat vs EnvPool Go1JoystickFlatTerrain-v1",
}


def add_ratios_to_floor(results: list[dict]) -> None:
    """Set each row's ratio_to_floor: its physics steps/s over those of its floor (a), the
    one timed beside it or else (a) at the same N and threads; None without one."""
    floor = {(r["n"], r["threads"]): r["physics_steps_per_s"] for r in results if r["mode"] == "a"}
    for r in results:
        if r["mode"] in ("t", "e", "r", "s"):  # (t), (r), (s): ratios of their own; (e) no floor
            continue
        base = r.get("floor_physics_steps_per_s") or floor.get((r["n"], r["threads"]))
        r["ratio_to_floor"] = r["physics_steps_per_s"] / base if base else None


def worker_line(rows: list[dict]) -> str:
    """One worker's rows on one line: each mode's (and contender's) env and physics steps/s
    ((s): seconds per iteration alone and side by side)."""
    if rows and rows[0]["mode"] == "s":
        r = rows[0]
        side = ", ".join(f"{v:.2f}" for v in r["side_by_side_s_per_iteration"])
        return f"(s) {r['alone_s_per_iteration']:.2f} s/iteration alone, {side} side by side"
    return ", ".join(
        f"({' '.join(filter(None, (r['mode'], r.get('contender'))))}) "
        f"{r['env_steps_per_s']:,.0f} env steps/s "
        f"{r['physics_steps_per_s']:,.0f} physics steps/s"
        for r in rows
    )


def _period(r: dict) -> str:
    """A row's control period as 'env step (substeps x timestep)'."""
    return f"{r['control_dt_s'] * 1e3:g} ms ({r['substeps']} x {r['timestep_s'] * 1e3:g} ms)"


def table(results: list[dict]) -> str:
    """The results as markdown: one table for (a)-(d), and one for (e) if it ran."""
    lines = [
        "| mode | N | threads | env steps/s | physics steps/s | control period "
        "| robot s / core s | ratio to its (a) | settle share (window / amortized) "
        "| time in MuJoCo | peak RSS (MB) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    rows = [r for r in results if r["mode"] not in ("t", "e", "r", "s")]
    contest = [r for r in results if r["mode"] == "e"]
    if contest and not rows:
        return "\n".join(contest_table(contest))
    for r in sorted(rows, key=lambda r: (r["mode"], r["n"], r["threads"])):
        ratio = f"{r['ratio_to_floor']:.3f}" if r.get("ratio_to_floor") else "—"
        mujoco_share = f"{r['time_in_mujoco']:.1%}" if "time_in_mujoco" in r else "—"
        lines.append(
            f"| {r['mode']} {LABELS[r['mode']]} | {r['n']} | {r['threads']} | "
            f"{r['env_steps_per_s']:,.0f} | {r['physics_steps_per_s']:,.0f} | {_period(r)} | "
            f"{r['robot_seconds_per_core_second']:.2f} | {ratio} | "
            f"{r['settle_share']:.1%} / {r.get('settle_share_amortized', 0.0):.1%} | "
            f"{mujoco_share} | {r['peak_rss_mb']:,.0f} |"
        )
    if contest:
        lines += ["", *contest_table(contest)]
    return "\n".join(lines)


def contest_table(rows: list[dict]) -> list[str]:
    """(e): rwalk and EnvPool's Go1 on matching terrain, timed in alternating rounds."""
    lines = [
        "| terrain | env | N | threads | env steps/s | control period | robot s / core s "
        "| cores busy (measured) | resets per env step | memory per env (MB: added / N) "
        "| rwalk / EnvPool (robot s / core s) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    order = {"rough": 0, "flat": 1, "rwalk": 0, "envpool": 1}

    def key(r: dict) -> tuple:
        return order[r["terrain"]], r["n"], r["threads"], order[r["contender"]]

    for r in sorted(rows, key=key):
        name = f"rwalk {r['task']}" if r["contender"] == "rwalk" else f"EnvPool {r['task']}"
        ratio = f"{r['ratio_to_envpool']:.2f}" if "ratio_to_envpool" in r else ""
        lines.append(
            f"| {r['terrain']} | {name} | {r['n']} | {r['threads']} | "
            f"{r['env_steps_per_s']:,.0f} | {_period(r)} | "
            f"{r['robot_seconds_per_core_second']:.2f} | {r['cores_busy']:.2f} | "
            f"{r['resets_per_step'] / r['n']:.4f} | {r['memory_per_env_mb']:.2f} | {ratio} |"
        )
    return lines


def summary(results: list[dict]) -> list[str]:
    """The issue's floors, computed from the sweep."""
    out: list[str] = []
    if not results:
        return out
    by = {(r["mode"], r["n"], r["threads"]): r for r in results}
    cores = max(r["threads"] for r in results)
    thread_counts = sorted({1, cores})  # once each where every row ran on 1 thread
    for mode, n, t in [(m, n, t) for m in "bc" for n in (1024, 4096, 8192) for t in thread_counts]:
        if (mode, n, t) in by:
            ratio = by[(mode, n, t)]["ratio_to_floor"]
            out.append(f"({mode})/(a) physics steps/s at N={n}, {t} thread(s): {ratio:.3f}")
    batched = [r for r in results if r["mode"] == "b"]
    gyms = [r for r in results if r["mode"] == "d"]
    if batched and gyms:
        best_b = max(batched, key=lambda r: r["env_steps_per_s"])
        best_d = max(gyms, key=lambda r: r["env_steps_per_s"])
        out.append(
            f"best (b) {best_b['env_steps_per_s']:,.0f} env steps/s (N={best_b['n']}) vs best (d) "
            f"{best_d['env_steps_per_s']:,.0f} (N={best_d['n']}, {best_d['threads']} process(es)): "
            f"{best_b['env_steps_per_s'] / best_d['env_steps_per_s']:.2f}x"
        )
    if ("d", 1, 1) in by and ("a", 1, 1) in by:
        single, floor = by[("d", 1, 1)], by[("a", 1, 1)]
        share = single["physics_steps_per_s"] / floor["physics_steps_per_s"]
        out.append(
            f"single env: {single['env_steps_per_s']:,.0f} steps/s, {share:.3f} of the N=1 floor"
        )
    if ("b", 256, cores) in by and ("b", 4096, cores) in by:
        small, large = by[("b", 256, cores)], by[("b", 4096, cores)]
        per_env = (large["peak_rss_mb"] - small["peak_rss_mb"]) * 1024 / (4096 - 256)
        out.append(f"memory per additional env (N=4096 vs 256): {per_env:.1f} KB")
    for r in results:
        if r["mode"] == "t":
            out.append(
                f"(b) {r['threads']} threads vs 1 at N={r['n']}, one process, alternating: "
                f"{r['env_speedup']:.2f}x (raw mujoco.rollout: {r['floor_speedup']:.2f}x)"
            )
    for r in results:
        if r["mode"] == "s":
            speeds = " and ".join(f"{v:.2f}x" for v in r["side_by_side_speed"])
            out.append(
                f"(s) two --share-cores trainings of N={r['num_envs']} side by side: each at "
                f"{speeds} of one alone ({r['alone_s_per_iteration']:.2f} s per iteration "
                f"alone; on fixed threads, the default, "
                f"{r['alone_fixed_threads_s_per_iteration']:.2f} s)"
            )
    for r in results:
        if r["mode"] == "r":
            out.append(
                f"(r) robust training env at N={r['n']}, {r['threads']} thread(s), one process, "
                f"alternating: {r['robust_over_plain']:.3f} of the plain env's env steps/s "
                f"({r['robust_over_map']:.3f} of the map alone; map alone "
                f"{r['map_over_plain']:.3f} of plain)"
            )
    if ("b", 4096, cores) in by:
        r = by[("b", 4096, cores)]
        out.append(
            f"training defaults at N=4096: {r['env_steps_per_s']:,.0f} env steps/s, settle share "
            f"{r['settle_share']:.1%} in the window, {r['settle_share_amortized']:.1%} amortized; "
            f"first reset {r['first_reset_seconds_per_env'] * 1e3:.1f} ms per env"
        )
    return out + _robot_seconds_lines(results)


def _robot_seconds_lines(results: list[dict]) -> list[str]:
    """Simulated robot-seconds per core-second: (a)-(c) at N >= 1024 on 1 thread, and
    each (e) pair."""
    out = []
    for n in sorted({r["n"] for r in results if r["n"] >= 1024}):
        rows = {r["mode"]: r for r in results if r["n"] == n and r["threads"] == 1}
        shown = [m for m in "bca" if m in rows]
        if shown:
            figures = ", ".join(
                f"({m}) {rows[m]['robot_seconds_per_core_second']:.2f}" for m in shown
            )
            out.append(
                f"robot-seconds per core-second at N={n}, 1 thread: {figures} "
                f"(control period {_period(rows[shown[0]])})"
            )
    pairs = {}
    for r in results:
        if r["mode"] == "e":
            pairs.setdefault((r["terrain"], r["n"], r["threads"]), {})[r["contender"]] = r
    for pair in pairs.values():
        ours, theirs = pair["rwalk"], pair["envpool"]
        out.append(
            f"(e) {ours['terrain']}, N={ours['n']}, {ours['threads']} thread(s), alternating: "
            f"rwalk {ours['task']} {ours['robot_seconds_per_core_second']:.2f} vs EnvPool "
            f"{theirs['task']} {theirs['robot_seconds_per_core_second']:.2f} robot-seconds per "
            f"core-second: {ours['ratio_to_envpool']:.2f}x; memory per env "
            f"{ours['memory_per_env_mb']:.2f} vs {theirs['memory_per_env_mb']:.1f} MB"
            + (
                " (EnvPool's memory keeps N below 1024 here: rwalk's N >= 1024 figure is (b)'s)"
                if ours["n"] < 1024
                else ""
            )
        )
    return out


def plot(results: list[dict], path: Path) -> None:
    """Physics steps/s against N of (a)-(c) per thread count, (d) as points; a PNG at path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    for mode in "abc":
        for t in sorted({r["threads"] for r in results}):
            rows = sorted(
                (r for r in results if r["mode"] == mode and r["threads"] == t),
                key=lambda r: r["n"],
            )
            if rows:
                ax.plot(
                    [r["n"] for r in rows], [r["physics_steps_per_s"] for r in rows],
                    marker="o", linestyle="-" if t > 1 else "--",
                    label=f"({mode}) {LABELS[mode]}, {t} thread{'s' if t > 1 else ''}",
                )  # fmt: skip
    for r in results:
        if r["mode"] == "d":
            kind = "Async" if r["threads"] > 1 else "Sync"
            ax.scatter([r["n"]], [r["physics_steps_per_s"]], marker="x", s=60, color="k")
            ax.annotate(f"(d) {kind}VectorEnv", (r["n"], r["physics_steps_per_s"]), fontsize=7)
    ax.set(xscale="log", xlabel="N (envs)", ylabel="physics steps / s (settling included)")
    ax.set_title("Throughput beside the raw mujoco.rollout floor (world_train)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
