"""The batched tasks as TorchRL ``EnvBase``s: ``BatchedEnv`` (any task), and by task
``ResidualWalkVecEnv`` and ``AdaptiveGaitVecEnv``."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import ClassVar

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from rwalk.config import EnvConfig
from rwalk.core import Core
from rwalk.tasks.base import Task
from rwalk.tasks.registry import get_task


class BatchedEnv(EnvBase):
    """N envs of a task stepped together (``batch_size=(num_envs,)``).

    Keys (all float32 unless noted; N = num_envs):

    - ``observation`` (N, 65): the spec's observation (see docs/environment.md).
    - ``phase`` (N, 2): sin and cos of 2π x the gait phase (not in the spec).
    - ``lateral_offset`` (N, 1): y - y0, the drift the lateral penalty sees (not in the spec).
    - any other extra piece of the task (``command`` of a commanded adaptive task).
    - ``action`` (N, action_dim) in [-1, 1], as the task lays it out (residual_walk: 12
      foot residuals FL, FR, RL, RR x (x, y, z)); clipped.
    - ``reward`` (N, 1), ``done`` / ``terminated`` / ``truncated`` (N, 1) bool.
    - ``("reward_terms", name)`` (N, 1): each weighted reward term; they sum to ``reward``.
    - ``diverged`` (N, 1) bool: the simulation blew up this step (also terminated).
    - with ``groups``, one key per group (N, D): its pieces concatenated, float32.
      The group ``policy`` reads them with this step's observation noise (the config's
      ``observation_noise``; the same noise in every read of a step), every other group
      exactly. The keys above stay as they are (exact).

    Partial resets follow the ``"_reset"`` mask; reset envs are settled in one
    batched rollout. Seeding goes through ``set_seed``: env i of a batch seeded
    s starts exactly like a single env of the task seeded s + i.

    Args:
        num_envs: N.
        config: the task's config; None: the task's defaults (the spec's).
        seed: seed for the starts; None draws one from the OS.
        device: only "cpu" (the simulation runs on the CPU).
        task: a registry name or ``Task`` class; None: the class's ``task``, else the task
            whose config class ``config`` is.
        groups: observation groups as keys: group name -> its pieces (names of
            ``rwalk.observations``), or a function of the task giving them (for rules
            that read the task's extras, as ``rwalk.rl.config.observation_groups``).
            None: no group keys.

    Raises:
        ValueError: a group named like another key, without pieces, or with an unknown
            piece (naming it).
    """

    #: The task when none is named (None: the config's).
    task: ClassVar[str | None] = None
    #: The group read with observation noise (the one a policy acts on); others are exact.
    NOISY_GROUP: ClassVar[str] = "policy"

    def __init__(
        self,
        num_envs: int,
        config: EnvConfig | None = None,
        seed: int | None = None,
        device: str | torch.device = "cpu",
        task: str | type[Task] | None = None,
        groups: Mapping[str, Sequence[str]]
        | Callable[[Task], Mapping[str, Sequence[str]]]
        | None = None,
    ) -> None:
        if torch.device(device).type != "cpu":
            raise ValueError(f"{type(self).__name__} runs on the CPU only, got device {device!r}")
        task = task or self.task
        if config is None:
            config = (get_task(task) if isinstance(task, str) else task or Task).config_type()
        self.core = Core(config, num_envs, seed=seed, task=task)
        super().__init__(device="cpu", batch_size=torch.Size([num_envs]))
        self.rng = torch.Generator()
        if seed is not None:
            self.rng.manual_seed(seed)
        n = num_envs
        core = self.core
        self.extras = core.task.extras()
        """Keys of the task's pieces beside the observation."""
        self.groups = self._check_groups(groups(core.task) if callable(groups) else groups)
        """Observation groups: key -> its pieces, in the order they are concatenated."""
        pieces = {
            name: Bounded(-1.0, 1.0, shape=(n, 2), dtype=torch.float32)
            if name == "phase"
            else Unbounded(shape=(n, core.piece_size(name)), dtype=torch.float32)
            for name in ("observation", *self.extras)
        }
        widths = {
            group: sum(core.piece_size(name) for name in names)
            for group, names in self.groups.items()
        }
        self.observation_spec = Composite(
            **pieces,
            **{g: Unbounded(shape=(n, w), dtype=torch.float32) for g, w in widths.items()},
            reward_terms=Composite(
                {t.name: Unbounded(shape=(n, 1), dtype=torch.float32) for t in core.terms},
                shape=(n,),
            ),
            diverged=Unbounded(shape=(n, 1), dtype=torch.bool),
            shape=(n,),
        )
        self.action_spec = Bounded(-1.0, 1.0, shape=(n, core.task.action_dim), dtype=torch.float32)
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float32)
        flag = Categorical(2, shape=(n, 1), dtype=torch.bool)
        self.done_spec = Composite(
            done=flag.clone(), terminated=flag.clone(), truncated=flag.clone(), shape=(n,)
        )

    def _check_groups(
        self, groups: Mapping[str, Sequence[str]] | None
    ) -> dict[str, tuple[str, ...]]:
        taken = ("observation", *self.extras, "reward_terms", "diverged", "action", "reward",
                 "done", "terminated", "truncated", "_reset")  # fmt: skip
        checked = {}
        for group, names in (groups or {}).items():
            if group in taken:
                raise ValueError(
                    f"observation group {group!r} would replace the env's key {group!r}; "
                    "give it another name"
                )
            if isinstance(names, str) or not names:
                raise ValueError(
                    f"observation group {group!r} must be a sequence of piece names, got {names!r}"
                )
            for name in names:
                self.core.piece_size(name)  # ValueError naming an unknown piece
            checked[group] = tuple(names)
        return checked

    @property
    def config(self) -> EnvConfig:
        return self.core.config

    @property
    def num_envs(self) -> int:
        return self.core.num_envs

    @property
    def expected_velocity(self) -> float:
        """step_length / cycle_time of the (starting) gait. m/s."""
        return self.core.config.expected_velocity

    def set_terrain_scale(self, scale: float) -> None:
        """Scale the terrain's roughness for every env (0 flat .. 1 full)."""
        self.core.set_terrain_scale(scale)

    # ------------------------------------------------------------------ EnvBase
    def _reset(self, tensordict: TensorDictBase | None, **kwargs) -> TensorDictBase:
        mask = None if tensordict is None else tensordict.get("_reset", None)
        n = self.num_envs
        if mask is not None and (
            mask.dtype != torch.bool or tuple(mask.shape) not in ((n,), (n, 1))
        ):
            raise ValueError(
                f'"_reset" must be a boolean mask of shape ({n},) or ({n}, 1), got dtype '
                f"{mask.dtype} and shape {tuple(mask.shape)}"
            )
        if mask is None or not self.core.started:
            self.core.reset()
        else:
            self.core.reset(mask.reshape(-1))
        zeros = torch.zeros(n, dtype=torch.float64)
        no = torch.zeros(n, dtype=torch.bool)
        out = self._outputs({t.name: zeros for t in self.core.terms}, zeros, no, no, no)
        return out.exclude("reward")

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        r = self.core.step(tensordict.get("action"))
        return self._outputs(r.terms, r.reward, r.diverged, r.terminated, r.truncated)

    def _outputs(
        self,
        terms: dict[str, torch.Tensor],
        reward: torch.Tensor,
        diverged: torch.Tensor,
        terminated: torch.Tensor,
        truncated: torch.Tensor,
    ) -> TensorDict:
        core = self.core
        keys = ("observation", *self.extras)
        wanted = dict.fromkeys((*keys, *(n for names in self.groups.values() for n in names)))
        exact = {name: core.piece(name) for name in wanted}  # each piece read once
        noisy = core.observations.noisy
        groups = {
            group: torch.cat(
                [noisy(n, exact[n]) if group == self.NOISY_GROUP else exact[n] for n in names],
                dim=-1,
            ).to(torch.float32)
            for group, names in self.groups.items()
        }
        return TensorDict(
            {
                **{name: exact[name].to(torch.float32) for name in keys},
                **groups,
                "reward_terms": {
                    name: term.to(torch.float32).unsqueeze(-1) for name, term in terms.items()
                },
                "reward": reward.to(torch.float32).unsqueeze(-1),
                "diverged": diverged.unsqueeze(-1),
                "terminated": terminated.unsqueeze(-1),
                "truncated": truncated.unsqueeze(-1),
                "done": (terminated | truncated).unsqueeze(-1),
            },
            batch_size=self.batch_size,
        )

    def _set_seed(self, seed: int | None) -> None:
        used = self.core.seed(seed)
        self.rng.manual_seed(used)


class ResidualWalkVecEnv(BatchedEnv):
    """N residual-walk envs (ResidualWalkEnv.md) stepped together: ``BatchedEnv`` of the
    residual task unless ``task`` names another."""

    task: ClassVar[str | None] = "residual_walk"


class AdaptiveGaitVecEnv(BatchedEnv):
    """N adaptive-gait envs (AdaptiveGaitEnv.md) stepped together.

    Keys as ``BatchedEnv``, but ``observation`` is (N, 69) (the 65 values,
    then the four gait parameters normalised to [-1, 1]) and ``action`` (N, 16)
    (four gait deltas, then the 12 residuals). With ``command_range`` set in the
    config, ``command`` (N, 1) holds each episode's target velocity (m/s).
    """

    task: ClassVar[str] = "adaptive_gait"
