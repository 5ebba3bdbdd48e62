"""An adaptive and a residual policy against the base gait, and the adaptive policy's gait
by terrain (docs/adaptive.md; ``rwalk-adaptive-report`` is the command line).

Every row runs the same paired episodes (episode i starts like a single env seeded
seed + i). ``compare`` runs (a) flat ground (the rough world at scale 0), where the
cost of transport compares the gaits' effort, (b) the nominal evaluation (the rough
world at scale 1.0, robustness's "nominal") and (c) each of ``SPEEDS`` commanded on
it. The speed is each episode's target velocity, which the reward and the velocity
error track; only a policy trained with commands reads it (asked for the gait's speed
in (a) and (b)); the base gait and a residual policy walk as they do.

``gait_by_terrain`` puts the adaptive policy on every kind of tile (flat, rough,
slopes, steps, stones) of a held-out terrain-levels map at every level and reports
the mean and spread of each gait parameter it commands, and of how high its feet rise
above the ground under them in each swing (residuals included); ``adaptation`` checks the
step height on rough and step tiles at the upper levels against flat ground.
``gait_at_speeds`` reports the same quantities asked for each of ``SPEEDS`` on the
nominal world: which parameters a commanded policy moves to change its speed, and
whether one of them sits at its bound.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch

from rwalk import episodes, presets
from rwalk.config import EnvConfig
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.evaluation import (
    Evaluation,
    Policy,
    commanded,
    evaluate,
    evaluation_config,
    load_policy,
    trained_env,
)
from rwalk.levels import TerrainLevels
from rwalk.observations import HEIGHT_OFFSETS, foot_clearances
from rwalk.robustness import HELD_OUT_MAP_SEED, on_map
from rwalk.tasks.adaptive_gait import ADAPTED

#: What the gait statistics hold, in order: the commanded parameters, then each swing's
#: peak: the highest the foot's bottom rose above the ground under it in that swing
#: (what the step height and the residuals together gave). SI units.
MEASURED = (*ADAPTED, "swing_peak")
#: Each quantity's label, scale and unit in the tables and the figure.
LABELS = {
    "step_height": ("step height", 1000, "mm"), "step_length": ("step length", 1000, "mm"),
    "cycle_time": ("cycle time", 1, "s"), "body_height": ("body height", 1000, "mm"),
    "swing_peak": ("swing peak above ground", 1000, "mm"),
}  # fmt: skip
#: Commanded speeds of the rows (c). m/s.
SPEEDS = (0.05, 0.10, 0.15, 0.20, 0.25)
#: The kinds of tile ``gait_by_terrain`` walks on, flat first.
TERRAIN_KINDS = ("flat", "rough", "slopes", "steps", "stones")
#: Steps of each episode of ``gait_by_terrain`` (10 s at 50 Hz).
GAIT_STEPS = 500
#: Steps at the start of each episode left out of the gait statistics: the policy moves
#: the parameters away from the starting gait within a second.
SKIP_STEPS = 50
#: Kinds and lowest level of ``adaptation``'s hard ground, and its floor: the step height
#: there over that on flat ground.
HARD_KINDS = ("rough", "steps")
HARD_FROM_LEVEL = 5
ADAPTATION_FLOOR = 1.5


def run_row(name, checkpoint, episodes, seed, scale, command=None, **lengths) -> Evaluation:
    """One row: the base gait (checkpoint None) or a policy, on ``episodes`` paired episodes
    of the rough world at ``scale``, asked for ``command`` m/s (None: a commanded policy is
    asked for the gait's speed). ``lengths``: max_steps, settle_steps (the spec's
    evaluation's by default)."""
    if command is None and commanded(checkpoint):
        command = EnvConfig().expected_velocity
    steps = {"max_episode_steps": lengths["max_steps"]} if "max_steps" in lengths else {}
    if "settle_steps" in lengths:
        steps["settle_steps"] = lengths["settle_steps"]
    config = evaluation_config(
        checkpoint, terrain_scale=scale, **steps,
        command_range=None if command is None else (command, command),
    )  # fmt: skip
    env = BatchedEnv(episodes, config, seed=seed)
    policy = None if checkpoint is None else load_policy(checkpoint, env)
    row = evaluate(name, env, seed, policy)
    asked = "-" if command is None else f"{command:.3f}"
    return dataclasses.replace(row, name=f"{name} | {scale:g} | {asked}")


def compare(
    policies: dict[str, Path | None], episodes: int, seed: int, scale: float = 1.0, **lengths
) -> dict[str, list[Evaluation]]:
    """Rows (a) on flat ground, (b) at ``scale`` and (c) at each of ``SPEEDS`` at ``scale``,
    each a row per policy (name -> checkpoint; None = the base gait). ``lengths``: as
    ``run_row``'s."""
    out = {}
    for label, terrain in (("a", 0.0), ("b", scale)):
        out[label] = [
            run_row(n, c, episodes, seed, terrain, **lengths) for n, c in policies.items()
        ]
    out["c"] = [
        run_row(n, c, episodes, seed, scale, speed, **lengths)
        for speed in SPEEDS
        for n, c in policies.items()
    ]
    return out


@dataclass(frozen=True)
class GaitStats:
    """The gait of one kind of tile at one level, over its episodes (``MEASURED``)."""

    kind: str
    level: int
    episodes: int
    fall_rate: float
    mean: tuple[float, ...]
    """Per quantity (``MEASURED`` order; rows of reports older than the swing peak hold
    only ``ADAPTED``'s): mean over episodes of each episode's mean."""
    interval: tuple[float, ...]
    """Per quantity: half-width of the 95% interval of ``mean`` (1.96 standard errors
    over episodes)."""
    spread: tuple[float, ...]
    """Per quantity: standard deviation over every sample (step, or swing) of every
    episode."""


def gait_by_terrain(
    checkpoint: Path,
    episodes: int,
    seed: int,
    steps: int = GAIT_STEPS,
    levels: TerrainLevels | None = None,
) -> list[GaitStats]:
    """The adaptive policy's gait on each of ``TERRAIN_KINDS`` at each level of a held-out
    map (``levels``: default ``TerrainLevels(seed=HELD_OUT_MAP_SEED)``'s), ``episodes``
    paired episodes each, ``steps`` long; the first SKIP_STEPS of each are left out. A
    commanded policy is asked for the gait's speed."""
    return walk_levels(
        lambda env: load_policy(checkpoint, env), trained_env(checkpoint),
        commanded(checkpoint), episodes, seed, steps, levels,
    )  # fmt: skip


def walk_levels(
    policy_for: Callable[[BatchedEnv], Policy],
    trained: EnvConfig,
    asked: bool,
    episodes: int,
    seed: int,
    steps: int,
    levels: TerrainLevels | None = None,
) -> list[GaitStats]:
    """``gait_by_terrain`` of the policy that ``policy_for`` builds on each level's env (the
    evaluation env of a policy trained in ``trained``, an adaptive task's config; asked
    for the gait's speed if ``asked``)."""
    levels = levels or TerrainLevels(seed=HELD_OUT_MAP_SEED)
    speed = EnvConfig().expected_velocity
    kinds = len(TERRAIN_KINDS)
    out = []
    for level in range(levels.levels):
        base = presets.evaluation_env(trained, max_episode_steps=steps,
                                      command_range=(speed, speed) if asked else None)  # fmt: skip
        config = on_map(base, dataclasses.replace(
            levels, kinds=TERRAIN_KINDS, start_level=level, curriculum=False))  # fmt: skip
        env = BatchedEnv(episodes * kinds, config, seed=seed)
        walked = _walk(env, policy_for(env), seed, steps)
        for k, kind in enumerate(TERRAIN_KINDS):
            out.append(_stats(kind, level, walked, slice(k, None, kinds)))  # env i: kind i % kinds
    return out


def gait_at_speeds(
    checkpoint: Path, episodes: int, seed: int, steps: int = GAIT_STEPS, scale: float = 1.0
) -> list[GaitStats]:
    """A commanded adaptive policy's gait asked for each of ``SPEEDS`` (``walk_speeds``)."""
    return walk_speeds(lambda env: load_policy(checkpoint, env), trained_env(checkpoint),
                       episodes, seed, steps, scale)  # fmt: skip


def walk_speeds(
    policy_for: Callable[[BatchedEnv], Policy],
    trained: EnvConfig,
    episodes: int,
    seed: int,
    steps: int = GAIT_STEPS,
    scale: float = 1.0,
) -> list[GaitStats]:
    """The gait (``MEASURED``) of the policy that ``policy_for`` builds, asked for each of
    ``SPEEDS`` on ``episodes`` paired episodes of the rough world at ``scale`` (1.0:
    robustness's "nominal"), ``steps`` long, the first SKIP_STEPS left out: a row per
    speed, its kind the speed asked ("0.05 m/s") and its level 0 (the world has none)."""
    out = []
    for speed in SPEEDS:
        config = presets.evaluation_env(trained, terrain_scale=scale, max_episode_steps=steps,
                                        command_range=(speed, speed))  # fmt: skip
        env = BatchedEnv(episodes, config, seed=seed)
        out.append(_stats(f"{speed:g} m/s", 0, _walk(env, policy_for(env), seed, steps)))
    return out


def _stats(kind: str, level: int, walked, rows: slice = slice(None)) -> GaitStats:
    """The ``GaitStats`` of the envs ``rows`` of one ``_walk``."""
    sums, squares, counts, fell = (t[rows] for t in walked)
    episodes = len(fell)
    n = counts.clamp(min=1)
    per_episode = sums / n
    pooled_mean = sums.sum(0) / n.sum(0)
    pooled_var = squares.sum(0) / n.sum(0) - pooled_mean**2
    sd = per_episode.std(0) if episodes > 1 else torch.zeros(len(MEASURED))
    return GaitStats(
        kind=kind, level=level, episodes=episodes,
        fall_rate=float(fell.double().mean()),
        mean=tuple(per_episode.mean(0).tolist()),
        interval=tuple((1.96 * sd / math.sqrt(episodes)).tolist()),
        spread=tuple(pooled_var.clamp(min=0).sqrt().tolist()),
    )  # fmt: skip


def _walk(env: BatchedEnv, policy, seed: int, steps: int):
    """One episode per env: per env and ``MEASURED`` quantity, the sum and sum of squares of
    its samples after SKIP_STEPS until the episode ended (the parameters each step, the
    peak of each swing that ended), their count, and whether the env fell."""
    core = env.core
    env.set_seed(seed)
    core.reset()
    policy.reset()
    n, m = core.num_envs, len(ADAPTED)
    sums = torch.zeros(n, len(MEASURED), dtype=torch.float64)
    squares = torch.zeros_like(sums)
    counts = torch.zeros_like(sums)
    ended = torch.zeros(n, dtype=torch.bool)
    fell = torch.zeros(n, dtype=torch.bool)
    radius = core.world.geometry.foot_radius
    in_swing = torch.zeros(n, 4, dtype=torch.bool)
    peak = torch.zeros(n, 4, dtype=torch.float64)
    with torch.inference_mode():
        for step in range(steps):
            _, end = episodes.step(core, policy(), auto_reset=False)
            swing = core.controller.swing_at(core.task.sensed_phase)
            under = foot_clearances(core.obs, core.terrain).view(n, 4, len(HEIGHT_OFFSETS))
            height = under[..., 0] - radius
            if step >= SKIP_STEPS:
                live = (~ended).double().unsqueeze(-1)
                params = core.task.params
                sums[:, :m] += params * live
                squares[:, :m] += params * params * live
                counts[:, :m] += live
                landed = (in_swing & ~swing).double() * live  # swings that ended this step
                sums[:, m] += (peak * landed).sum(-1)
                squares[:, m] += (peak * peak * landed).sum(-1)
                counts[:, m] += landed.sum(-1)
            peak = torch.where(in_swing & swing, torch.maximum(peak, height), height)
            in_swing = swing
            if end is not None:
                fresh = end.ids[~ended[end.ids]]
                fell[fresh] = end.stats["terminated"][~ended[end.ids]].bool()
                ended[end.ids] = True
            if bool(ended.all()):
                break
    return sums, squares, counts, fell


def adaptation(stats: list[GaitStats]) -> dict:
    """Step height on HARD_KINDS tiles at levels >= HARD_FROM_LEVEL against flat ground (all
    levels): the means over their episodes, 95% intervals, the ratio, and whether it meets
    ADAPTATION_FLOOR with intervals that do not overlap."""

    def pooled(rows: list[GaitStats]) -> tuple[float, float]:
        # Equal episodes per row: the mean of row means, the interval of their pooled sample.
        mean = sum(r.mean[0] for r in rows) / len(rows)
        se2 = sum((r.interval[0] / 1.96) ** 2 for r in rows) / len(rows) ** 2
        return mean, 1.96 * math.sqrt(se2)

    hard = pooled([r for r in stats if r.kind in HARD_KINDS and r.level >= HARD_FROM_LEVEL])
    flat = pooled([r for r in stats if r.kind == "flat"])
    ratio = hard[0] / flat[0]
    apart = hard[0] - hard[1] > flat[0] + flat[1]
    return {
        "hard": hard, "flat": flat, "ratio": ratio,
        "met": ratio >= ADAPTATION_FLOOR and apart,
    }  # fmt: skip


def gait_table(stats: list[GaitStats]) -> str:
    """Mean ± 95% interval (spread) of each quantity (``MEASURED``) per kind and level, as
    Markdown; "-" where an older report's row lacks it."""
    lines = [
        "| kind | level | falls | "
        + " | ".join(f"{LABELS[p][0]} ({LABELS[p][2]})" for p in MEASURED)
        + " |",
        "| --- | --- | --- |" + " --- |" * len(MEASURED),
    ]
    for r in stats:
        cells = []
        for i, p in enumerate(MEASURED):
            u = LABELS[p][1]
            digits = 1 if u > 1 else 3
            cells.append("-" if i >= len(r.mean) else
                         f"{r.mean[i] * u:.{digits}f} ± {r.interval[i] * u:.{digits}f} "
                         f"({r.spread[i] * u:.{digits}f})")  # fmt: skip
        lines.append(f"| {r.kind} | {r.level} | {r.fall_rate:.0%} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot_levels(stats: list[GaitStats], path: Path) -> None:
    """Each quantity (``MEASURED``, those every row holds) against the terrain level, one
    line per kind with its 95% intervals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = [p for i, p in enumerate(MEASURED) if all(i < len(r.mean) for r in stats)]
    fig, axes = plt.subplots(2, 3, figsize=(14, 7), sharex=True)
    for ax in axes.flat[len(shown) :]:
        ax.set_visible(False)
    for ax, (i, name) in zip(axes.flat, enumerate(shown), strict=False):  # shown: a prefix
        label, scale, unit = LABELS[name]
        for kind in TERRAIN_KINDS:
            rows = [r for r in stats if r.kind == kind]
            ax.errorbar([r.level for r in rows], [r.mean[i] * scale for r in rows],
                        yerr=[r.interval[i] * scale for r in rows], capsize=2, marker="o",
                        markersize=3, label=kind)  # fmt: skip
        ax.set_title(f"{label} ({unit})")
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("terrain level (0 flat .. 9 hardest)")
        ax.xaxis.set_tick_params(labelbottom=True)
    axes[0, 0].legend()
    fig.suptitle(
        "Adaptive policy: its gait by kind of tile and level (held-out map, 95% intervals)"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def table(rows: list[Evaluation]) -> str:
    """The rows as a Markdown table (each row's name holds its policy, terrain and command)."""
    lines = [
        "| policy | terrain | commanded (m/s) | fall rate | forward velocity (m/s) "
        "| velocity error (m/s) | servo power (W) | cost of transport |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        lines.append(
            f"| {r.name} | {r.fall_rate:.0%} | {r.forward_velocity:.3f} | "
            f"{r.velocity_error:.4f} ± {r.velocity_error_se * 1.96:.4f} | {r.power:.2f} | "
            f"{r.cost_of_transport:.2f} |"
        )
    return "\n".join(lines)
