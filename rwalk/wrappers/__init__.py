"""Adapters of the batched env to training libraries."""

from rwalk.wrappers.rsl_rl import RslRlVecEnv

__all__ = ["RslRlVecEnv"]
