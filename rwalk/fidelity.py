"""Physics fidelity: candidate physics settings against a fine reference simulation.

Every candidate (``CANDIDATES``) keeps the 50 Hz control rate (decimation =
20 ms / timestep) and differs from the reference only in the settings that cost
time: timestep, solver iterations, friction cone, foot contact dimensionality
and softness. ``run_cases`` walks robots on flat and rough ground (the base gait
from standing, as in ``docs/base_gait.md``; with a checkpoint also the policy's
closed loop after 2 s of settling) and compares the figures of
``rwalk.analysis.WalkReport`` with the reference's.

Faithful: every metric's difference from the reference lies within the
reference's own seed-to-seed noise, 1.96·√2 standard errors of its mean over the
robots (the 95% band of the difference between two reference runs with
independent starts; a second reference run with other seeds shows it), never
narrower than the precision the docs quote (``RESOLUTION``: on flat ground all
robots walk one limit cycle and the seed noise is ~0). The cost
(``measure_costs``) is simulated robot-seconds per core-second on one thread on
the rough world, every candidate timed in alternating rounds in one process.
``rwalk-fidelity`` (``rwalk.runners.fidelity``) is the command line.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from rwalk.analysis import WalkReport, walk
from rwalk.core import ResidualWalkCore
from rwalk.physics import Physics
from rwalk.presets import BASE_GAIT_WORLDS, base_gait_config

#: The worlds walked on, by name: the base-gait check's.
WORLDS = BASE_GAIT_WORLDS
#: Seconds per env step: the 50 Hz control rate every candidate keeps.
CONTROL_DT = 0.02

_MODEL = {"cone": "elliptic", "solver": "Newton", "integrator": "implicitfast",
          "foot_condim": 4, "foot_solref": (0.008, 1.0)}  # fmt: skip
_DEFAULT_SOLVER = {"iterations": 100, "ls_iterations": 50, "tolerance": 1e-8}
_FINE = {"iterations": 100, "ls_iterations": 50, "tolerance": 1e-10}


def _physics(timestep: float, **changes) -> Physics:
    return Physics(**{**_MODEL, **_DEFAULT_SOLVER, "timestep": timestep, **changes})


#: The reference and the candidates; each sets every field, so none depends on the world
#: file. The model's contact (elliptic cones, condim 4, 8 ms foot time constant) is the
#: reference's; ``*-solref4`` rows use the 4 ms foot of the model before this change.
CANDIDATES: dict[str, Physics] = {
    "reference": _physics(0.0005, **_FINE),
    "reference-solref4": _physics(0.0005, **_FINE, foot_solref=(0.004, 1.0)),
    "2ms-solref4": _physics(0.002, foot_solref=(0.004, 1.0)),
    "2ms": _physics(0.002),
    "4ms": _physics(0.004),
    "4ms-pyramidal": _physics(0.004, cone="pyramidal"),
    "4ms-condim3": _physics(0.004, foot_condim=3),
    "4ms-it2": _physics(0.004, iterations=2, ls_iterations=4),
    "5ms": _physics(0.005),
    "10ms": _physics(0.01),
}
#: Metrics compared, with how to aggregate each per-robot array.
METRICS = (
    "speed_ratio",
    "fall_rate",
    "heading_change",
    "sideways_drift",
    "velocity_error",
    "foot_error",
    "contact_match",
    "torque",
)
#: The smallest difference each metric is read to (the precision the docs quote): the
#: band never narrows below it. On flat ground every robot walks the same limit cycle
#: up to its heading, so the reference's seed-to-seed noise there is ~0.
RESOLUTION = {
    "speed_ratio": 0.01,
    "fall_rate": 0.01,
    "heading_change": 0.005,
    "sideways_drift": 0.005,
    "velocity_error": 0.002,
    "foot_error": 0.0002,
    "contact_match": 0.01,
    "torque": 0.002,
}
#: Seed of the second reference run: its starts share nothing with seed 0's.
SECOND_SEED = 1_000_003
#: Half-width of the faithful band, in standard errors of the reference's mean.
BAND = 1.96 * math.sqrt(2.0)


def per_robot(report: WalkReport) -> dict[str, np.ndarray]:
    """Per-robot values of each metric (speed ratio over the robots that did not fall)."""
    ok = ~report.fell
    return {
        "speed_ratio": report.speed[ok] / report.expected_velocity,
        "fall_rate": report.fell.astype(np.float64),
        "heading_change": np.abs(report.heading_change),
        "sideways_drift": np.abs(report.sideways_drift),
        "velocity_error": report.velocity_error,
        "foot_error": report.foot_error,
        "contact_match": report.contact_match,
        "torque": report.torque,
    }


def mean_and_error(values: np.ndarray) -> tuple[float, float]:
    """Mean and its standard error (nan with fewer than 2 values)."""
    if values.size < 2:
        return (float(values.mean()) if values.size else math.nan), math.nan
    return float(values.mean()), float(values.std(ddof=1) / math.sqrt(values.size))


def run_case(physics: Physics, world: str, robots: int, steps: int, seed: int, policy=None):
    """Walk ``robots`` robots ``steps`` env steps; {metric: (mean, standard error)}."""
    config = dataclasses.replace(base_gait_config(WORLDS[world]), physics=physics)
    if policy is None:
        report = walk(ResidualWalkCore(config, robots, seed=seed), steps)
    else:
        config = dataclasses.replace(config, settle_steps=100)
        core, act = policy(config, robots, seed)
        report = walk(core, steps, policy=lambda obs: act())
    return {name: mean_and_error(v) for name, v in per_robot(report).items()}


def policy_loader(checkpoint: Path):
    """(config, robots, seed) -> (core, act) for a trained rsl-rl checkpoint."""

    def load(config, robots: int, seed: int):
        from rwalk.envs.torchrl_env import ResidualWalkVecEnv
        from rwalk.evaluation import load_policy

        vec = ResidualWalkVecEnv(robots, config, seed=seed)
        return vec.core, load_policy(checkpoint, vec)

    return load


def run_cases(
    names: list[str],
    worlds: list[str],
    robots: int,
    steps: int,
    checkpoint: Path | None = None,
    policy_only: bool = False,
    log: Callable[[str], None] | None = None,
) -> dict[str, dict]:
    """Every candidate in ``names`` (and the reference again at ``SECOND_SEED``) in each case.

    The cases are the base gait on each world (``"flat"``, ``"rough"``), then with
    ``checkpoint`` the policy on each (``"flat policy"``, ...).

    Args:
        names: candidates, the reference among them.
        worlds: names of ``WORLDS``.
        robots: robots per run.
        steps: env steps per run.
        checkpoint: an rsl-rl checkpoint whose closed loop is also run; None = none.
        policy_only: with ``checkpoint``, skip the base gait's cases.
        log: called with a line after each run (its wall time); None = silent.

    Returns:
        case -> row label -> {"metrics": {metric: (mean, standard error)}, "physics":
        the candidate's settings, "deviation": ``faithful`` against the reference
        (not in the reference's row)}.
    """
    cases = [] if policy_only else [(world, None) for world in worlds]
    if checkpoint is not None:
        cases += [(f"{world} policy", policy_loader(checkpoint)) for world in worlds]
    results: dict[str, dict] = {}
    for case, policy in cases:
        world = case.split(" ")[0]
        rows = results[case] = {}
        runs = [(name, 0) for name in names] + [("reference", SECOND_SEED)]
        for name, seed in runs:
            label = name if seed == 0 else f"{name} (seed {seed})"
            start = time.perf_counter()
            metrics = run_case(CANDIDATES[name], world, robots, steps, seed, policy)
            rows[label] = {"metrics": metrics, "physics": dataclasses.asdict(CANDIDATES[name])}
            if log is not None:
                log(f"{case:>12} {label:>28}: {time.perf_counter() - start:6.1f} s")
        reference = rows["reference"]["metrics"]
        for label, row in rows.items():
            if label != "reference":
                row["deviation"] = faithful(row["metrics"], reference)
    return results


def faithful(row: dict, reference: dict) -> dict[str, float]:
    """|candidate − reference| / band per metric (<= 1: within the seed-to-seed noise).

    The band is 1.96·√2 standard errors of the reference's mean, at least the
    metric's ``RESOLUTION``."""
    out = {}
    for name in METRICS:
        (value, _), (ref, ref_error) = row[name], reference[name]
        band = max(BAND * ref_error, RESOLUTION[name]) if math.isfinite(ref_error) else math.inf
        out[name] = abs(value - ref) / band if math.isfinite(value) else math.inf
    return out


def measure_costs(names: list[str], envs: int, rounds: int, window: float) -> dict[str, float]:
    """Robot-seconds simulated per core-second on the rough world, 1 thread, alternating."""
    torch.set_num_threads(1)
    cores, zeros = {}, torch.zeros(envs, 12)
    for name in names:
        config = dataclasses.replace(
            base_gait_config(WORLDS["rough"]), physics=CANDIDATES[name], num_threads=1
        )
        cores[name] = ResidualWalkCore(config, envs, seed=0)
        cores[name].reset()
    simulated = dict.fromkeys(names, 0.0)
    spent = dict.fromkeys(names, 0.0)
    for _ in range(rounds):
        for name, core in cores.items():
            start = time.perf_counter()
            while time.perf_counter() - start < window:
                core.step(zeros)
                simulated[name] += envs * core.control_dt
            spent[name] += time.perf_counter() - start
    return {name: simulated[name] / spent[name] for name in names}


def table(results: dict) -> str:
    """Markdown: one row per (case, candidate), mean ± standard error, deviation, cost."""
    head = ["case", "physics", "robot-s / core-s", "faithful", "worst |Δ|/band"]
    lines = ["| " + " | ".join(head + list(METRICS)) + " |", "|" + " --- |" * (len(head) + 8)]
    for case, rows in results["cases"].items():
        for name, row in rows.items():
            deviation = row.get("deviation", {})
            worst = max(deviation.values()) if deviation else 0.0
            cost = results["cost"].get(name.split(" ")[0])
            cells = [
                case,
                name,
                f"{cost:,.0f}" if cost else "—",
                "—" if not deviation else ("yes" if worst <= 1.0 else "no"),
                f"{worst:.2f}" if deviation else "—",
            ]
            cells += [_fmt(row["metrics"][m]) for m in METRICS]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _fmt(pair) -> str:
    mean, error = pair
    return f"{mean:.4g} ± {error:.2g}" if math.isfinite(error) else f"{mean:.4g}"


def plot(results: dict, path: Path) -> None:
    """Cost against the worst normalised deviation, one marker per case and candidate."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for case, rows in results["cases"].items():
        xs, ys, labels = [], [], []
        for name, row in rows.items():
            cost = results["cost"].get(name)
            if not row.get("deviation") or cost is None:
                continue
            xs.append(cost)
            ys.append(min(max(row["deviation"].values()), 10.0))
            labels.append(name)
        ax.scatter(xs, ys, label=case)
        for x, y, label in zip(xs, ys, labels, strict=True):
            ax.annotate(label, (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.axhline(1.0, color="grey", linestyle="--", linewidth=1)
    ax.set_xlabel("simulated robot-seconds per core-second (rough, 1 thread)")
    ax.set_ylabel("worst |Δ| / seed-noise band (clipped at 10)")
    ax.set_title("Physics candidates: cost vs fidelity (≤ 1 is faithful)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    from rwalk.rl.checkpoints import atomic_write

    atomic_write(path, lambda file: fig.savefig(file, format="png", dpi=120))
    plt.close(fig)
