"""The TorchRL trainer's algorithm, models and collectors, as one config dataclass.

``TorchRLConfig`` is to ``rwalk-train-torchrl`` what ``rwalk.rl.config.TrainConfig``
is to ``rwalk-train``: its fields are the trainer's flags (their docstrings the
help), checked on creation with messages that name the flag. Kept apart from the
trainer (``rwalk.rl.torchrl_ppo``) and the collectors (``rwalk.rl.torchrl_collect``),
which both read it, and free of torchrl imports.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from tyro.conf import OmitArgPrefixes

from rwalk.rl.config import Env, Preset, RunSettings, TrainingBase
from rwalk.validation import require_at_least, require_in, require_positive

BACKENDS = ("process", "ray", "distributed")
"""Values of ``--backend``."""


@dataclass(frozen=True)
class TorchRLConfig:
    """TorchRL's PPO (GAE, ClipPPOLoss), its TanhNormal actor and value network, and the
    collector workers that gather its frames."""

    num_steps_per_env: int = 32
    """rollout length per iteration"""
    num_learning_epochs: int = 4
    """PPO epochs per iteration"""
    num_mini_batches: int = 4
    """minibatches per epoch"""
    learning_rate: float = 3e-4
    """Adam step"""
    gamma: float = 0.99
    """discount"""
    lmbda: float = 0.95
    """GAE lambda"""
    clip_epsilon: float = 0.2
    """PPO ratio clip"""
    entropy_coef: float = 1e-4
    """entropy bonus"""
    init_noise_std: float = 0.1
    """initial pre-tanh action std"""
    reward_scale: float = 1e-3
    """reward multiplier for PPO (the env's reward is the spec's, ~300 per step)"""
    hidden_dims: tuple[int, ...] = (128, 128)
    """MLP layers of the actor and the critic"""
    collectors: int = 1
    """collector workers, each stepping its own --num-envs envs (1 with the process
    backend: the envs step in this process)"""
    backend: str = "process"
    """where collector workers run: process (local processes), distributed
    (torch.distributed with gloo, local processes) or ray (pip install -e ".[ray]")"""

    def __post_init__(self) -> None:
        require_at_least(
            self, 1, "num_steps_per_env", "num_learning_epochs", "num_mini_batches", "collectors"
        )
        if self.backend not in BACKENDS:
            known = ", ".join(BACKENDS)
            raise ValueError(f"--backend must be one of {known}, got {self.backend!r}")
        require_at_least(self, 0, "entropy_coef")
        require_positive(self, "learning_rate", "init_noise_std", "reward_scale", "clip_epsilon")
        require_in(self, "gamma", 0.0, 1.0, low_open=True)
        require_in(self, "lmbda", 0.0, 1.0)
        if not self.hidden_dims or min(self.hidden_dims) < 1:
            raise ValueError(f"--hidden-dims must be sizes >= 1, got {self.hidden_dims}")

    def frames_per_batch(self, num_envs: int) -> int:
        """Frames of one iteration: every worker's ``num_envs`` envs for
        ``num_steps_per_env`` steps."""
        return self.collectors * num_envs * self.num_steps_per_env

    def check_batch(self, num_envs: int) -> None:
        """Each minibatch must hold a frame, with ``num_envs`` envs per worker.

        Raises:
            ValueError: ``--num-mini-batches must be <= --num-envs * --num-steps-per-env
                = <frames>, got <n>`` (``--collectors * `` first with several workers).
        """
        frames = self.frames_per_batch(num_envs)
        if self.num_mini_batches > frames:
            product = "--num-envs * --num-steps-per-env"
            if self.collectors > 1:
                product = "--collectors * " + product
            raise ValueError(
                f"--num-mini-batches must be <= {product} = {frames}, got {self.num_mini_batches}"
            )


@dataclass(frozen=True)
class TorchRLTraining(TrainingBase[Env]):
    """An rwalk-train-torchrl run: the envs as rwalk-train's, TorchRL's PPO and
    collectors, and the run (every field a flag; config.json holds it)."""

    num_envs: int = 256
    """parallel envs (with collectors: per worker)"""
    preset: OmitArgPrefixes[Preset] = field(default_factory=lambda: Preset(recipe="plain"))
    """The task and world the configs started from (PPO alone: --recipe plain)."""
    train: OmitArgPrefixes[TorchRLConfig] = field(default_factory=TorchRLConfig)
    """TorchRL's PPO, models and collectors."""
    run: OmitArgPrefixes[RunSettings] = field(
        default_factory=lambda: RunSettings(log_dir="logs/torchrl", max_iterations=50)
    )
    """Where the run writes and how long it runs."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.preset.own_recipe is not None:
            raise ValueError(f"--recipe {self.preset.recipe} trains a teacher and its "
                             f"student (rwalk-train); rwalk-train-torchrl trains --recipe "
                             f"plain")  # fmt: skip
        self.train.check_batch(self.num_envs)  # a minibatch holds a frame
