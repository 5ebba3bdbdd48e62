"""A curriculum of commanded speeds: start near the gait's speed, widen where it tracks.

``EnvConfig.command_range`` is cut into ``CommandCurriculum.bins`` equal bins. Each bin
has an integer weight from 0 to ``steps``; an episode's command is drawn from a bin with
probability proportional to its weight, then uniformly within it. At first only the bins
that overlap ``start`` have weight (all of it). An episode that runs its whole length
(a fall or a cut-short episode counts nothing: ``Task.judge_commands``) with a mean
|v_x - v*| of at most ``tolerance`` adds one to its bin's weight and to each
neighbour's (walk-these-ways' ``RewardThresholdCurriculum``: a bin's success unlocks the
commands next to it; legged_gym's ``update_command_curriculum`` widens one range the same
way). Weights never fall, so commands already learned stay in the mix.

The weights are integers and the draws come from the env's keyed streams, so the
curriculum is the same on every CPU.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

#: Most bins of a command curriculum.
MAX_BINS = 10_000
#: Most weight steps of a bin.
MAX_STEPS = 1_000


@dataclass(frozen=True)
class CommandCurriculum:
    """Which commanded speeds an episode draws from, widened as the policy tracks them."""

    bins: int = 12
    """Equal bins across ``command_range`` (12 over 0.03-0.27 m/s: 0.02 m/s each)."""
    start: tuple[float, float] = (0.12, 0.14)
    """Commands drawn at first: the bins that overlap (low, high), within command_range. m/s."""
    tolerance: float = 0.03
    """An episode tracked its command when it ran its whole length and its mean per-step
    |v_x - v*| was at most this. m/s."""
    steps: int = 5
    """A bin's full weight, in the steps one tracked episode adds to it and its neighbours
    (walk-these-ways: 0.2 of the full weight each)."""

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> ValueError:
            return ValueError(f"CommandCurriculum.{name} {why}, got {getattr(self, name)!r}")

        for name, top in (("bins", MAX_BINS), ("steps", MAX_STEPS)):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= top):
                raise bad(name, f"must be an integer in [1, {top}]")
        start = self.start
        if not (
            isinstance(start, tuple)
            and len(start) == 2
            and all(isinstance(v, (int, float)) and math.isfinite(v) for v in start)
            and start[0] <= start[1]
        ):
            raise bad("start", "must be LOW HIGH m/s, finite, with LOW <= HIGH")
        if not (isinstance(self.tolerance, (int, float)) and math.isfinite(self.tolerance)
                and self.tolerance > 0):  # fmt: skip
            raise bad("tolerance", "must be a finite speed > 0 m/s")

    def check_range(self, command_range: tuple[float, float] | None) -> None:
        """Refuse a ``command_range`` this curriculum cannot cut: none, or one without
        width, or one that ``start`` does not lie within.

        Raises:
            ValueError: naming the field and the values.
        """
        if command_range is None or not command_range[0] < command_range[1]:
            raise ValueError(
                f"EnvConfig.command_curriculum needs a command_range LOW HIGH with LOW < HIGH "
                f"to cut into bins, got {command_range!r}"
            )
        low, high = command_range
        if not low <= self.start[0] <= self.start[1] <= high:
            raise ValueError(
                f"CommandCurriculum.start {self.start!r} must lie within the command_range "
                f"{command_range!r}"
            )


class CommandWeights:
    """The bins' weights of one batch of envs, and the commands they draw.

    Args:
        curriculum: the config.
        command_range: (low, high) m/s, low < high (``CommandCurriculum.check_range``).
    """

    def __init__(self, curriculum: CommandCurriculum, command_range: tuple[float, float]) -> None:
        curriculum.check_range(command_range)
        self.curriculum = curriculum
        self.low = float(command_range[0])
        self.width = (float(command_range[1]) - self.low) / curriculum.bins
        """Width of a bin. m/s."""
        edges = self.low + self.width * torch.arange(curriculum.bins + 1, dtype=torch.float64)
        first, last = curriculum.start
        overlap = (edges[:-1] <= last) & (edges[1:] >= first)
        self.weights = overlap.long() * curriculum.steps
        """Each bin's weight, 0 to ``curriculum.steps``: at first full over ``start``, else
        0. Shape: (bins,) long."""

    def draw(self, u: Tensor) -> Tensor:
        """Commands from two uniform [0, 1) numbers per env: the first picks a bin by the
        weights, the second a speed within it. u: shape (M, 2) float64. Returns (M,) m/s."""
        bins = self.curriculum.bins
        total = torch.cumsum(self.weights, 0)
        picked = torch.searchsorted(total.to(torch.float64), u[:, 0] * float(total[-1]),
                                    right=True).clamp(max=bins - 1)  # fmt: skip
        return self.low + (picked.to(torch.float64) + u[:, 1]) * self.width

    def bin_of(self, command: Tensor) -> Tensor:
        """The bin each command lies in (the top edge in the last). Shape: (M,) long."""
        index = torch.floor((command - self.low) / self.width).long()
        return index.clamp(0, self.curriculum.bins - 1)

    def update(self, command: Tensor, walked: Tensor, speed_error: Tensor, fell: Tensor) -> None:
        """Episodes that ended: each tracked one (walked, no fall, mean |v_x - v*| within
        the tolerance) adds a step to its command's bin and to each neighbour's.

        Args:
            command: each episode's commanded speed. m/s.
            walked: its steps walked (0: no episode ended; it counts nothing).
            speed_error: its summed |v_x - v*|. m/s.
            fell: whether it ended in a fall.
            Each shape: (M,).
        """
        tracked = (walked > 0) & ~fell
        tracked &= speed_error <= self.curriculum.tolerance * walked.to(torch.float64)
        if not bool(tracked.any()):
            return
        bins = self.curriculum.bins
        hit = torch.zeros(bins + 2, dtype=torch.long)
        centre = self.bin_of(command[tracked]) + 1
        for shift in (-1, 0, 1):  # each bin and its neighbours, once per tracked episode
            hit.index_add_(0, centre + shift, torch.ones_like(centre))
        gained = self.weights + hit[1:-1]
        self.weights.copy_(gained.clamp(max=self.curriculum.steps))

    def load(self, saved: Tensor) -> str | None:
        """Go on from saved weights (a checkpoint's ``command_weights``); returns a line
        for the log where they are of another number of bins (the curriculum then starts
        again), else None.

        Raises:
            ValueError: naming the field, if the weights are not integers in [0, steps].
        """
        steps = self.curriculum.steps
        integers = isinstance(saved, Tensor) and saved.dtype in (torch.int32, torch.int64)
        if not (integers and saved.dim() == 1 and bool(((saved >= 0) & (saved <= steps)).all())):
            raise ValueError(f"command_weights must be a 1-D integer tensor of weights in "
                             f"[0, {steps}], got {saved!r}")  # fmt: skip
        if saved.numel() != self.curriculum.bins:
            return (f"command weights of {saved.numel()} bins, this run has "
                    f"{self.curriculum.bins}: the command curriculum starts again")  # fmt: skip
        self.weights.copy_(saved)
        return None

    def unlocked(self) -> tuple[float, float]:
        """(low, high) of the bins with weight: the commands drawn now. m/s."""
        open_bins = torch.nonzero(self.weights > 0).flatten()
        first, last = int(open_bins[0]), int(open_bins[-1])
        return self.low + first * self.width, self.low + (last + 1) * self.width

    def log(self) -> dict[str, Tensor]:
        """TensorBoard scalars: ``Curriculum/command_low`` and ``command_high`` (the
        unlocked commands' ends) and ``command_weight`` (the bins' mean share of full)."""
        low, high = self.unlocked()
        share = self.weights.to(torch.float64).mean() / self.curriculum.steps
        return {"Curriculum/command_low": torch.tensor(low, dtype=torch.float64),
                "Curriculum/command_high": torch.tensor(high, dtype=torch.float64),
                "Curriculum/command_weight": share}  # fmt: skip
