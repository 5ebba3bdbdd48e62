"""Views of the tasks: batched TorchRL envs and Gymnasium single envs.

The TorchRL views (and with them torchrl) are imported on first use.
"""

from rwalk.envs.gym_env import AdaptiveGaitEnv, ResidualWalkEnv

__all__ = ["AdaptiveGaitEnv", "AdaptiveGaitVecEnv", "ResidualWalkEnv", "ResidualWalkVecEnv"]


def __getattr__(name: str):
    if name in ("ResidualWalkVecEnv", "AdaptiveGaitVecEnv"):
        from rwalk.envs import torchrl_env as vec_env

        return getattr(vec_env, name)
    raise AttributeError(f"module 'rwalk.envs' has no attribute {name!r}")
