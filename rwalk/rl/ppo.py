"""``LagSmoothedPPO``: rsl-rl's PPO with a cost on the change of the actor's *mean*
action, priced by each sample's servo delay (``--lag-smoothness W``).

Beside PPO's loss, each minibatch's loss adds W x the mean over its samples of
L x Σ (μ(o) − a_last)², μ(o) the actor's mean action for the stored observation, a_last
the action the env applied the step before (the piece ``last_action``: zero at an
episode's start) and L the servo delay that applied, in substeps (``servo_lag``:
``PhysicsRandomizer.lag``, 0 where no delay applies). Where the servos do not lag the
policy is PPO's alone. A sampled a_last carries the exploration noise, but the cost's
gradient in μ, 2 W L (μ − a_last) / B, averages to the pull toward the last mean: the
cost smooths the mean and never the noise, unlike a reward on the action's change
(``Shaping.latency_action_rate``, docs/learning.md: it priced mostly the noise, whose std
rsl-rl keeps one for every state, and the teacher cut it everywhere). It is CAPS's
temporal term (Mysore et al., ICRA 2021) on the mean, against the previous step's
applied action, so that shuffled minibatches need no pairs.

rsl-rl's ``PPO.update`` has no slot for a loss of one's own, so the cost's gradient
rides on the mean of the actor's distribution: during ``update`` a forward hook on the
actor registers, at each of PPO's stochastic forward passes (the one whose log
probabilities the surrogate reads; the mirror loss's deterministic pass is left alone),
a hook on that mean adding the cost's gradient to the one PPO's loss sends back. The
parameters' gradients are then those of PPO's loss plus the cost (tests/test_ppo.py
checks them against the cost added to the loss), clipped and stepped by rsl-rl. The
observations carry the group ``smoothing`` (``servo_lag``, ``last_action``), which no
model reads. ``Loss/lag_smoothness`` logs the cost's mean (unweighted).
"""

from __future__ import annotations

import torch
from rsl_rl.algorithms import PPO
from torch import Tensor

#: The pieces of the observation group the cost reads: the delay, then the last action.
SMOOTHING_OBS = ("servo_lag", "last_action")


def lag_cost(mean: Tensor, smoothing: Tensor) -> Tensor:
    """Each sample's L x Σ (μ − a_last)². Shape: (B, A), (B, 1 + A) -> (B,)."""
    lag, last = smoothing[:, :1], smoothing[:, 1:]
    return (lag * (mean - last).square()).sum(dim=-1)


def lag_pull(mean: Tensor, smoothing: Tensor, weight: float) -> Tensor:
    """The gradient in ``mean`` of ``weight`` x the batch's mean ``lag_cost``:
    2 W L (μ − a_last) / B. Shape: (B, A)."""
    lag, last = smoothing[:, :1], smoothing[:, 1:]
    return (2.0 * weight / mean.shape[0]) * lag * (mean - last)


class LagSmoothedPPO(PPO):
    """rsl-rl's PPO plus ``lag_smoothness`` x the mean of L x Σ (μ − a_last)² over each
    minibatch (0: PPO's update as it is)."""

    def __init__(self, *args, lag_smoothness: float = 0.0, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.lag_smoothness = float(lag_smoothness)
        self._sums = [0.0, 0]  # cost, passes

    def _on_forward(self, actor, args, kwargs, output) -> None:
        """After a stochastic forward pass with gradients: the cost's gradient joins
        the one reaching the distribution's mean."""
        if not (kwargs.get("stochastic_output") and torch.is_grad_enabled()):
            return
        mean = actor.output_mean
        smoothing = args[0]["smoothing"]
        with torch.no_grad():
            pull = lag_pull(mean, smoothing, self.lag_smoothness)
            self._sums[0] += lag_cost(mean, smoothing).mean().item()
            self._sums[1] += 1
        mean.register_hook(lambda grad: grad + pull)

    def update(self) -> dict[str, float]:
        """rsl-rl's update with the cost's gradient; ``lag_smoothness`` the cost's mean
        over the update's minibatches."""
        if not self.lag_smoothness:
            return super().update()
        self._sums = [0.0, 0]
        handle = self.actor.register_forward_hook(self._on_forward, with_kwargs=True)
        try:
            losses = super().update()
        finally:
            handle.remove()
        losses["lag_smoothness"] = self._sums[0] / max(1, self._sums[1])
        return losses
