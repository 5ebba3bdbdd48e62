"""``LagSmoothedPPO``: rsl-rl's PPO with a cost on the change of the actor's *mean*
action, priced by each sample's servo delay (``--lag-smoothness W``).

Beside PPO's loss, each minibatch's loss adds W x the mean over its samples of
L x Σ (μ(o_t) − μ̄_{t−1})², μ(o_t) the actor's mean action for the stored observation,
μ̄_{t−1} the mean the actor had for the step before in the same env when the rollout
was collected (``distribution_params``, no noise in it), and L the servo delay that
applied, in substeps (the piece ``servo_lag``: ``PhysicsRandomizer.lag``, 0 where no
delay applies). A sample without a step before it in the rollout (the rollout's first,
an episode's start) costs nothing, and where the servos do not lag the update is
PPO's alone. It is CAPS's temporal term (Mysore et al., ICRA 2021) with the earlier
step's side held at the rollout's values, so that shuffled minibatches need no pairs.

Two costs on the action's change were measured before it (docs/learning.md): a reward
on the change of the *sampled* action priced mostly the exploration noise, whose std
rsl-rl keeps one for every state (``Shaping.latency_action_rate``); the same cost as
this one against the *applied* action of the step before (commit 5b3e917) rewarded a
mean that follows the last step's noise, which the observation reveals. Measured on
the default's teacher (docs/learning.md, "A cost on the change of the policy's mean
action, priced by the delay", one seed): the delayed loop worse at every delay, more
with the weight; not in the default.

rsl-rl's ``PPO.update`` has no slot for a loss of one's own, so the cost's gradient
rides on the mean of the actor's distribution: during ``update`` a forward hook on the
actor registers, at each of PPO's stochastic forward passes (the one whose log
probabilities the surrogate reads; the mirror loss's deterministic pass is left alone),
a hook on that mean adding the cost's gradient to the one PPO's loss sends back. The
parameters' gradients are then those of PPO's loss plus the cost (tests/test_ppo.py
checks them against the cost added to the loss), clipped and stepped by rsl-rl. The
observations carry the group ``smoothing`` (``servo_lag``, then ``last_action`` as the
width and mirror of an action), which no model reads; before each update its action
part is overwritten with the previous step's mean (``pair_with_previous_means``).
``Loss/lag_smoothness`` logs the cost's mean (unweighted).
"""

from __future__ import annotations

import torch
from rsl_rl.algorithms import PPO
from torch import Tensor

#: The pieces of the observation group the cost reads: the delay, then an action's width
#: (its values replaced by the previous step's mean before each update).
SMOOTHING_OBS = ("servo_lag", "last_action")


def lag_cost(mean: Tensor, smoothing: Tensor) -> Tensor:
    """Each sample's L x Σ (μ − μ̄_prev)² (``smoothing``: L, then μ̄_prev).
    Shape: (B, A), (B, 1 + A) -> (B,)."""
    lag, last = smoothing[:, :1], smoothing[:, 1:]
    return (lag * (mean - last).square()).sum(dim=-1)


def lag_pull(mean: Tensor, smoothing: Tensor, weight: float) -> Tensor:
    """The gradient in ``mean`` of ``weight`` x the batch's mean ``lag_cost``:
    2 W L (μ − μ̄_prev) / B. Shape: (B, A)."""
    lag, last = smoothing[:, :1], smoothing[:, 1:]
    return (2.0 * weight / mean.shape[0]) * lag * (mean - last)


class LagSmoothedPPO(PPO):
    """rsl-rl's PPO plus ``lag_smoothness`` x the mean of L x Σ (μ − μ̄_prev)² over each
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

    def pair_with_previous_means(self) -> None:
        """Each stored sample's ``smoothing`` group pairs it with the rollout's mean action
        of the step before in its env (the actor's at rollout time: no noise in it); a
        sample with no such step in the rollout (its first step, an episode's start) has
        its delay set to 0, so that it costs nothing."""
        smoothing = self.storage.observations["smoothing"]  # (T, N, 1 + A)
        means = self.storage.distribution_params[0]  # (T, N, A)
        continuing = 1.0 - self.storage.dones[:-1].to(smoothing.dtype)  # (T - 1, N, 1)
        smoothing[1:, :, 1:] = means[:-1]
        smoothing[1:, :, :1] *= continuing
        smoothing[0, :, :1] = 0.0

    def update(self) -> dict[str, float]:
        """rsl-rl's update with the cost's gradient; ``lag_smoothness`` the cost's mean
        over the update's minibatches."""
        if not self.lag_smoothness:
            return super().update()
        self.pair_with_previous_means()
        self._sums = [0.0, 0]
        handle = self.actor.register_forward_hook(self._on_forward, with_kwargs=True)
        try:
            losses = super().update()
        finally:
            handle.remove()
        losses["lag_smoothness"] = self._sums[0] / max(1, self._sums[1])
        return losses
