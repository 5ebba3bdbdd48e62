"""rwalk: a massively-parallel CPU RL environment for residual corrections on a
Bézier trot of a small MuJoCo quadruped."""

from rwalk.assets import load_model, resolve_model_path, validate_model
from rwalk.config import EnvConfig
from rwalk.core import ResidualWalkCore, StepResult
from rwalk.envs import ResidualWalkEnv, ResidualWalkVecEnv
from rwalk.gait import BezierGaitController, GaitParameters
from rwalk.kinematics import LegGeometry, leg_fk, leg_ik
from rwalk.rewards import RewardWeights
from rwalk.sim import BatchedSim

__all__ = [
    "BatchedSim",
    "BezierGaitController",
    "EnvConfig",
    "GaitParameters",
    "LegGeometry",
    "ResidualWalkCore",
    "ResidualWalkEnv",
    "ResidualWalkVecEnv",
    "RewardWeights",
    "StepResult",
    "leg_fk",
    "leg_ik",
    "load_model",
    "resolve_model_path",
    "validate_model",
]

GYM_ID = "rwalk/ResidualWalk-v0"


def _register() -> None:
    import gymnasium

    if GYM_ID not in gymnasium.registry:
        gymnasium.register(id=GYM_ID, entry_point="rwalk.envs.gym_env:ResidualWalkEnv")


_register()
