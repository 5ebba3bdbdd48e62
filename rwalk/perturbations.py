"""Perturbations: events that disturb an episode while it runs (kicks to the torso).

``Pushes`` configures them; ``PushSchedule`` gives each env its kicks at
control-step boundaries, vectorised over the batch. Env i of a core seeded s
draws its k-th kick (when, how hard, which way) from the key (s + i, "push", k)
of ``rwalk.rng``, so the same seed gives the same kicks at any thread count.
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

    def __post_init__(self) -> None:
        check_range(self, "speed", 0.0)
        check_range(self, "interval", 0.0, above=True)


class PushSchedule:
    """The kicks of N envs.

    Args:
        pushes: the config's kicks (None: never).
        num_envs: N.
        control_dt: duration of one env step. Seconds.
        qvel: each simulation's joint velocities, a live view (the torso's free joint
            first). Shape: (N, nv).
    """

    def __init__(self, pushes: Pushes | None, num_envs: int, control_dt: float, qvel) -> None:
        self.pushes = pushes
        self.control_dt = control_dt
        self._qvel = qvel
        n = num_envs
        self.draws = torch.zeros(n, dtype=torch.long)
        """Kicks drawn so far by each env. Shape: (N,)."""
        self.countdown = torch.full((n,), torch.iinfo(torch.long).max, dtype=torch.long)
        """Env steps until each env's next kick. Shape: (N,)."""
        self.kick = torch.zeros(n, 2, dtype=torch.float64)
        """Each env's next kick: the change of the torso's (x, y) velocity. Shape: (N, 2). m/s."""
        self.done = 0
        """Kicks given so far (all envs)."""
        self._seed = 0

    def seed(self, seed: int) -> None:
        """Key the draws by ``seed`` (env i draws from seed + i) and restart them."""
        self._seed = seed
        self.draws.zero_()

    def reset(self, rows: Tensor) -> None:
        """Draw the first kick of each env of ``rows`` (its episode starts)."""
        if self.pushes is not None:
            self._schedule(rows)

    def _schedule(self, rows: Tensor) -> None:
        """Draw the next kick of each env of ``rows``: when (from now) and how hard."""
        low, high = self.pushes.interval
        u = rng.uniform_rows(self._seed, rows, PUSH_STREAM, self.draws, 3)
        seconds = low + u[:, 0] * (high - low)
        # Clamped before the conversion: a huge interval (meant as "never") stays huge.
        steps = torch.ceil(seconds / self.control_dt).clamp(1.0, NEVER).to(torch.long)
        self.countdown[rows] = steps
        speed = self.pushes.speed[0] + u[:, 1] * (self.pushes.speed[1] - self.pushes.speed[0])
        angle = u[:, 2] * (2.0 * math.pi)
        self.kick[rows] = torch.stack(
            (speed * exactmath.cos(angle), speed * exactmath.sin(angle)), dim=-1
        )

    def before_step(self) -> None:
        """Kick the envs whose time has come (at this control-step boundary)."""
        if self.pushes is None:
            return
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
        return {"draws": self.draws, "countdown": self.countdown, "kick": self.kick}
