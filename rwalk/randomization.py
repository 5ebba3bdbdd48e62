"""Worlds that differ per env: randomised physics, pushes, control latency and sensor noise.

Configured by three dataclasses on ``EnvConfig`` (each None by default, the
spec's env): ``Randomization`` (per-env physics through ``mujoco.batch.Batch.expand``,
resampled at every reset), ``Pushes`` (horizontal velocity kicks to the torso at
random intervals) and ``ObservationNoise`` (uniform noise on the policy's
observation group, never on the critic's). ``Perturbations`` applies them to a
core, vectorised over the batch: no Python per env.

Every draw is keyed like the starts (``rwalk.rng``): env i of a core seeded s
draws its k-th physics sample from (s + i, "physics", k) and its k-th push from
(s + i, "push", k); noise comes from a torch generator seeded from (s, "obs_noise").
So the same seed gives bit-identical worlds and trajectories at any thread count.

Ranges (a 0.8 kg robot on 0.3 N·m hobby servos; see docs/robustness.md for the
references: legged_gym and MuJoCo Playground's Go1):
friction 0.5–1.3 (legged_gym 0.5–1.25; the nominal rubber foot is 1.2), payload
−0.05–+0.12 kg on the 0.56 kg torso (−6 %…+15 % of the robot, legged_gym ±1 kg
of 12 kg), centre of mass ±1 cm on a 18 cm torso, servo gain and torque limit
×0.85–1.15 (walk-these-ways' motor strength ×0.9–1.1), joint damping and
armature ×0.8–1.2, latency 0–2 substeps (0–8 ms).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import mujoco
import numpy as np
import torch
from torch import Tensor

from rwalk import exactmath, rng
from rwalk.constants import (
    FLOOR_GEOM,
    FOOT_GEOMS,
    GROUND_GEOM,
    JOINT_NAMES,
    OBS_ANGVEL,
    OBS_DIM,
    OBS_FOOT_POS,
    OBS_FOOT_VEL,
    OBS_JOINT_POS,
    OBS_JOINT_VEL,
    OBS_LINVEL,
    OBS_POS,
    OBS_QUAT,
    TORSO_BODY,
)

#: Random streams (see ``rwalk.rng``).
PHYSICS_STREAM = "physics"
PUSH_STREAM = "push"
NOISE_STREAM = "obs_noise"


def _check_range(
    obj, name: str, low: float | None = None, above: bool = False, integer: bool = False
) -> None:
    """Raise a ValueError naming ``obj``'s field ``name`` unless it is a (min, max) pair
    of finite numbers (integers) with min <= max and min >= low (> low if ``above``)."""
    value = getattr(obj, name)
    field = f"{type(obj).__name__}.{name}"
    ok = (
        isinstance(value, tuple)
        and len(value) == 2
        and all(
            isinstance(v, int if integer else (int, float))
            and not isinstance(v, bool)
            and math.isfinite(v)
            for v in value
        )
    )
    if not ok:
        wanted = "integers" if integer else "finite numbers"
        raise ValueError(f"{field} must be a pair of {wanted} (min, max), got {value!r}")
    if value[0] > value[1]:
        raise ValueError(f"{field} has min > max: {value!r}")
    if low is not None and (value[0] < low or (above and value[0] == low)):
        raise ValueError(f"{field} must be {'>' if above else '>='} {low:g}, got {value!r}")


@dataclass(frozen=True)
class Randomization:
    """Per-env physics, drawn uniformly from each (min, max) at every reset.

    A range with min == max sets that value for every env (the robustness
    benchmark's held-out conditions); ``Randomization.nominal()`` changes nothing.
    """

    friction: tuple[float, float] = (0.5, 1.3)
    """Sliding friction of the feet and the ground (MuJoCo takes the larger of the
    two geoms'; both are set). The model's is 1.2."""
    payload: tuple[float, float] = (-0.05, 0.12)
    """Mass added to the torso (0.56 kg of the robot's 0.8). kg."""
    com_offset: tuple[float, float] = (-0.01, 0.01)
    """Shift of the torso's centre of mass along x and along y (each drawn). Metres."""
    kp_scale: tuple[float, float] = (0.85, 1.15)
    """Factor on the servos' position gain (kp = 6 N·m/rad)."""
    force_scale: tuple[float, float] = (0.85, 1.15)
    """Factor on the servos' torque limit (0.3 N·m)."""
    damping_scale: tuple[float, float] = (0.8, 1.2)
    """Factor on the leg joints' damping."""
    armature_scale: tuple[float, float] = (0.8, 1.2)
    """Factor on the leg joints' armature (rotor inertia)."""
    latency: tuple[int, int] = (0, 2)
    """Delay of the servo targets, in physics substeps (at most one control period)."""

    def __post_init__(self) -> None:
        _check_range(self, "friction", 0.0)
        _check_range(self, "payload")
        _check_range(self, "com_offset")
        _check_range(self, "kp_scale", 0.0, above=True)
        _check_range(self, "force_scale", 0.0, above=True)
        _check_range(self, "damping_scale", 0.0)
        _check_range(self, "armature_scale", 0.0)
        _check_range(self, "latency", 0, integer=True)

    @classmethod
    def nominal(cls, **ranges) -> Randomization:
        """The model's own values (nothing randomised), with ``ranges`` overriding fields."""
        base = dict(
            friction=(NOMINAL_FRICTION,) * 2, payload=(0.0, 0.0), com_offset=(0.0, 0.0),
            kp_scale=(1.0, 1.0), force_scale=(1.0, 1.0), damping_scale=(1.0, 1.0),
            armature_scale=(1.0, 1.0), latency=(0, 0),
        )  # fmt: skip
        return cls(**(base | ranges))


@dataclass(frozen=True)
class Pushes:
    """Horizontal velocity kicks to the torso, per env, at control-step boundaries."""

    speed: tuple[float, float] = (0.0, 0.15)
    """Magnitude of each kick, uniform in (min, max), in a uniformly random horizontal
    direction. m/s (x 0.8 kg = the impulse in N·s)."""
    interval: tuple[float, float] = (2.0, 5.0)
    """Time from an episode's start or a kick to the next kick, uniform. Seconds."""

    def __post_init__(self) -> None:
        _check_range(self, "speed", 0.0)
        _check_range(self, "interval", 0.0, above=True)


@dataclass(frozen=True)
class ObservationNoise:
    """Half-widths of uniform noise added to the policy's observation, per block.

    The sensor blocks apply wherever the spec's 65 sensor values appear (the pieces
    ``sensors`` and ``observation``); the others name pieces. Contacts stay exact.
    """

    torso_pos: float = 0.005
    """m."""
    torso_quat: float = 0.01
    torso_linvel: float = 0.015
    """m/s (about 10% of the walking speed, like legged_gym's 0.1 m/s at ~1 m/s)."""
    torso_angvel: float = 0.1
    """rad/s."""
    joint_pos: float = 0.01
    """rad."""
    joint_vel: float = 0.3
    """rad/s."""
    foot_pos: float = 0.002
    """m."""
    foot_vel: float = 0.03
    """m/s."""
    lateral_offset: float = 0.005
    """m."""
    gait: float = 0.0
    """The adaptive task's gait parameters (normalised)."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (
                isinstance(value, (int, float))
                and not isinstance(value, bool)
                and math.isfinite(value)
                and value >= 0
            ):
                raise ValueError(f"ObservationNoise.{f.name} must be a scale >= 0, got {value!r}")

    def sensor_scales(self) -> Tensor:
        """Scale of each of the 65 sensor values. Shape: (65,) float64."""
        scales = torch.zeros(OBS_DIM, dtype=torch.float64)
        blocks = (
            (OBS_POS, self.torso_pos), (OBS_QUAT, self.torso_quat),
            (OBS_LINVEL, self.torso_linvel), (OBS_ANGVEL, self.torso_angvel),
            (OBS_JOINT_POS, self.joint_pos), (OBS_JOINT_VEL, self.joint_vel),
            (OBS_FOOT_POS, self.foot_pos), (OBS_FOOT_VEL, self.foot_vel),
        )  # fmt: skip
        for block, scale in blocks:
            scales[block] = scale
        return scales


#: Contact friction of the model (the larger of foot 1.2 and ground 1.0).
NOMINAL_FRICTION = 1.2
#: The physics piece: each parameter as (value - centre) / spread, so that the
#: training ranges map to about [-1, 1] whatever an evaluation draws.
PHYSICS_PARAMS: tuple[tuple[str, float, float], ...] = (
    ("friction", 0.9, 0.4),
    ("payload", 0.035, 0.085),
    ("com_x", 0.0, 0.01),
    ("com_y", 0.0, 0.01),
    ("kp_scale", 1.0, 0.15),
    ("force_scale", 1.0, 0.15),
    ("damping_scale", 1.0, 0.2),
    ("armature_scale", 1.0, 0.2),
    ("latency", 1.0, 1.0),
)
#: The model's own values of PHYSICS_PARAMS.
NOMINAL_PARAMS = (NOMINAL_FRICTION, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.0)
_CENTRE = torch.tensor([c for _, c, _ in PHYSICS_PARAMS], dtype=torch.float64)
_SPREAD = torch.tensor([s for _, _, s in PHYSICS_PARAMS], dtype=torch.float64)


class Perturbations:
    """The config's randomisation, pushes, latency and noise, applied to a core.

    Args:
        core: the core (its simulation built, not yet reset).

    Raises:
        ValueError: naming the field, for a payload that leaves the torso without
            mass or a latency beyond one control period.
    """

    def __init__(self, core) -> None:
        cfg = core.config
        self.core = core
        self.randomization: Randomization | None = cfg.randomization
        self.pushes: Pushes | None = cfg.pushes
        self.noise: ObservationNoise | None = cfg.observation_noise
        n, k = core.num_envs, core.decimation
        model = core.model
        self.params = _CENTRE.new_tensor(NOMINAL_PARAMS).repeat(n, 1)
        """Each env's physics, in PHYSICS_PARAMS order (raw values). Shape: (N, 9)."""
        self.physics_draws = torch.zeros(n, dtype=torch.long)
        self.push_draws = torch.zeros(n, dtype=torch.long)
        self.latency = torch.zeros(n, dtype=torch.long)
        """Servo-target delay of each env. Shape: (N,). Substeps."""
        self.push_countdown = torch.full((n,), torch.iinfo(torch.long).max, dtype=torch.long)
        """Env steps until each env's next kick. Shape: (N,)."""
        self.kick = torch.zeros(n, 2, dtype=torch.float64)
        """Each env's next kick: the change of the torso's (x, y) velocity. Shape: (N, 2). m/s."""
        self.pushes_done = 0
        """Kicks given so far (all envs)."""
        rand = self.randomization
        if rand is not None:
            torso = model.body(TORSO_BODY)
            if float(torso.mass[0]) + rand.payload[0] <= 0:
                raise ValueError(
                    f"Randomization.payload {rand.payload!r} leaves the torso "
                    f"({float(torso.mass[0]):g} kg) with no mass"
                )
            if rand.latency[1] > k:
                raise ValueError(
                    f"Randomization.latency {rand.latency!r} exceeds one control period "
                    f"({k} substeps)"
                )
            self._torso = torso.id
            ground = [model.geom(GROUND_GEOM).id]
            if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, FLOOR_GEOM) >= 0:
                ground.append(model.geom(FLOOR_GEOM).id)
            self._friction_geoms = np.array(
                ground + [model.geom(name).id for name in FOOT_GEOMS], dtype=np.int64
            )
            self._dofs = np.array(
                [int(model.joint(name).dofadr[0]) for name in JOINT_NAMES], dtype=np.int64
            )
            batch = core.sim.batch
            self._arrays = {
                name: batch.expand(name)
                for name in (
                    "geom_friction", "body_mass", "body_ipos", "actuator_gainprm",
                    "actuator_biasprm", "actuator_forcerange", "dof_damping", "dof_armature",
                )
            }  # fmt: skip
            self._nominal = {name: np.array(getattr(model, name)) for name in self._arrays}
        self._held = torch.zeros(n, k, len(JOINT_NAMES), dtype=torch.float64)
        """Each env's servo targets of the last control period (the delayed ones come
        from its end). Shape: (N, K, 12)."""
        self._generator = torch.Generator()
        self._noise_cache: dict[str, Tensor] = {}
        self._scale_cache: dict[str, Tensor | None] = {}  # per piece: fixed by the config

    def seed(self, seed: int) -> None:
        """Restart the draws (the core was reseeded)."""
        self.physics_draws.zero_()
        self.push_draws.zero_()
        key = int(rng.keys(seed, NOISE_STREAM, 0))
        self._generator.manual_seed(key & (2**63 - 1))
        self._noise_cache.clear()

    # ------------------------------------------------------------ resets
    def reset(self, rows: Tensor, settle_tail: np.ndarray) -> None:
        """Draw new physics and the first kick time for ``rows`` (before they settle).

        Args:
            rows: env indices. Shape: (M,).
            settle_tail: the last K servo targets of settling. Shape: (K, 12).
        """
        if self.randomization is not None:
            self._draw_physics(rows)
            self._held[rows] = torch.from_numpy(settle_tail)
        if self.pushes is not None:
            self._schedule_push(rows)

    def _draw_physics(self, rows: Tensor) -> None:
        rand = self.randomization
        u = rng.uniform_rows(self.core.seed_value, rows, PHYSICS_STREAM, self.physics_draws, 9)
        ranges = (
            rand.friction, rand.payload, rand.com_offset, rand.com_offset, rand.kp_scale,
            rand.force_scale, rand.damping_scale, rand.armature_scale,
        )  # fmt: skip
        low = torch.tensor([r[0] for r in ranges], dtype=torch.float64)
        high = torch.tensor([r[1] for r in ranges], dtype=torch.float64)
        values = low + u[:, :8] * (high - low)
        # latency: a whole number of substeps, each equally likely
        span = rand.latency[1] - rand.latency[0] + 1
        latency = rand.latency[0] + torch.floor(u[:, 8] * span).to(torch.long)
        self.params[rows, :8] = values
        self.params[rows, 8] = latency.to(torch.float64)
        self.latency[rows] = latency
        self.apply(rows)

    def apply(self, rows: Tensor) -> None:
        """Write ``params`` of ``rows`` into their simulations (and derived constants)."""
        if self.randomization is None:
            return
        ids = rows.numpy()
        p = self.params[rows].numpy()
        a, nom = self._arrays, self._nominal
        a["geom_friction"][ids[:, None], self._friction_geoms, 0] = p[:, 0:1]
        t = self._torso
        a["body_mass"][ids, t] = nom["body_mass"][t] + p[:, 1]
        a["body_ipos"][ids, t, 0] = nom["body_ipos"][t, 0] + p[:, 2]
        a["body_ipos"][ids, t, 1] = nom["body_ipos"][t, 1] + p[:, 3]
        kp = p[:, 4:5]
        a["actuator_gainprm"][ids, :, 0] = nom["actuator_gainprm"][None, :, 0] * kp
        a["actuator_biasprm"][ids, :, 1] = nom["actuator_biasprm"][None, :, 1] * kp
        a["actuator_forcerange"][ids] = nom["actuator_forcerange"][None] * p[:, 5, None, None]
        a["dof_damping"][ids[:, None], self._dofs] = nom["dof_damping"][self._dofs] * p[:, 6:7]
        a["dof_armature"][ids[:, None], self._dofs] = nom["dof_armature"][self._dofs] * p[:, 7:8]
        self.core.sim.batch.set_const(ids.astype(np.int32))

    def _schedule_push(self, rows: Tensor) -> None:
        """Draw the next kick of each env of ``rows``: when (from now) and how hard."""
        low, high = self.pushes.interval
        u = rng.uniform_rows(self.core.seed_value, rows, PUSH_STREAM, self.push_draws, 3)
        seconds = low + u[:, 0] * (high - low)
        steps = torch.ceil(seconds / self.core.control_dt).to(torch.long).clamp(min=1)
        self.push_countdown[rows] = steps
        speed = self.pushes.speed[0] + u[:, 1] * (self.pushes.speed[1] - self.pushes.speed[0])
        angle = u[:, 2] * (2.0 * math.pi)
        self.kick[rows] = torch.stack(
            (speed * exactmath.cos(angle), speed * exactmath.sin(angle)), dim=-1
        )

    # ------------------------------------------------------------ steps
    def before_step(self) -> None:
        """Kick the envs whose time has come (at this control-step boundary)."""
        self._noise_cache.clear()
        if self.pushes is None:
            return
        self.push_countdown -= 1
        due = self.push_countdown <= 0
        if not bool(due.any()):
            return
        rows = due.nonzero().squeeze(-1)
        ids = rows.numpy()
        self.core.sim.qvel[ids, 0:2] += self.kick[rows].numpy()
        self.pushes_done += ids.size
        self._schedule_push(rows)

    def delay(self, ctrl: np.ndarray) -> np.ndarray:
        """The servo targets each env applies, ``latency`` substeps late: the end of
        the last period's targets, then the start of this one's. (N, K, 12) -> same."""
        if self.randomization is None or self.randomization.latency == (0, 0):
            return ctrl
        current = torch.from_numpy(ctrl)
        k = ctrl.shape[1]
        both = torch.cat((self._held, current), dim=1)  # (N, 2K, 12)
        index = (k - self.latency)[:, None] + torch.arange(k)[None, :]
        applied = both.gather(1, index[:, :, None].expand(-1, -1, ctrl.shape[2]))
        self._held.copy_(current)
        return np.ascontiguousarray(applied.numpy())

    # ------------------------------------------------------------ pieces
    def normalised_params(self) -> Tensor:
        """The physics piece: each parameter centred and scaled. Shape: (N, 9)."""
        return (self.params - _CENTRE) / _SPREAD

    def noisy(self, name: str, value: Tensor) -> Tensor:
        """``value`` of the piece ``name`` plus this step's noise (the same noise for
        every read within one step). Shape: (N, D) -> (N, D)."""
        if self.noise is None:
            return value
        if name not in self._scale_cache:
            self._scale_cache[name] = self._scales(name, value.shape[-1])
        scales = self._scale_cache[name]
        if scales is None:
            return value
        noise = self._noise_cache.get(name)
        if noise is None:
            u = torch.rand(value.shape, dtype=torch.float64, generator=self._generator)
            noise = (2.0 * u - 1.0) * scales
            self._noise_cache[name] = noise
        return value + noise

    def _scales(self, name: str, width: int) -> Tensor | None:
        """Noise half-width of each value of the piece ``name``; None for an exact piece."""
        if name in ("observation", "observation_from_start"):
            pieces = self.core.task.pieces()
            parts = [
                self._scales(piece, pieces[piece].size) for piece in self.core.task.observation
            ]
            sizes = [pieces[piece].size for piece in self.core.task.observation]
            zeros = [torch.zeros(size, dtype=torch.float64) for size in sizes]
            scales = torch.cat([z if p is None else p for p, z in zip(parts, zeros, strict=True)])
            return scales if bool(scales.any()) else None
        if name == "sensors":
            return self.noise.sensor_scales()
        scale = getattr(self.noise, name) if name in _NOISE_PIECES else 0.0
        return torch.full((width,), float(scale), dtype=torch.float64) if scale > 0 else None

    def state(self) -> dict[str, Tensor]:
        """Per-env tensors to keep when the core is pickled."""
        return {
            "params": self.params, "physics_draws": self.physics_draws,
            "push_draws": self.push_draws, "latency": self.latency,
            "push_countdown": self.push_countdown, "kick": self.kick, "held": self._held,
        }  # fmt: skip


#: Pieces with a scale of their own in ObservationNoise.
_NOISE_PIECES = ("lateral_offset", "gait")
