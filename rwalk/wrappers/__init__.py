"""Adapters of the batched env to training libraries (``rwalk.rl``; kept for old imports)."""

from rwalk.rl.rsl_rl_env import RslRlVecEnv

__all__ = ["RslRlVecEnv"]
