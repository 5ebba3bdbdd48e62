"""Physics fidelity: candidate physics settings against a fine reference simulation.

    rwalk-fidelity --json docs/physics.json --plot docs/physics.png        # the full table
    rwalk-fidelity --checkpoint logs/rwalk/model_149.pt --json policy.json  # + a policy
    rwalk-fidelity --robots 32 --seconds 2 --only reference,4ms            # a quick look

Every candidate keeps the 50 Hz control rate (decimation = 20 ms / timestep) and
differs from the reference only in the settings that cost time: timestep, solver
iterations, friction cone, foot contact dimensionality and softness. For each one,
``--robots`` robots walk ``--seconds`` on flat and on rough ground (the base
gait from standing, as in ``docs/base_gait.md``; with ``--checkpoint`` also the
policy's closed loop after 2 s of settling), and the figures of
``rwalk.analysis.WalkReport`` are compared with the reference's.

Faithful: every metric's difference from the reference lies within the
reference's own seed-to-seed noise, 1.96·√2 standard errors of its mean over the
robots (the 95% band of the difference between two reference runs with
independent starts; a second reference run with other seeds shows it), never
narrower than the precision the docs quote (``RESOLUTION``: on flat ground all
robots walk one limit cycle and the seed noise is ~0). The cost
is simulated robot-seconds per core-second at ``--cost-envs`` envs on one thread
on the rough world, every candidate timed in alternating rounds in one process.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from rwalk.analysis import WalkReport, walk
from rwalk.cli import POSITIVE_FLOAT, POSITIVE_INT, command
from rwalk.core import ResidualWalkCore
from rwalk.physics import Physics
from rwalk.presets import base_gait_config

PROG = command("rwalk.runners.fidelity")
WORLDS = {"flat": "model/world_flat.xml", "rough": "model/world_train.xml"}

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


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--robots", type=POSITIVE_INT, default=256, help="robots per run")
    parser.add_argument("--seconds", type=POSITIVE_FLOAT, default=20.0, help="simulated time")
    parser.add_argument(
        "--only", type=_names, default=list(CANDIDATES), help="comma-separated candidates"
    )
    parser.add_argument("--worlds", type=_worlds, default=list(WORLDS), help="flat,rough")
    parser.add_argument("--checkpoint", type=Path, help="also run this policy's closed loop")
    parser.add_argument(
        "--policy-only", action="store_true", help="with --checkpoint: skip the base gait"
    )
    parser.add_argument("--cost-envs", type=POSITIVE_INT, default=256, help="envs in cost timing")
    parser.add_argument("--cost-rounds", type=POSITIVE_INT, default=3, help="alternating rounds")
    parser.add_argument("--cost-window", type=POSITIVE_FLOAT, default=1.0, help="seconds a turn")
    parser.add_argument("--json", type=Path, help="save the results here")
    parser.add_argument("--plot", type=Path, help="save the cost-vs-fidelity PNG here")
    args = parser.parse_args(argv)
    if "reference" not in args.only:
        args.only = ["reference", *args.only]
    if args.checkpoint is not None and not args.checkpoint.is_file():
        parser.error(f"--checkpoint {str(args.checkpoint)!r} is not a file")
    if args.policy_only and args.checkpoint is None:
        parser.error("--policy-only needs --checkpoint")
    return args


def _names(text: str) -> list[str]:
    names = [name for name in text.split(",") if name]
    unknown = [name for name in names if name not in CANDIDATES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"unknown candidate(s) {unknown or text!r}; known: {', '.join(CANDIDATES)}"
        )
    return names


def _worlds(text: str) -> list[str]:
    names = [name for name in text.split(",") if name]
    if not names or any(name not in WORLDS for name in names):
        raise argparse.ArgumentTypeError(f"worlds are {', '.join(WORLDS)}, got {text!r}")
    return names


def fidelity(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    steps = max(1, round(args.seconds / 0.02))
    cases = [] if args.policy_only else [(world, None) for world in args.worlds]
    if args.checkpoint is not None:
        cases += [(f"{world} policy", policy_loader(args.checkpoint)) for world in args.worlds]
    results: dict = {"robots": args.robots, "seconds": steps * 0.02, "cases": {}, "cost": {}}
    for case, policy in cases:
        world = case.split(" ")[0]
        rows = results["cases"][case] = {}
        runs = [(name, 0) for name in args.only] + [("reference", SECOND_SEED)]
        for name, seed in runs:
            label = name if seed == 0 else f"{name} (seed {seed})"
            start = time.perf_counter()
            metrics = run_case(CANDIDATES[name], world, args.robots, steps, seed, policy)
            rows[label] = {"metrics": metrics, "physics": dataclasses.asdict(CANDIDATES[name])}
            print(f"{case:>12} {label:>28}: {time.perf_counter() - start:6.1f} s", flush=True)
        reference = rows["reference"]["metrics"]
        for label, row in rows.items():
            if label != "reference":
                row["deviation"] = faithful(row["metrics"], reference)
    results["cost"] = measure_costs(args.only, args.cost_envs, args.cost_rounds, args.cost_window)
    print(table(results))
    if args.json is not None:
        from rwalk.rl.checkpoints import atomic_write_text

        atomic_write_text(args.json, json.dumps(results, indent=1))
    if args.plot is not None:
        plot(results, args.plot)
    return results


def main(argv: list[str] | None = None) -> None:
    fidelity(argv)


if __name__ == "__main__":
    main()
