"""Observation pieces: named blocks of values the views assemble, each with its noise.

A piece is declared once as an ``ObsPiece``: its width, the function that reads
it from the core's parts (``Sources``), what it holds, and the half-width of the
uniform noise a policy sees on it when the config has ``observation_noise``
(a number, or a function of the ``ObservationNoise`` config; None: exact).
Every task offers ``COMMON_PIECES`` plus its own (``Task.pieces``); the TorchRL
keys, the rsl-rl groups, the export's input layout and the noise all come from
these declarations.

Two pieces are built from the task's own list of pieces (``Task.observation``):
``observation``, the task's spec observation, and ``observation_from_start``,
the same with the torso's x and y taken from the episode's start, so that a
policy cannot read where on a map it is.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import Tensor

from rwalk import mirror as mirrors
from rwalk import rng
from rwalk.constants import (
    OBS_ANGVEL,
    OBS_DIM,
    OBS_FOOT_POS,
    OBS_FOOT_VEL,
    OBS_JOINT_POS,
    OBS_JOINT_VEL,
    OBS_LINVEL,
    OBS_POS,
    OBS_QUAT,
)
from rwalk.mirror import Mirror
from rwalk.randomization import PHYSICS_PARAMS
from rwalk.terrain import Terrain

#: Random stream of the observation noise (see ``rwalk.rng``).
NOISE_STREAM = "obs_noise"
#: The task's spec observation, and the same with x, y from the episode's start.
COMPOSITE = ("observation", "observation_from_start")


@dataclass(frozen=True)
class ObservationNoise:
    """Half-widths of uniform noise added to the policy's observation, per block.

    The sensor blocks are the ``sensors`` piece's noise (and so the spec observation's,
    wherever its 65 values appear); the others that of the pieces they name.
    Contacts stay exact. Pieces declared with a fixed noise (``ObsPiece.noise``) get
    it whenever a config has an ``ObservationNoise``.
    """

    torso_pos: float = 0.005
    """Half-width of the torso position's noise. m."""
    torso_quat: float = 0.01
    """Half-width of the torso orientation quaternion's noise (each component)."""
    torso_linvel: float = 0.015
    """Half-width of the torso velocity's noise. m/s (about 10% of the walking speed, like
    legged_gym's 0.1 m/s at ~1 m/s)."""
    torso_forward_speed: float | None = None
    """Half-width of the noise on the torso velocity's forward (x) component alone, and
    on the pieces read from it (``cycle_speed``). m/s; None: ``torso_linvel``'s."""
    torso_angvel: float = 0.1
    """Half-width of the torso angular velocity's noise. rad/s."""
    joint_pos: float = 0.01
    """Half-width of the joint angles' noise. rad."""
    joint_vel: float = 0.3
    """Half-width of the joint speeds' noise. rad/s."""
    foot_pos: float = 0.002
    """Half-width of the foot positions' noise (torso frame). m."""
    foot_vel: float = 0.03
    """Half-width of the foot velocities' noise (torso frame). m/s."""
    lateral_offset: float = 0.005
    """Half-width of the lateral offset piece's noise. m."""
    gait: float = 0.0
    """Half-width of the noise on the adaptive task's gait parameters (normalised)."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None and f.name == "torso_forward_speed":
                continue
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
        scales[OBS_LINVEL.start] = self.forward_speed
        return scales

    @property
    def forward_speed(self) -> float:
        """Half-width of the noise on the torso's forward speed (m/s)."""
        return self.torso_linvel if self.torso_forward_speed is None else self.torso_forward_speed


class Sources(NamedTuple):
    """What pieces read: the core's parts (live objects, updated in place)."""

    sensors: Tensor
    """The spec's 65 sensor values of each env (contacts as 0/1). Shape: (N, 65)."""
    episodes: Any
    """``rwalk.episodes.Episodes``: x0, y0 of each episode."""
    physics: Any
    """``rwalk.randomization.PhysicsDraws``: each env's drawn physics."""
    terrain: Terrain
    """Ground heights."""
    task: Any
    """The ``rwalk.tasks.Task``: gait phase, targets, its own state."""
    sim: Any
    """The ``rwalk.sim.BatchedSim``: every simulation's arrays (qvel, actuator_force, ...)."""


Noise = float | Callable[[ObservationNoise], "Tensor | float"] | None


class ObsPiece(NamedTuple):
    """A named block of observation values."""

    size: int
    read: Callable[[Sources], Tensor]
    """The block for every env, float64. Shape: (N, size)."""
    doc: str
    noise: Noise = None
    """Half-width of the uniform noise on each value when the config has observation
    noise: a number, a function of the ``ObservationNoise`` config giving a number or
    one per value (Shape: (size,)), or None (never noisy)."""
    mirror: Mirror | None = None
    """The piece of the robot's left-right mirrored state (``rwalk.mirror``), for
    symmetry augmentation; None: the piece has none declared (a run that mirrors refuses
    it, naming it)."""


#: Ground samples around each foot for the privileged pieces, in world axes: under the
#: foot, and 3 cm ahead, behind, left and right of it. Metres.
HEIGHT_OFFSETS = ((0.0, 0.0), (0.03, 0.0), (-0.03, 0.0), (0.0, 0.03), (0.0, -0.03))
#: Pieces a critic (or a teacher) adds to the policy's by default: the world the actor
#: cannot see.
PRIVILEGED_PIECES = ("physics", "heights")
#: Every piece only a simulation has: PRIVILEGED_PIECES and those a teacher may read
#: instead (--teacher-obs); a student and a deployed policy read none of them.
SIMULATOR_PIECES = (*PRIVILEGED_PIECES, "heights_under_feet")


def _rotation(sensors: Tensor) -> tuple[tuple[Tensor, Tensor, Tensor], ...]:
    """Rows of the torso's rotation matrix (torso frame to world) from its quaternion
    sensor, each entry (N,)."""
    w, x, y, z = sensors[:, OBS_QUAT].unbind(-1)
    return (
        (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)),
        (2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)),
        (2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)),
    )


def _rotate(rotation, local: Tensor, origin: Tensor | None = None) -> list[Tensor]:
    """World x, y, z of torso-frame vectors (plus ``origin``, added first), each (N, 4).

    Args:
        local: the vectors in the torso frame. Shape: (N, 4, 3).
        origin: a world point to add. Shape: (N, 3).
    """
    out = []
    for i, row in enumerate(rotation):
        total = row[0][:, None] * local[..., 0]
        if origin is not None:
            total = origin[:, i, None] + total
        out.append(total + row[1][:, None] * local[..., 1] + row[2][:, None] * local[..., 2])
    return out


def foot_clearances(sensors: Tensor, terrain: Terrain,
                    samples: Sequence[tuple[float, float]] = HEIGHT_OFFSETS) -> Tensor:  # fmt: skip
    """Height of each foot above the ground at ``samples`` (x, y offsets, world axes)
    around it, foot-major.

    The feet's world positions come from the torso's position and orientation and the
    feet's positions in the torso frame (the observation's sensors), with elementwise
    products and sums only. Shape: (N, 65) -> (N, 4 * len(samples)) float64. Metres.
    """
    n = sensors.shape[0]
    world = _rotate(_rotation(sensors), sensors[:, OBS_FOOT_POS].view(n, 4, 3),
                    sensors[:, OBS_POS])  # fmt: skip
    offsets = torch.tensor(samples, dtype=torch.float64)
    ground = terrain.heights_at(
        world[0][..., None] + offsets[:, 0], world[1][..., None] + offsets[:, 1]
    )
    return (world[2][..., None] - ground).reshape(n, -1)


def foot_velocities(sensors: Tensor) -> Tensor:
    """Each foot's world velocity: v + ω × (R r) + R v_rel, from the torso's velocity and
    angular velocity (world frame) and the feet's positions r and velocities v_rel in the
    torso frame (the observation's sensors). Shape: (N, 65) -> (N, 4, 3) float64. m/s."""
    n = sensors.shape[0]
    rotation = _rotation(sensors)
    r = _rotate(rotation, sensors[:, OBS_FOOT_POS].view(n, 4, 3))
    v_rel = _rotate(rotation, sensors[:, OBS_FOOT_VEL].view(n, 4, 3))
    v = [sensors[:, OBS_LINVEL.start + i, None] for i in range(3)]
    w = [sensors[:, OBS_ANGVEL.start + i, None] for i in range(3)]
    spin = (w[1] * r[2] - w[2] * r[1], w[2] * r[0] - w[0] * r[2], w[0] * r[1] - w[1] * r[0])
    return torch.stack([v[i] + spin[i] + v_rel[i] for i in range(3)], -1)


def _lateral_offset(s: Sources) -> Tensor:
    return (s.sensors[:, OBS_POS.start + 1] - s.episodes.y0).unsqueeze(-1)


def _heights_under_feet(s: Sources) -> Tensor:
    return foot_clearances(s.sensors, s.terrain, HEIGHT_OFFSETS[:1])


#: Where each sample of HEIGHT_OFFSETS lands in the mirrored state (+y <-> -y).
HEIGHT_MIRROR = (0, 1, 2, 4, 3)

#: Pieces every task has. ``sensors`` is the spec's 65-D observation.
COMMON_PIECES: dict[str, ObsPiece] = {
    "sensors": ObsPiece(OBS_DIM, lambda s: s.sensors,
                        "the spec's 65 values: torso, joints, feet, contacts",
                        noise=ObservationNoise.sensor_scales, mirror=mirrors.SENSORS),
    "phase": ObsPiece(2, lambda s: s.task.phase_features(), "sin, cos of 2π x the gait phase",
                      mirror=mirrors.PHASE),
    "lateral_offset": ObsPiece(1, _lateral_offset,
                               "torso y - y0, the drift the lateral term sees (m)",
                               noise=lambda cfg: cfg.lateral_offset, mirror=mirrors.signed((-1,))),
    "command": ObsPiece(1, lambda s: s.task.target.unsqueeze(-1),
                        "the episode's target velocity (m/s; config.command_range)",
                        mirror=mirrors.identity(1)),
    "cycle_speed": ObsPiece(1, lambda s: s.episodes.cycle_speed().unsqueeze(-1),
                            "the torso's forward speed averaged over the last gait cycle (m/s)",
                            noise=lambda cfg: cfg.forward_speed / 4, mirror=mirrors.identity(1)),
    "physics": ObsPiece(len(PHYSICS_PARAMS), lambda s: s.physics.normalised_params(),
                        "privileged: the env's randomised physics, centred and scaled "
                        "(rwalk.randomization)",
                        mirror=mirrors.signed([p.mirror for p in PHYSICS_PARAMS])),
    "servo_lag": ObsPiece(1, lambda s: s.physics.lag().unsqueeze(-1).to(torch.float64),
                          "privileged: the servo delay that applies, in substeps (0 without "
                          "one; rwalk.randomization.PhysicsRandomizer.lag)",
                          mirror=mirrors.identity(1)),
    "heights": ObsPiece(4 * len(HEIGHT_OFFSETS),
                        lambda s: foot_clearances(s.sensors, s.terrain),
                        "privileged: each foot's height above the ground under it and 3 cm "
                        "around it (m)", mirror=mirrors.per_leg_with_samples(HEIGHT_MIRROR)),
    "heights_under_feet": ObsPiece(4, _heights_under_feet,
                                   "privileged: each foot's height above the ground under it "
                                   "(m; heights' first sample)",
                                   mirror=mirrors.per_leg_with_samples((0,))),
}  # fmt: skip


def piece_catalog(
    pieces: Mapping[str, ObsPiece], observation: Sequence[str]
) -> dict[str, tuple[int, str]]:
    """Size and content of every piece a task offers: the composites ``observation`` and
    ``observation_from_start`` (of the pieces ``observation``), then ``pieces``."""
    size = sum(pieces[name].size for name in observation)
    spec = (
        "the spec's 65-D observation (docs/environment.md)"
        if tuple(observation) == ("sensors",)
        else f"the task's spec observation: pieces {' + '.join(observation)}"
    )
    return {
        "observation": (size, spec),
        "observation_from_start": (
            size,
            "the spec observation with the torso's x, y minus their values at the episode's "
            "start (info['start_position'])",
        ),
        **{name: (piece.size, piece.doc) for name, piece in pieces.items()},
    }


class Observations:
    """Reads a task's pieces, and the noisy ones a policy sees.

    Args:
        pieces: every piece of the task (``Task.pieces()``).
        observation: the pieces of the task's spec observation, in order.
        sources: what the pieces read.
        noise: the config's observation noise; None: every piece exact.
    """

    def __init__(
        self,
        pieces: Mapping[str, ObsPiece],
        observation: Sequence[str],
        sources: Sources,
        noise: ObservationNoise | None,
    ) -> None:
        self.pieces = dict(pieces)
        self.observation = tuple(observation)
        self.catalog = piece_catalog(pieces, observation)
        """Size and content of every piece a view may ask for."""
        self.sources = sources
        self.noise = noise
        self.steps = torch.zeros(sources.sensors.shape[0], dtype=torch.long)
        """Steps each env has taken since the core was seeded (its noise counter). (N,)."""
        self._seed = 0
        self._noise_cache: dict[str, Tensor] = {}
        self._scale_cache: dict[str, Tensor | None] = {}  # per piece: fixed by the config

    def size(self, name: str) -> int:
        """Width of the piece ``name``.

        Raises:
            ValueError: naming the piece and listing the task's pieces.
        """
        if name not in self.catalog:
            self._piece(name)  # raises, naming it
        return self.catalog[name][0]

    def read(self, name: str) -> Tensor:
        """The piece ``name`` of every env, exact. Shape: (N, size) float64.

        Raises:
            ValueError: naming the piece and listing the task's pieces.
        """
        if name == "observation":
            if self.observation == ("sensors",):
                return self.sources.sensors
            return torch.cat([self.read(part) for part in self.observation], dim=-1)
        if name == "observation_from_start":
            obs = self.read("observation").clone()
            obs[:, OBS_POS.start] -= self.sources.episodes.x0
            obs[:, OBS_POS.start + 1] -= self.sources.episodes.y0
            return obs
        return self._piece(name).read(self.sources)

    def _piece(self, name: str) -> ObsPiece:
        if name not in self.pieces:
            raise ValueError(f"no observation piece {name!r}; choose from {tuple(self.catalog)}")
        return self.pieces[name]

    # ------------------------------------------------------------ noise
    def seed(self, seed: int) -> None:
        """Key the noise by ``seed`` and restart every env's step count."""
        self._seed = seed
        self.steps.zero_()
        self._noise_cache.clear()

    def new_step(self) -> None:
        """A step begins: the next reads draw new noise."""
        self.steps += 1
        self._noise_cache.clear()

    def _draw(self, name: str, width: int) -> Tensor:
        """Uniform [0, 1) numbers of piece ``name`` for every env at its current step:
        env i's from the key (seed + i, "obs_noise/<name>", its step count), so env i of
        any batch sees the noise of a single env seeded seed + i. Shape: (N, width)."""
        with np.errstate(over="ignore"):  # seed + i wraps modulo 2^64
            seeds = np.uint64(self._seed) + np.arange(len(self.steps), dtype=np.uint64)
        keys = rng.keys(seeds, f"{NOISE_STREAM}/{name}", self.steps.numpy().astype(np.uint64))
        return torch.from_numpy(rng.uniform(keys, width))

    def noisy(self, name: str, value: Tensor | None = None) -> Tensor:
        """The piece ``name`` (``value``: already read) plus this step's noise (the same
        noise for every read within one step). Shape: (N, size)."""
        value = self.read(name) if value is None else value
        if self.noise is None:
            return value
        if name not in self._scale_cache:
            self._scale_cache[name] = self.scales(name)
        scales = self._scale_cache[name]
        if scales is None:
            return value
        noise = self._noise_cache.get(name)
        if noise is None:
            noise = (2.0 * self._draw(name, value.shape[-1]) - 1.0) * scales
            self._noise_cache[name] = noise
        return value + noise

    def state(self) -> dict[str, Tensor]:
        """Per-env tensors to keep when the core is pickled."""
        return {"steps": self.steps}

    def mirror(self, name: str) -> Mirror:
        """The left-right mirror of the piece ``name`` (``rwalk.mirror``).

        Raises:
            ValueError: naming the piece, if it declares none.
        """
        if name in COMPOSITE:
            return mirrors.concat(self.mirror(part) for part in self.observation)
        declared = self._piece(name).mirror
        if declared is None:
            raise ValueError(f"observation piece {name!r} declares no mirror (ObsPiece.mirror)")
        return declared

    def scales(self, name: str) -> Tensor | None:
        """Noise half-width of each value of the piece ``name`` under the config's
        observation noise; None for an exact piece. Shape: (size,) float64."""
        if self.noise is None:
            return None
        if name in COMPOSITE:
            parts = [self.scales(part) for part in self.observation]
            zeros = [torch.zeros(self.pieces[part].size, dtype=torch.float64)
                     for part in self.observation]  # fmt: skip
            scales = torch.cat([z if p is None else p for p, z in zip(parts, zeros, strict=True)])
            return scales if bool(scales.any()) else None
        piece = self._piece(name)
        if piece.noise is None:
            return None
        scale = piece.noise(self.noise) if callable(piece.noise) else piece.noise
        if isinstance(scale, Tensor):
            return scale
        scale = float(scale)
        return torch.full((piece.size,), scale, dtype=torch.float64) if scale > 0 else None
