"""Views of the residual-walk task: batched TorchRL env and Gymnasium single env."""

from rwalk.envs.gym_env import ResidualWalkEnv
from rwalk.envs.vec_env import ResidualWalkVecEnv

__all__ = ["ResidualWalkEnv", "ResidualWalkVecEnv"]
