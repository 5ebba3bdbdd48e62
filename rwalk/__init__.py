"""rwalk: a massively-parallel CPU RL environment for residual corrections on a
Bézier trot of a small MuJoCo quadruped."""

from rwalk.assets import load_model, resolve_model_path, validate_model
from rwalk.config import EnvConfig
from rwalk.core import Core, ResidualWalkCore, StepResult
from rwalk.envs import AdaptiveGaitEnv, ResidualWalkEnv
from rwalk.gait import BezierGaitController, GaitParameters
from rwalk.kinematics import LegGeometry, leg_fk, leg_ik
from rwalk.levels import TerrainLevels
from rwalk.observations import ObservationNoise
from rwalk.perturbations import Pushes
from rwalk.physics import Physics
from rwalk.randomization import Randomization
from rwalk.rewards import GaitCosts, RewardWeights
from rwalk.sim import BatchedSim
from rwalk.tasks import TASKS, AdaptiveGaitConfig, GaitBounds, get_task

__all__ = [
    "TASKS",
    "AdaptiveGaitConfig",
    "AdaptiveGaitEnv",
    "AdaptiveGaitVecEnv",
    "BatchedSim",
    "BezierGaitController",
    "Core",
    "EnvConfig",
    "GaitBounds",
    "GaitCosts",
    "GaitParameters",
    "LegGeometry",
    "ObservationNoise",
    "Physics",
    "Pushes",
    "Randomization",
    "ResidualWalkCore",
    "ResidualWalkEnv",
    "ResidualWalkVecEnv",
    "RewardWeights",
    "StepResult",
    "TerrainLevels",
    "get_task",
    "leg_fk",
    "leg_ik",
    "load_model",
    "resolve_model_path",
    "validate_model",
]

GYM_ID = "rwalk/ResidualWalk-v0"
ADAPTIVE_GYM_ID = "rwalk/AdaptiveGait-v0"


def __getattr__(name: str):
    # The TorchRL view loads torchrl on first use only: importing torchrl switches the
    # process's multiprocessing start method to spawn, which `import rwalk` must not do.
    if name in ("ResidualWalkVecEnv", "AdaptiveGaitVecEnv"):
        from rwalk.envs import torchrl_env as vec_env

        return getattr(vec_env, name)
    raise AttributeError(f"module 'rwalk' has no attribute {name!r}")


def _register() -> None:
    import gymnasium

    views = {GYM_ID: "ResidualWalkEnv", ADAPTIVE_GYM_ID: "AdaptiveGaitEnv"}
    for env_id, view in views.items():
        if env_id not in gymnasium.registry:
            # One episode length: make's TimeLimit (spec.max_episode_steps, the spec's 1000
            # unless make is given another); the env itself then has no limit of its own.
            gymnasium.register(
                id=env_id,
                entry_point=f"rwalk.envs.gym_env:{view}",
                max_episode_steps=1000,
                kwargs={"max_episode_steps": None},
            )


_register()
