"""The config of a task's envs: world, gait, timing, starts, reward and the world's variations."""

from __future__ import annotations

import math
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, is_dataclass, replace
from typing import Any

from rwalk.commands import CommandCurriculum
from rwalk.constants import EPISODE_STEPS, SETTLE_STEPS
from rwalk.gait import GaitParameters
from rwalk.kinematics import LegGeometry
from rwalk.levels import TerrainLevels
from rwalk.observations import ObservationNoise
from rwalk.perturbations import Pushes
from rwalk.physics import Physics
from rwalk.randomization import Randomization
from rwalk.rewards import GaitCosts, RewardWeights, Shaping

#: Most physics substeps per env step: the controller's targets for a whole control
#: period are computed at once, so this bounds the memory of one step (and of settling).
MAX_DECIMATION = 1000
#: Most env steps of an episode, and of settling (10^6 steps: 5.6 hours at 50 Hz).
MAX_STEPS = 2**31 - 1
MAX_SETTLE_STEPS = 1_000_000
#: Most envs of a core (and entries of a settled-start pool).
MAX_ENVS = 1 << 24
#: Most physics threads.
MAX_THREADS = 1024
#: Longest interval between two command draws (a day). Seconds.
MAX_INTERVAL = 86_400.0
#: Largest commanded speed, either way (the robot walks ~0.1-0.3 m/s). m/s.
MAX_SPEED = 10.0


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


@dataclass(frozen=True)
class EnvConfig:
    """Everything that defines the task. Variants via ``dataclasses.replace``."""

    model_path: str = "model/world_train.xml"
    """MJCF world: a path, or a name of a packaged model such as ``model/world_flat.xml``."""
    gait: GaitParameters = field(default_factory=GaitParameters)
    """The fixed base gait."""
    residual_scale: float = 0.02
    """Metres of foot offset per unit of action."""
    max_episode_steps: int = EPISODE_STEPS
    """Env steps before truncation."""
    settle_steps: int = SETTLE_STEPS
    """Env steps of zero-residual gait run at each reset before the episode starts."""
    control_dt: float | None = 0.02
    """Duration of one env step (0.02 s = 50 Hz control). Seconds. None: decimation
    x the physics timestep."""
    decimation: int | None = None
    """Physics substeps per env step; None derives it from control_dt / timestep
    (5 at the default 4 ms timestep). Given with control_dt, the two must agree."""
    physics: Physics = field(default_factory=Physics)
    """Overrides of the world file's physics settings (none by default)."""
    terrain_scale: float = 1.0
    """Roughness of a heightfield world: 0 flat .. 1 full."""
    randomize: bool = False
    """Perturb each start's position and orientation (the spec's reset option)."""
    start_position: tuple[float, float] = (-3.5, 0.0)
    """Nominal (x, y) of the torso at a start. Metres."""
    position_noise: tuple[float, float] = (0.02, 0.02)
    """Half-widths of the uniform (x, y) perturbation when randomizing. Metres."""
    yaw_noise: float = 0.1
    """Half-width of the uniform yaw perturbation when randomizing. Radians."""
    tilt_noise: float = 0.02
    """Half-width of the uniform roll and pitch perturbations when randomizing. Radians."""
    settle_pool: int = 0
    """Settled starts kept ready for partial resets; 0 settles each resetting env in
    place (the spec's behaviour). A pool is refilled in one batched rollout, so
    resets of a few envs never run small, thread-starved settles."""
    settle_reuse: int = 1
    """Resets each pooled start serves before it is replaced by a fresh settle.
    Every pooled start is an independent settle from its own random start, so
    each reset's state has the same distribution as with in-place settling;
    with reuse > 1 some resets share a start and settling costs 1/reuse."""
    num_threads: int = 0
    """Physics worker threads including the caller's; 0 uses all cores."""
    reward_weights: RewardWeights = field(default_factory=RewardWeights)
    """Weights of the reward terms."""
    costs: GaitCosts | None = None
    """Reward terms beyond the spec's, charging how the robot walks: swing clearance below
    a target, feet slipping, servo power (``rwalk.rewards.GaitCosts``). None: the spec's
    four terms only."""
    shaping: Shaping | None = None
    """Training-only reward terms beside the spec's: a kernel on the speed error and a
    reward for staying up (``rwalk.rewards.Shaping``). None: none (the spec's reward)."""
    command_range: tuple[float, float] | None = None
    """None: the reward tracks the gait's step_length / cycle_time (the spec). (low,
    high): each episode draws its target velocity uniformly from it (m/s), and the
    views expose it as the piece ``command``."""
    command_interval: float | None = None
    """With ``command_range``: seconds between two draws of an env's target velocity within
    an episode (None: one draw per episode, at its start)."""
    command_curriculum: CommandCurriculum | None = None
    """With ``command_range``: draw the commands from its bins that the policy has learned
    to track, starting near the gait's speed (``rwalk.commands``); None: uniformly from
    the whole range from the start."""
    randomization: Randomization | None = None
    """Per-env physics (friction, payload, servo strength, ...) drawn at every reset;
    None: the model's own (the spec's env). See ``rwalk.randomization``."""
    pushes: Pushes | None = None
    """Random horizontal kicks to the torso; None: no kicks."""
    observation_noise: ObservationNoise | None = None
    """Noise on the policy's observation group (never the critic's); None: exact."""
    terrain_levels: TerrainLevels | None = None
    """A map of terrain levels in the world's heightfield (``rwalk.levels``): each env
    starts on the pad of its own tile (its kind, at its level; ``position_noise``
    spreads it there) and, with the map's curriculum, moves between levels at its
    resets. None: the world's own heightfield at ``terrain_scale``."""

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> ValueError:
            return ValueError(f"{type(self).__name__}.{name} {why}, got {getattr(self, name)!r}")

        kinds = (("gait", GaitParameters), ("reward_weights", RewardWeights), ("physics", Physics))
        optional = (
            ("randomization", Randomization), ("pushes", Pushes),
            ("observation_noise", ObservationNoise), ("terrain_levels", TerrainLevels),
            ("costs", GaitCosts), ("shaping", Shaping),
            ("command_curriculum", CommandCurriculum),
        )  # fmt: skip
        for name, kind in kinds + optional:
            if (name, kind) in optional and getattr(self, name) is None:
                continue
            if not isinstance(getattr(self, name), kind):
                raise TypeError(
                    f"EnvConfig.{name} must be a {kind.__name__}, got "
                    f"{type(getattr(self, name)).__name__} {getattr(self, name)!r}"
                )
        for name in ("start_position", "position_noise"):
            value = getattr(self, name)
            if not (
                isinstance(value, tuple)
                and len(value) == 2
                and all(_is_number(v) and math.isfinite(v) for v in value)
            ):
                raise bad(name, "must be a pair of finite numbers (x, y)")
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not math.isfinite(value):
                raise bad(f.name, "must be finite")
        if not self.residual_scale > 0:
            raise bad("residual_scale", "must be > 0")
        integers = (
            ("max_episode_steps", 1, MAX_STEPS),
            ("settle_steps", 0, MAX_SETTLE_STEPS),
            ("decimation", 1, None),
            ("settle_pool", 0, MAX_ENVS),
            ("settle_reuse", 1, MAX_STEPS),
        )
        for name, low, high in integers:
            value = getattr(self, name)
            if name == "decimation" and value is None:
                continue
            if not isinstance(value, int) or isinstance(value, bool):
                raise bad(name, "must be an integer")
            if value < low:
                raise bad(name, f"must be >= {low}")
            if high is not None and value > high:
                raise bad(name, f"must be at most {high}")
        if self.decimation is not None and self.decimation > MAX_DECIMATION:
            raise bad(
                "decimation",
                f"must be <= {MAX_DECIMATION} (physics steps per control step: a 50 Hz controller "
                "at a 4 ms timestep needs 5; each env step holds decimation servo targets)",
            )
        if self.control_dt is None and self.decimation is None:
            raise ValueError("EnvConfig needs control_dt or decimation (both are None)")
        if self.control_dt is not None and not (
            _is_number(self.control_dt) and self.control_dt > 0
        ):
            raise bad("control_dt", "must be a number of seconds > 0")
        if not 0.0 <= self.terrain_scale <= 1.0:
            raise bad("terrain_scale", "must be in [0, 1]")
        if self.terrain_levels is not None and self.terrain_scale != 1.0:
            raise bad("terrain_scale", "must be 1.0 with terrain_levels (each level sets its own)")
        if min(self.position_noise) < 0 or self.yaw_noise < 0 or self.tilt_noise < 0:
            raise ValueError("EnvConfig noise half-widths must be >= 0")
        if not isinstance(self.num_threads, int) or not 0 <= self.num_threads <= MAX_THREADS:
            raise bad("num_threads", f"must be an integer in [0, {MAX_THREADS}]")
        if self.command_range is not None and not (
            isinstance(self.command_range, tuple)
            and len(self.command_range) == 2
            and all(_is_number(v) for v in self.command_range)
            and self.command_range[0] <= self.command_range[1]
        ):
            raise bad("command_range", "must be LOW HIGH m/s with LOW <= HIGH (or None)")
        if self.command_interval is not None and not (
            _is_number(self.command_interval) and 0 < self.command_interval <= MAX_INTERVAL
        ):
            raise bad("command_interval", f"must be None or seconds in (0, {MAX_INTERVAL:g}]")
        if self.command_range is not None and not all(
            abs(v) <= MAX_SPEED for v in self.command_range
        ):
            raise bad("command_range", f"must be speeds within ±{MAX_SPEED:g} m/s")
        if self.command_curriculum is not None:  # without a range: refused by the task
            if self.command_range is not None:  # (a flag may give the range after the part)
                self.command_curriculum.check_range(self.command_range)
            if self.command_interval is not None:
                raise bad("command_interval", "must be None with a command_curriculum (it "
                          "judges each episode's one command)")  # fmt: skip
        if self.shaping is not None and self.shaping.kind_tracking:
            kinds = self.terrain_levels.kinds if self.terrain_levels is not None else ()
            missing = [kind for kind in self.shaping.tracking_kinds if kind not in kinds]
            if missing or not self.shaping.tracking_kinds:
                raise ValueError(
                    f"Shaping.kind_tracking {self.shaping.kind_tracking!r} weighs the envs on "
                    f"tracking_kinds {self.shaping.tracking_kinds!r}, which need tiles in the "
                    f"terrain-levels map (its kinds: {kinds or 'none, no map'})"
                )
        if self.costs is not None:  # the default legs; a Core checks its model's again
            self.costs.check_reach(LegGeometry(), self.top_speed)

    def substeps(self, timestep: float) -> int:
        """Physics substeps per env step at a physics ``timestep`` (seconds).

        Raises:
            ValueError: naming the timestep, control_dt and decimation, if the
                timestep is not positive or the substeps miss the control rate.
        """
        if not (_is_number(timestep) and math.isfinite(timestep) and timestep > 0):
            raise ValueError(f"the physics timestep must be > 0 seconds, got {timestep!r}")
        if self.control_dt is None:
            return self.decimation
        substeps = round(self.control_dt / timestep)
        if substeps < 1 or abs(substeps * timestep - self.control_dt) > 1e-9 * self.control_dt:
            raise ValueError(
                f"the physics timestep {timestep:g} s does not divide EnvConfig.control_dt="
                f"{self.control_dt:g} s into whole substeps: choose a timestep of "
                f"control_dt / k (e.g. {self.control_dt / max(substeps, 1):g} s)"
            )
        if self.decimation is not None and self.decimation != substeps:
            raise ValueError(
                f"EnvConfig.decimation={self.decimation} x timestep {timestep:g} s = "
                f"{self.decimation * timestep:g} s misses control_dt={self.control_dt:g} s: "
                f"use decimation={substeps} or control_dt=None"
            )
        if substeps > MAX_DECIMATION:
            raise ValueError(
                f"control_dt={self.control_dt:g} s at timestep {timestep:g} s needs {substeps} "
                f"substeps per env step, more than {MAX_DECIMATION}"
            )
        return substeps

    @property
    def expected_velocity(self) -> float:
        """step_length / cycle_time. m/s."""
        return self.gait.expected_velocity

    @property
    def top_speed(self) -> float:
        """The fastest target velocity the reward can ask (either sign): the command
        range's farther end, else the gait's. m/s."""
        if self.command_range is not None:
            return max(abs(v) for v in self.command_range)
        return abs(self.expected_velocity)

    @property
    def varies(self) -> bool:
        """Whether the world varies from episode to episode beyond its starts: terrain
        levels, randomised physics, pushes or observation noise."""
        parts = (self.terrain_levels, self.randomization, self.pushes, self.observation_noise)
        return any(part is not None for part in parts)


def convert(kind: type[EnvConfig], config: EnvConfig, **extra) -> EnvConfig:
    """A ``kind`` (a task's config class) with ``config``'s ``EnvConfig`` fields and
    ``extra`` (``kind``'s own fields; the others at their defaults)."""
    base = {f.name: getattr(config, f.name) for f in fields(EnvConfig)}
    return kind(**(base | extra))


def part_type(kind: type, name: str) -> type | None:
    """The dataclass that field ``name`` of the dataclass ``kind`` holds where it holds one
    (``GaitCosts`` for ``EnvConfig``'s ``costs: GaitCosts | None``), else None."""
    hint = typing.get_type_hints(kind)[name]
    parts = [k for k in (hint, *typing.get_args(hint)) if is_dataclass(k)]
    return parts[0] if parts else None


def with_fields(config: Any, values: Mapping[str, Any]) -> Any:
    """``config`` with each field that ``values`` names by its dotted path set to its
    value, in order (``{"costs.power": 2.0, "randomization.latency": (0, 3)}``: the paths
    of --env.costs.power and --env.randomization.latency; a path may end in a field of a
    NamedTuple); a part that is None starts at its type's defaults, as where a flag names
    a field of it. Each part made is checked as a flag's is (its ``__post_init__``)."""
    for path, value in values.items():
        config = _with_field(config, path.split("."), value)
    return config


def _with_field(config: Any, names: list[str], value: Any) -> Any:
    name, rest = names[0], names[1:]
    if rest:
        part = getattr(config, name)
        part = part_type(type(config), name)() if part is None else part
        value = _with_field(part, rest, value)
    if isinstance(config, tuple):  # a NamedTuple
        return config._replace(**{name: value})
    return replace(config, **{name: value})
