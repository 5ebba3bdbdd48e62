"""The robustness benchmark's conditions, rows, floors, table and plot (``rwalk-robustness``).

Every row of a condition runs the same --episodes paired episodes: episode i
starts like a single env seeded --seed + i, with the same drawn physics and the
same kicks, whichever policy walks. Conditions (CONDITIONS; the training's
ranges are in ``rwalk.randomization`` and ``rwalk.levels``):

- nominal: the evaluation of docs/results.md (rough world at scale 1.0, nothing randomised);
- new maps: terrain-levels maps from fresh seeds, at --map-level;
- rougher: rough tiles 1.3 x the training's roughest (9.1 cm peak to peak), fresh seed;
- low / high friction: 0.3 and 2.0 (training 0.5-1.3);
- payload: +0.2 kg on the torso (training up to +0.12);
- weak servos: gain and torque limit x 0.7 (training 0.85-1.15; the residual default 0.75-1.15);
- pushes: 0.3 m/s kicks (0.24 N·s on the 0.8 kg robot) every 2 s (training up to 0.15 m/s);
- latency: servo targets 4 substeps (16 ms) late (training up to 2; the residual default 3).

Policies are evaluated without observation noise. Prints one table per
condition with each row's speed error split into its bias and ripple and each
policy's floors (``floors``: held out, falls <= 1/4 of the base gait's and <= 3%,
velocity error <= 1/2 of the base gait's and <= 0.03 m/s, |bias| <= 0.01 m/s;
nominal: falls <= 2%, error <= 0.02 m/s, |bias| <= 0.005 m/s), writes every row to
--json and, with --plot, a bar chart.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from rwalk import presets
from rwalk.config import EnvConfig
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.evaluation import (
    Evaluation,
    fall_interval,
    first_episodes,
    load_policy,
    read_results,
    summarise,
    task_of,
    trained_env,
)
from rwalk.levels import TerrainLevels
from rwalk.perturbations import Pushes
from rwalk.randomization import Randomization

#: Seed of the held-out maps (training uses TerrainLevels' default seed 0).
HELD_OUT_MAP_SEED = 1234
#: Settling on a map's pad: the training's (500 steps of gait would walk off the 0.8 m pad).
MAP_SETTLE_STEPS = 100


def on_map(base: EnvConfig, levels: TerrainLevels) -> EnvConfig:
    """``base``'s episodes on the pads of a terrain-levels map: the pads' start spread,
    and at most MAP_SETTLE_STEPS of settling."""
    return dataclasses.replace(
        base,
        terrain_levels=levels,
        position_noise=presets.PAD_SPREAD,
        settle_steps=min(base.settle_steps, MAP_SETTLE_STEPS),
    )


def _physics(**ranges) -> Callable[[EnvConfig, int], EnvConfig]:
    return lambda base, level: dataclasses.replace(
        base, randomization=Randomization.nominal(**ranges)
    )


#: name -> (what it is, the config from the nominal evaluation's and --map-level).
CONDITIONS: dict[str, tuple[str, Callable[[EnvConfig, int], EnvConfig]]] = {
    "nominal": ("rough world at scale 1.0, nothing randomised", lambda base, level: base),
    "new maps": (
        f"terrain-levels map seed {HELD_OUT_MAP_SEED}, every kind, one level",
        lambda base, level: on_map(
            base, TerrainLevels(seed=HELD_OUT_MAP_SEED, start_level=level, curriculum=False)
        ),
    ),
    "rougher": (
        "rough tiles at 9.1 cm peak to peak (training's top: 7 cm)",
        lambda base, level: on_map(
            base,
            TerrainLevels(
                seed=HELD_OUT_MAP_SEED + 1,
                kinds=("rough",),
                roughness=0.091,
                start_level=TerrainLevels().levels - 1,
                curriculum=False,
            ),
        ),
    ),
    "low friction": ("friction 0.3 (training 0.5-1.3)", _physics(friction=(0.3, 0.3))),
    "high friction": ("friction 2.0 (training 0.5-1.3)", _physics(friction=(2.0, 2.0))),
    "payload": ("+0.2 kg on the torso (training -0.05..+0.12)", _physics(payload=(0.2, 0.2))),
    "weak servos": (
        "servo gain and torque limit x 0.7 (training 0.85-1.15; the residual default 0.75-1.15)",
        _physics(kp_scale=(0.7, 0.7), force_scale=(0.7, 0.7)),
    ),
    "pushes": (
        "0.3 m/s kicks (0.24 N·s) every 2 s (training up to 0.15 m/s every 2-5 s)",
        lambda base, level: dataclasses.replace(
            base, pushes=Pushes(speed=(0.3, 0.3), interval=(2.0, 2.0))
        ),
    ),
    "latency": (
        "servo targets 16 ms late (training up to 8 ms; the residual default up to 12 ms)",
        _physics(latency=(4, 4)),
    ),
}


@dataclasses.dataclass(frozen=True)
class Row:
    condition: str
    policy: str
    evaluation: Evaluation


def read_rows(path: Path) -> list[Row]:
    """The rows of a written --json, read as data (``evaluation.read_results``), each
    checked.

    Raises:
        ValueError: naming the file and what is wrong.
    """
    data = read_results(path)
    rows = data.get("rows") if isinstance(data, dict) else None
    if not isinstance(rows, list) or len(rows) > 10_000:
        raise ValueError(f'{str(path)!r} has no list "rows" (of at most 10000)')
    out = []
    for i, row in enumerate(rows):
        if not (isinstance(row, dict) and all(isinstance(row.get(k), str) and len(row[k]) <= 200
                                              for k in ("condition", "policy"))):  # fmt: skip
            raise ValueError(f"{str(path)!r}: row {i} needs the texts condition and policy")
        try:
            out.append(
                Row(row["condition"], row["policy"], Evaluation.from_json(row.get("evaluation")))
            )
        except ValueError as error:
            raise ValueError(f"{str(path)!r}: row {i}: {error}") from None
    return out


def condition_config(
    name: str,
    map_level: int = 6,
    max_steps: int = presets.EVALUATION.max_episode_steps,
    settle_steps: int = presets.EVALUATION.settle_steps,
    trained: EnvConfig | None = None,
) -> EnvConfig:
    """The episodes of condition ``name`` for a policy trained in ``trained`` (its record's
    env; None: the residual task's defaults, the base gait's), the evaluation's:
    ``max_steps`` long after ``settle_steps`` of settling (on a map at most
    MAP_SETTLE_STEPS).

    Raises:
        ValueError: an unknown condition (listing them), or a level outside the map.
    """
    if name not in CONDITIONS:
        raise ValueError(f"unknown condition {name!r}; choose from {tuple(CONDITIONS)}")
    # Every episode's target is the gait's speed, offered as the piece ``command`` too: a
    # policy trained with commands reads it, the others do not (the same episodes).
    speed = EnvConfig().expected_velocity
    base = presets.evaluation_env(
        trained or EnvConfig(), max_episode_steps=max_steps, settle_steps=settle_steps,
        command_range=(speed, speed),
    )  # fmt: skip
    return CONDITIONS[name][1](base, map_level)


def run_condition(
    name: str,
    policies: dict[str, Path | None],
    episodes: int,
    seed: int,
    config: Callable[..., EnvConfig],
    by_kind: bool = False,
) -> list[Row]:
    """Every policy (None: the base gait, on the residual task) on the same paired episodes
    of one condition, each on an env its policy acts in (``config(trained=its record's
    env)``): an adaptive and a residual policy meet the same terrain, physics draws and
    kicks from the same starts. With ``by_kind``, on a map of several kinds of tile, after
    the condition's rows one more per kind and policy, condition ``"NAME: KIND"``: the
    same episodes, those of the envs on that kind (env i walks kind i mod the kinds)."""
    envs: dict[tuple[str, EnvConfig], BatchedEnv] = {}
    rows: list[Row] = []
    by_name: dict[str, list[Row]] = {}  # the rows of each kind, every policy's in turn
    for label, checkpoint in policies.items():
        key = (task_of(checkpoint), config(trained=trained_env(checkpoint)))
        if key not in envs:
            envs[key] = BatchedEnv(episodes, key[1], seed=seed, task=key[0])
        env = envs[key]
        policy = None if checkpoint is None else load_policy(checkpoint, env)
        run = first_episodes(env, seed, policy)
        rows.append(Row(name, label, summarise(label, env, run)))
        levels = key[1].terrain_levels
        if by_kind and levels is not None and len(levels.kinds) > 1:
            kind = env.core.curriculum.terrain_kind
            for index, kind_name in enumerate(levels.kinds):
                on = kind == index
                if bool(on.any()):
                    row = Row(f"{name}: {kind_name}", label, summarise(label, env, run, on))
                    by_name.setdefault(row.condition, []).append(row)
    return rows + [row for kind_rows in by_name.values() for row in kind_rows]


#: The floors of a policy: nominal (falls, per-step error, |bias|), and on a held-out
#: condition (falls, error, |bias|, and falls and error as shares of the base gait's).
NOMINAL_FLOORS = (0.02, 0.02, 0.005)
HELD_OUT_FLOORS = (0.03, 0.03, 0.01)
BASE_SHARES = (0.25, 0.5)


def floors(rows: list[Row]) -> dict[str, str]:
    """Each policy's verdict on its condition's floors (the base gait's row is the reference):
    nominal, falls <= 2%, per-step error <= 0.02 m/s, |bias| <= 0.005 m/s; held out, falls
    <= 3% and <= 1/4 of the base gait's, error <= 0.03 m/s and <= 1/2 of the base gait's,
    |bias| <= 0.01 m/s. An evaluation without a bias (older JSON) is judged without it."""
    base = next(r.evaluation for r in rows if r.policy == "base gait")
    verdicts = {}
    for row in rows:
        if row.policy == "base gait":
            continue
        e = row.evaluation
        nominal = row.condition == "nominal"
        falls, error, bias = NOMINAL_FLOORS if nominal else HELD_OUT_FLOORS
        ok = e.fall_rate <= falls and e.velocity_error <= error and not abs(e.velocity_bias) > bias
        if not nominal:
            ok = ok and e.fall_rate <= base.fall_rate * BASE_SHARES[0]
            ok = ok and e.velocity_error <= base.velocity_error * BASE_SHARES[1]
        verdicts[row.policy] = "met" if ok else "missed"
    return verdicts


def table(rows: list[Row]) -> str:
    verdicts = {}
    for condition in dict.fromkeys(r.condition for r in rows):
        verdicts |= {
            (condition, p): v
            for p, v in floors([r for r in rows if r.condition == condition]).items()
        }
    lines = [
        "| condition | policy | falls (95% interval) | forward velocity (m/s) "
        "| velocity error (m/s) | bias (m/s) | ripple (m/s) | floors |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        e = r.evaluation
        low, high = fall_interval(e)
        lines.append(
            f"| {r.condition} | {r.policy} | {e.fall_rate:.0%} ({low:.0%}–{high:.0%}) | "
            f"{e.forward_velocity:.3f} | "
            f"{e.velocity_error:.4f} ± {1.96 * e.velocity_error_se:.4f} | "
            f"{e.velocity_bias:+.4f} | {e.velocity_ripple:.4f} | "
            f"{verdicts.get((r.condition, r.policy), '-')} |"
        )
    return "\n".join(lines)


def plot(rows: list[Row], path: Path) -> None:
    """Falls and velocity error per condition, one bar per policy."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    conditions = list(dict.fromkeys(r.condition for r in rows))
    policies = list(dict.fromkeys(r.policy for r in rows))
    width = 0.8 / len(policies)
    x = np.arange(len(conditions))
    fig, axes = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True)
    for i, policy in enumerate(policies):
        by = {r.condition: r.evaluation for r in rows if r.policy == policy}
        falls = [100 * by[c].fall_rate for c in conditions]
        error = [by[c].velocity_error for c in conditions]
        se = [1.96 * by[c].velocity_error_se for c in conditions]
        axes[0].bar(x + i * width, falls, width, label=policy)
        axes[1].bar(x + i * width, error, width, yerr=se, capsize=2, label=policy)
    axes[0].set_ylabel("falls (% of episodes)")
    axes[1].set_ylabel("velocity error (m/s)")
    axes[1].set_xticks(x + width * (len(policies) - 1) / 2, conditions, rotation=20)
    axes[0].legend()
    for ax in axes:
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle("Robustness: paired episodes per condition (95% interval on the error)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
