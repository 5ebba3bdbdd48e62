"""``SmoothDistillation``: rsl-rl's ``Distillation`` with a cost on the student's action
change from one step to the next (``--distill-smoothness``; CAPS's temporal term, Mysore et
al., ICRA 2021).

Beside the imitation's mean square error, each rollout step's loss adds ``smoothness``
times the mean over envs of the mean square of the student's action change since the step
before; a pair across an episode's start counts zero, and the first step of each pass over
the rollout has no pair. The gradient flows through both actions of a pair within one of
rsl-rl's gradient windows (``gradient_length`` steps), through the later one across a
window's edge. Measured on the default's teacher against the 16 ms delay's oscillation
(docs/learning.md, "A smoother student by a cost on its action change"): the actions
smoother, the delayed loop not; not in the default.

rsl-rl's ``Distillation.update`` computes its loss step by step, in the rollout's order,
through ``self.loss_fn(actions, teacher_actions)``; the cost rides on that call, so the
update itself stays rsl-rl's. ``Loss/behavior`` stays the imitation's alone and
``Loss/smoothness`` is the (unweighted) mean square change.
"""

from __future__ import annotations

import torch
from rsl_rl.algorithms import Distillation


class SmoothDistillation(Distillation):
    """rsl-rl's ``Distillation`` plus ``smoothness`` x the student's mean square action
    change per step (0: rsl-rl's own, the same bits)."""

    def __init__(self, *args, smoothness: float = 0.0, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.smoothness = float(smoothness)
        self._imitation = self.loss_fn
        self._calls = 0
        self._previous: torch.Tensor | None = None
        self._sums = [0.0, 0.0, 0]  # imitation, change, steps paired
        if self.smoothness:
            self.loss_fn = self._step_loss

    def _step_loss(self, actions: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """The loss of one rollout step: the imitation's, plus the weighted change since the
        step before where both lie in one episode and one pass over the rollout."""
        steps = self.storage.num_transitions_per_env
        step = self._calls % steps
        if self._calls % self.gradient_length == 0 and self._previous is not None:
            self._previous = self._previous.detach()  # the window before has stepped
        imitation = self._imitation(actions, target)
        loss = imitation
        self._sums[0] += imitation.item()
        if step > 0:
            same_episode = ~self.storage.dones[step - 1].view(-1).bool()
            per_env = (actions - self._previous).square().mean(dim=-1)
            change = (per_env * same_episode).sum() / per_env.numel()
            loss = loss + self.smoothness * change
            self._sums[1] += change.item()
            self._sums[2] += 1
        self._previous = actions
        self._calls += 1
        return loss

    def update(self) -> dict[str, float]:
        """rsl-rl's update; with a smoothness cost, ``behavior`` is the imitation's mean
        loss and ``smoothness`` the mean square change per step."""
        if not self.smoothness:
            return super().update()
        self._calls, self._previous, self._sums = 0, None, [0.0, 0.0, 0]
        losses = super().update()
        self._previous = None
        losses["behavior"] = self._sums[0] / max(1, self._calls)
        losses["smoothness"] = self._sums[1] / max(1, self._sums[2])
        return losses
