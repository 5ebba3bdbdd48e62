"""Views of the residual-walk task: batched TorchRL env and Gymnasium single env.

``ResidualWalkVecEnv`` (and with it torchrl) is imported on first use.
"""

from rwalk.envs.gym_env import ResidualWalkEnv

__all__ = ["ResidualWalkEnv", "ResidualWalkVecEnv"]


def __getattr__(name: str):
    if name == "ResidualWalkVecEnv":
        from rwalk.envs.vec_env import ResidualWalkVecEnv

        return ResidualWalkVecEnv
    raise AttributeError(f"module 'rwalk.envs' has no attribute {name!r}")
