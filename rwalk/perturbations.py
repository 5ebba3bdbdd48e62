"""Perturbations: what disturbs an episode while it runs (kicks to the torso, and a
steady force on it).

``Pushes`` configures them; ``PushSchedule`` gives each env its kicks at
control-step boundaries and its episode's steady force, vectorised over the batch.
Env i of a core seeded s draws its k-th kick (when, how hard, which way) from the
key (s + i, "push", k) of ``rwalk.rng`` and its k-th episode's force from
(s + i, "push_force", k), so the same seed gives the same kicks and forces at any
thread count (and a force range leaves the kicks' draws as they were).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from rwalk import exactmath, rng
from rwalk.randomization import check_range

#: Random stream of the kicks (see ``rwalk.rng``).
PUSH_STREAM = "push"
#: Random stream of the episodes' steady forces.
FORCE_STREAM = "push_force"
#: Largest steady force: 5 N is 0.64 of the 0.8 kg robot's weight. Newtons.
MAX_FORCE = 5.0
#: Env steps until a kick that is never due (a countdown of 2^62 steps: 2.9 billion years).
NEVER = float(2**62)


@dataclass(frozen=True)
class Pushes:
    """Horizontal velocity kicks to the torso, per env, at control-step boundaries."""

    speed: tuple[float, float] = (0.0, 0.15)
    """Magnitude of each kick, uniform in (min, max), in a uniformly random horizontal
    direction. m/s (x 0.8 kg = the impulse in N·s)."""
    interval: tuple[float, float] = (2.0, 5.0)
    """Time from an episode's start or a kick to the next kick, uniform. Seconds."""
    force: tuple[float, float] = (0.0, 0.0)
    """A steady horizontal force on the torso's centre of mass for a whole episode (a
    headwind, a tow): its magnitude uniform in (min, max), in a uniformly random
    horizontal direction, drawn at the episode's start. Newtons, at most 5 (MAX_FORCE; the
    robot weighs 7.8 N); (0, 0): none."""

    def __post_init__(self) -> None:
        check_range(self, "speed", 0.0)
        check_range(self, "interval", 0.0, above=True)
        check_range(self, "force", 0.0)
        if self.force[1] > MAX_FORCE:
            raise ValueError(f"Pushes.force must be at most {MAX_FORCE:g} N, got {self.force!r}")

    @property
    def steady(self) -> bool:
        """Whether the episodes have a steady force."""
        return self.force != (0.0, 0.0)


class PushSchedule:
    """The kicks of N envs.

    Args:
        pushes: the config's kicks (None: never).
        num_envs: N.
        control_dt: duration of one env step. Seconds.
        qvel: each simulation's joint velocities, a live view (the torso's free joint
            first). Shape: (N, nv).
        torso_force: each simulation's force on the torso, a live view
            (``BatchedSim.applied_force``). Shape: (N, 3).
    """

    def __init__(
        self, pushes: Pushes | None, num_envs: int, control_dt: float, qvel, torso_force
    ) -> None:
        self.pushes = pushes
        self.control_dt = control_dt
        self._qvel, self._torso_force = qvel, torso_force
        n = num_envs
        self.draws = torch.zeros(n, dtype=torch.long)
        """Kicks drawn so far by each env. Shape: (N,)."""
        self.countdown = torch.full((n,), torch.iinfo(torch.long).max, dtype=torch.long)
        """Env steps until each env's next kick. Shape: (N,)."""
        self.kick = torch.zeros(n, 2, dtype=torch.float64)
        """Each env's next kick: the change of the torso's (x, y) velocity. Shape: (N, 2). m/s."""
        self.force_draws = torch.zeros(n, dtype=torch.long)
        """Steady forces drawn so far by each env. Shape: (N,)."""
        self.force = torch.zeros(n, 2, dtype=torch.float64)
        """Each env's steady (x, y) force on the torso this episode. Shape: (N, 2). N."""
        self.done = 0
        """Kicks given so far (all envs)."""
        self._seed = 0

    def seed(self, seed: int) -> None:
        """Key the draws by ``seed`` (env i draws from seed + i) and restart them."""
        self._seed = seed
        self.draws.zero_()
        self.force_draws.zero_()

    def reset(self, rows: Tensor) -> None:
        """Draw the first kick and the steady force of each env of ``rows`` (its episode
        starts)."""
        if self.pushes is None:
            return
        self._schedule(rows)
        if self.pushes.steady:
            low, high = self.pushes.force
            u = rng.uniform_rows(self._seed, rows, FORCE_STREAM, self.force_draws, 2)
            self.force[rows] = _horizontal(low + u[:, 0] * (high - low), u[:, 1])

    def _schedule(self, rows: Tensor) -> None:
        """Draw the next kick of each env of ``rows``: when (from now) and how hard."""
        low, high = self.pushes.interval
        u = rng.uniform_rows(self._seed, rows, PUSH_STREAM, self.draws, 3)
        seconds = low + u[:, 0] * (high - low)
        # Clamped before the conversion: a huge interval (meant as "never") stays huge.
        steps = torch.ceil(seconds / self.control_dt).clamp(1.0, NEVER).to(torch.long)
        self.countdown[rows] = steps
        speed = self.pushes.speed[0] + u[:, 1] * (self.pushes.speed[1] - self.pushes.speed[0])
        self.kick[rows] = _horizontal(speed, u[:, 2])

    def before_step(self) -> None:
        """Put every env's steady force on its torso (a start just placed has none) and
        kick the envs whose time has come (at this control-step boundary)."""
        if self.pushes is None:
            return
        if self.pushes.steady:
            self._torso_force[:, 0:2] = self.force.numpy()
        self.countdown -= 1
        due = self.countdown <= 0
        if not bool(due.any()):
            return
        rows = due.nonzero().squeeze(-1)
        ids = rows.numpy()
        self._qvel[ids, 0:2] += self.kick[rows].numpy()
        self.done += ids.size
        self._schedule(rows)

    def state(self) -> dict[str, Tensor]:
        """Per-env tensors to keep when the core is pickled."""
        return {"draws": self.draws, "countdown": self.countdown, "kick": self.kick,
                "force_draws": self.force_draws, "force": self.force}  # fmt: skip


def _horizontal(size: Tensor, u: Tensor) -> Tensor:
    """Vectors of length ``size`` at the angles 2πu in the horizontal plane. Shape: (M, 2)."""
    angle = u * (2.0 * math.pi)
    return torch.stack((size * exactmath.cos(angle), size * exactmath.sin(angle)), dim=-1)
