"""The adaptive-gait task (spec: AdaptiveGaitEnv.md): the policy also changes the gait.

Action (N, 16): ``[0:4]`` deltas of step_height, step_length, cycle_time and
body_height (``action x delta``, added each step, clipped to the range), then
the 12 foot residuals of the residual task. Observation (N, 69): the 65 sensor
values, then the four current parameters normalised to [-1, 1] over their
ranges. Every env carries its own parameters and a continuous phase: a new
cycle time changes how fast the phase advances, never the phase itself.

Default ranges, for this robot (legs 0.05 + 0.06 m, hip-to-foot reach
0.026..0.109 m) and world_train's ground (heights with a standard deviation of
8.6 mm at full roughness, bumps ~0.1 m apart):

- step_height 0.01..0.04 m: about 1 to 5 standard deviations of the ground; its
  top stays below the lowest body height, with room for the swing leg to fold.
- step_length 0..0.16 m: from stepping in place to a stride whose stance sweep
  (0.65 x 0.16 = 0.10 m) the legs reach at every body height in range.
- cycle_time 0.3..0.9 s: at duty 0.65, 0.3 s leaves 0.105 s swings (26 physics
  steps); 0.9 s is 1.5 x the nominal 0.6 s.
- body_height 0.05..0.09 m: crouched to nearly stretched (the stance line at
  0.09 m lies 0.0925 m below the hip, inside the 0.109 m reach).

Each delta scale is a fortieth of its range: a full sweep takes 40 steps,
0.8 s, one to three gait cycles: fast enough to change the gait between bumps,
slow enough that a few noisy actions move it little. (A twentieth was tried
first; docs/adaptive.md tells what training made of both.)
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from rwalk import mirror as mirrors
from rwalk.config import EnvConfig, _is_number
from rwalk.constants import ACTION_DIM
from rwalk.gait import BezierGaitController, GaitParameters, GaitShape, advance_phase
from rwalk.gaitmath import MAX_STEP_RISE, speed_schedule
from rwalk.mirror import Mirror
from rwalk.observations import ObsPiece
from rwalk.tasks.base import Recipe, Task

#: Random stream of the starting parameters with ``start_spread`` (see ``rwalk.rng``).
START_GAIT_STREAM = "gait_start"
#: What the action's first four values do (AdaptiveGaitConfig.gait_action).
GAIT_ACTIONS = ("delta", "target", "schedule")
#: The training's spread of the starting parameters (``AdaptiveGaitConfig.start_spread``).
TRAINING_START_SPREAD = 0.5
#: The adapted parameters, in the order of the action's and observation's values.
ADAPTED: tuple[str, ...] = ("step_height", "step_length", "cycle_time", "body_height")
#: Longest ``schedule_stride`` accepted (the contract's longest stride). Metres.
MAX_STRIDE = 0.16


class Bound(NamedTuple):
    """Range of one adapted parameter and its change per unit of action per step."""

    low: float
    high: float
    delta: float


@dataclass(frozen=True)
class GaitBounds:
    """Ranges and delta scales of the adapted parameters (metres, seconds)."""

    step_height: Bound = Bound(0.01, 0.04, 0.00075)  # noqa: RUF009 (immutable)
    """Height of the swing apex above the stance line: (low, high, delta), metres."""
    step_length: Bound = Bound(0.0, 0.16, 0.004)  # noqa: RUF009 (immutable)
    """Stride, the distance the body advances per cycle: (low, high, delta), metres."""
    cycle_time: Bound = Bound(0.3, 0.9, 0.015)  # noqa: RUF009 (immutable)
    """Duration of one gait cycle: (low, high, delta), seconds."""
    body_height: Bound = Bound(0.05, 0.09, 0.001)  # noqa: RUF009 (immutable)
    """Commanded height of the hip points above the ground: (low, high, delta), metres."""

    def __post_init__(self) -> None:
        for name in ADAPTED:
            value = getattr(self, name)
            if not (
                isinstance(value, tuple)
                and len(value) == 3
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
                and all(math.isfinite(v) for v in value)
            ):
                raise ValueError(
                    f"GaitBounds.{name} must be (low, high, delta), finite numbers, got {value!r}"
                )
            object.__setattr__(self, name, Bound(*(float(v) for v in value)))
            low, high, delta = getattr(self, name)
            if not low < high:
                raise ValueError(f"GaitBounds.{name}: low must be < high, got {value!r}")
            if not delta > 0:
                raise ValueError(f"GaitBounds.{name}: delta must be > 0, got {value!r}")
        positive = ("step_height", "cycle_time", "body_height")
        for name in positive:
            if not getattr(self, name).low > 0:
                raise ValueError(f"GaitBounds.{name}: low must be > 0, got {getattr(self, name)!r}")
        if self.step_length.low < 0:
            raise ValueError(f"GaitBounds.step_length: low must be >= 0, got {self.step_length!r}")
        if self.step_height.high >= self.body_height.low:
            raise ValueError(
                f"GaitBounds.step_height: its high ({self.step_height.high!r} m) could reach the "
                f"body height (body_height low {self.body_height.low!r} m); keep it below"
            )

    def as_tensors(self) -> tuple[Tensor, Tensor, Tensor]:
        """low, high, delta of the four parameters in ``ADAPTED`` order. Each (4,) float64."""
        rows = [getattr(self, name) for name in ADAPTED]
        return tuple(torch.tensor(col, dtype=torch.float64) for col in zip(*rows, strict=True))


@dataclass(frozen=True)
class AdaptiveGaitConfig(EnvConfig):
    """``EnvConfig`` plus the adaptation bounds.

    ``gait`` is the gait every episode starts from (and settles with).
    """

    bounds: GaitBounds = field(default_factory=GaitBounds)
    """Ranges and delta scales of the adapted parameters."""
    start_spread: float = 0.0
    """0: every episode starts from ``gait`` (the contract's reset). s in (0, 1]:
    after settling with ``gait``, each episode starts from parameters drawn
    uniformly within s x each range around ``gait`` (clipped to the range): a
    training option, so that the policy and its critic see how the parameters
    matter instead of learning from the tiny spread of exploration noise."""

    gait_action: str = "delta"
    """What the action's first four values a do. "delta" (the contract): each step adds
    a x delta to the parameter, clipped to its range. "target": each step moves the
    parameter toward centre + a x half_width of its range by at most delta, so an action
    held at 0 holds the range's centre, and a parameter never drifts on the integral of
    exploration noise. "schedule": as "target", around the gait the target velocity asks
    for (``speed_schedule``: a gait command chosen by the speed) instead of the centre,
    each parameter within ``schedule_window`` x its half_width of it."""
    schedule_stride: float = 0.06
    """With gait_action "schedule": the stride (m) the schedule keeps while the cycle can
    shorten; ``speed_schedule`` tells the rest."""
    schedule_window: tuple[float, float, float, float] = (1.0, 0.25, 0.25, 1.0)
    """With gait_action "schedule": how far the action may move each parameter's target
    from the schedule's (step_height, step_length, cycle_time, body_height), as a
    fraction in [0, 1] of the parameter's half_width (0 pins it to the schedule)."""
    schedule_step_rise: float = 0.0
    """With gait_action "schedule": how the schedule's step height rises with the target
    velocity, metres per m/s, from the starting gait's step at its speed
    (``expected_velocity``), within step_height's range; 0 keeps the starting gait's step
    at every speed."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.gait_action not in GAIT_ACTIONS:
            raise ValueError(
                f"AdaptiveGaitConfig.gait_action must be one of {', '.join(GAIT_ACTIONS)}, "
                f"got {self.gait_action!r}"
            )
        stride = self.schedule_stride
        if not (_is_number(stride) and 0.0 < stride <= MAX_STRIDE):  # (NaN fails)
            raise ValueError(
                f"AdaptiveGaitConfig.schedule_stride must be metres in (0, {MAX_STRIDE:g}], "
                f"got {self.schedule_stride!r}"
            )
        window = self.schedule_window
        if not (
            isinstance(window, tuple)
            and len(window) == len(ADAPTED)
            and all(_is_number(w) and 0.0 <= w <= 1.0 for w in window)  # (NaN fails)
        ):
            raise ValueError(
                f"AdaptiveGaitConfig.schedule_window must be {len(ADAPTED)} fractions in "
                f"[0, 1] ({', '.join(ADAPTED)}), got {window!r}"
            )
        object.__setattr__(self, "schedule_window", tuple(float(w) for w in window))
        rise = self.schedule_step_rise
        if not (_is_number(rise) and 0.0 <= rise <= MAX_STEP_RISE):  # (NaN fails)
            raise ValueError(
                f"AdaptiveGaitConfig.schedule_step_rise must be metres per m/s in "
                f"[0, {MAX_STEP_RISE:g}], got {rise!r}"
            )
        object.__setattr__(self, "schedule_step_rise", float(rise))
        if self.gait_action == "schedule":
            slowest = (self.expected_velocity if self.command_range is None
                       else self.command_range[0])  # fmt: skip
            if not slowest > 0:
                raise ValueError(
                    f"AdaptiveGaitConfig.gait_action 'schedule' needs forward target "
                    f"velocities (> 0 m/s); command_range {self.command_range!r} asks for "
                    f"{slowest!r}"
                )
        if not (
            isinstance(self.start_spread, (int, float))
            and not isinstance(self.start_spread, bool)
            and 0.0 <= self.start_spread <= 1.0
        ):
            raise ValueError(
                f"AdaptiveGaitConfig.start_spread must be in [0, 1], got {self.start_spread!r}"
            )
        if not isinstance(self.bounds, GaitBounds):
            raise TypeError(
                f"AdaptiveGaitConfig.bounds must be a GaitBounds, got {type(self.bounds).__name__}"
            )
        for name in ADAPTED:
            low, high, _ = getattr(self.bounds, name)
            start = getattr(self.gait, name)
            if not low <= start <= high:
                raise ValueError(
                    f"GaitBounds.{name}: the starting gait's {name}={start!r} is outside "
                    f"[{low!r}, {high!r}]"
                )

    def corner_gaits(self) -> list[tuple[str, GaitParameters]]:
        """The starting gait at each extreme of the body height with the longest
        stride: the stance line must be reachable in all of them."""
        b = self.bounds
        return [
            ("body_height", dataclasses.replace(
                self.gait, body_height=h, step_length=b.step_length.high,
                step_height=min(self.gait.step_height, 0.5 * h)))
            for h in (b.body_height.low, b.body_height.high)
        ]  # fmt: skip


class AdaptiveGait(Task):
    """Gait deltas and foot residuals; see the module docstring."""

    name = "adaptive_gait"
    config_type = AdaptiveGaitConfig
    action_dim = len(ADAPTED) + ACTION_DIM
    action_layout = (
        "4 gait deltas (step_height, step_length, cycle_time, body_height), then 12 foot residuals"
    )
    observation = ("sensors", "gait")
    action_fields = ("bounds", "gait_action", "schedule_stride", "schedule_window",
                     "schedule_step_rise")  # fmt: skip
    acting_fields = (*Task.acting_fields, *action_fields)
    # the adaptive default (docs/adaptive.md, "Training: one command"): commands of
    # 0.03-0.27 m/s on all five kinds of tile; the body pinned at the trot's 70 mm, the
    # stride at least 40 mm and the cycle at least 0.45 s; the gait the command asks for
    # (the schedule), its step 13 mm at v* rising 40 mm per m/s and no wider, each foot
    # down for 55% of the cycle; the gait costs with power x2 and the speed kernel; a
    # teacher that reads the ground, then its blind GRU student on half its envs, then
    # 150 iterations of PPO on the student itself (the fine-tune stage)
    recipe = Recipe(
        env_fields={
            "command_range": (0.03, 0.27),
            "terrain_levels.kinds": ("flat", "rough", "slopes", "steps", "stones"),
            "bounds.body_height.low": 0.0699, "bounds.body_height.high": 0.0701,
            "bounds.step_length.low": 0.04, "bounds.cycle_time.low": 0.45,
            "costs.power": 2.0, "shaping.tracking": 300.0, "shaping.sigma": 0.02,
            "gait_action": "schedule", "gait.step_height": 0.013, "gait.duty_factor": 0.55,
            "schedule_step_rise": 0.04, "schedule_window": (0.0, 0.25, 0.25, 1.0),
        },
        train={"teacher": True, "student_iterations": 190, "student_actor": "gru",
               "distill_levels": True, "finetune_iterations": 150},
        max_iterations=500, student_env_share=0.5,
    )  # fmt: skip

    @classmethod
    def training_config(cls, world: EnvConfig) -> EnvConfig:
        """The base task's, starting each episode from parameters spread by
        TRAINING_START_SPREAD of each range."""
        return dataclasses.replace(super().training_config(world),
                                   start_spread=TRAINING_START_SPREAD)  # fmt: skip

    @classmethod
    def deploy_spec(cls, core) -> dict:
        """The trot's constants (the runtime's ``rwalk.gaitmath`` computes the foot paths
        from the current parameters) and the parameters' start, ranges and action."""
        controller, task, params = core.controller, core.task, core.controller.params
        gait = {
            "period": controller.period,
            "duty_factor": params.duty_factor,
            "stance_depth": params.stance_depth,
            "offsets": controller.leg_offsets.tolist(),
            "swing_points": controller.swing_points.tolist(),
            "neutral": controller.neutral.tolist(),
        }
        ranges = {key: getattr(task, key).tolist() for key in ("start", "low", "high", "delta")}
        adaptive = {"gait_action": core.config.gait_action, **ranges}
        if core.config.gait_action == "schedule":
            adaptive["schedule"] = {"stride": core.config.schedule_stride,
                                    "window": list(core.config.schedule_window),
                                    "step_rise": core.config.schedule_step_rise,
                                    "speed": core.config.expected_velocity}  # fmt: skip
        return {"runtime": "adaptive", "gait": gait, "adaptive": adaptive}

    def __init__(self, config: AdaptiveGaitConfig, world, num_envs: int) -> None:
        super().__init__(config, world, num_envs)
        cfg = config
        for field_name, gait in cfg.corner_gaits():
            try:
                BezierGaitController(gait, world.geometry, dt=world.dt)
            except ValueError as error:
                raise ValueError(
                    f"GaitBounds.{field_name}={getattr(cfg.bounds, field_name)!r}: the legs "
                    f"cannot reach it with a {gait.step_length} m stride: {error}"
                ) from None
        self.low, self.high, self.delta = cfg.bounds.as_tensors()
        self.centre = 0.5 * (self.low + self.high)
        self.half_width = 0.5 * (self.high - self.low)
        self.start = torch.tensor(
            [getattr(cfg.gait, name) for name in ADAPTED], dtype=torch.float64
        )
        self.span = torch.tensor(cfg.schedule_window, dtype=torch.float64) * self.half_width
        """With gait_action "schedule": how far the action moves a target from the
        schedule's. Shape: (4,)."""
        n = num_envs
        self.params = self.start.repeat(n, 1)
        """Current step_height, step_length, cycle_time, body_height. Shape: (N, 4)."""
        self.start_draws = torch.zeros(n, dtype=torch.long)
        """Starting parameters drawn so far by each env (with start_spread). Shape: (N,)."""
        self.gait_phase = torch.zeros(n, dtype=torch.float64)
        """Continuous gait phase in [0, 1) at the start of the next step. Shape: (N,)."""
        self.sensed = torch.zeros(n, dtype=torch.float64)
        """Gait phase at the start of the last step's last substep. Shape: (N,)."""

    @classmethod
    def pieces(cls) -> dict[str, ObsPiece]:
        pieces = super().pieces()
        pieces["gait"] = ObsPiece(
            len(ADAPTED),
            lambda s: (s.task.params - s.task.centre) / s.task.half_width,
            "step_height, step_length, cycle_time, body_height, each (v - centre) / half_width",
            noise=lambda cfg: cfg.gait,
            mirror=mirrors.identity(len(ADAPTED)),
        )
        return pieces

    @classmethod
    def action_mirror(cls) -> Mirror:
        return mirrors.concat((mirrors.identity(len(ADAPTED)), mirrors.RESIDUALS))

    def seed(self, seed: int) -> None:
        super().seed(seed)
        self.start_draws.zero_()

    def reset(self, rows: Tensor) -> None:
        self.params[rows] = self.start
        spread = self.config.start_spread
        if spread > 0:
            u = 2.0 * self.uniform(rows, START_GAIT_STREAM, self.start_draws, len(ADAPTED)) - 1.0
            offset = u * (spread * (self.high - self.low))
            self.params[rows] = torch.minimum(
                torch.maximum(self.start + offset, self.low), self.high
            )
        self.gait_phase[rows] = self.world.settled_tick / self.world.controller.period

    def act(self, action: Tensor) -> tuple[np.ndarray, Tensor]:
        world = self.world
        n, k = self.num_envs, world.decimation
        params = self.params
        if self.config.gait_action == "delta":
            moved = params + action[:, :4] * self.delta
        else:
            if self.config.gait_action == "target":
                target = self.centre + action[:, :4] * self.half_width
            else:
                target = self.scheduled() + action[:, :4] * self.span
            moved = params + torch.minimum(torch.maximum(target - params, -self.delta),
                                           self.delta)  # fmt: skip
        params.copy_(torch.minimum(torch.maximum(moved, self.low), self.high))
        residuals = action[:, 4:].reshape(n, 4, 3) * self.config.residual_scale
        phases = advance_phase(self.gait_phase, params[:, 2], world.dt, k)
        shape = GaitShape(params[:, 0], params[:, 1], params[:, 3])
        ctrl = world.controller.joint_targets_at(phases[:, :k], shape, residuals)
        swing = world.controller.swing_at(phases[:, k - 1])
        self.sensed.copy_(phases[:, k - 1])
        self.gait_phase.copy_(phases[:, k])
        return np.ascontiguousarray(ctrl.numpy()), swing

    def scheduled(self) -> Tensor:
        """The gait each env's target velocity asks for (``speed_schedule``). Shape: (N, 4)."""
        speed = torch.as_tensor(self.v_target, dtype=torch.float64).expand(self.num_envs)
        cfg = self.config
        return speed_schedule(speed, cfg.schedule_stride, self.low, self.high, self.start,
                              cfg.schedule_step_rise, cfg.expected_velocity)  # fmt: skip

    @property
    def phase(self) -> Tensor:
        return self.gait_phase

    @property
    def sensed_phase(self) -> Tensor:
        return self.sensed

    def phase_features(self) -> Tensor:
        return self.world.controller.phase_features_at(self.gait_phase)

    def gait_params(self) -> Tensor:
        """Current parameters in SI units. Shape: (N, 4)."""
        return self.params

    def state(self) -> dict[str, Tensor]:
        return super().state() | {"params": self.params, "gait_phase": self.gait_phase,
                                  "start_draws": self.start_draws}  # fmt: skip
