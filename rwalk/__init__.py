"""rwalk: a massively-parallel CPU RL environment for residual corrections on a
Bézier trot of a small MuJoCo quadruped."""

# Everything is imported on first use (PEP 562): ``import rwalk.deploy`` runs where
# torch is absent, and the TorchRL views load torchrl only when asked for (importing
# torchrl switches the process's multiprocessing start method to spawn).
_HOMES = {
    "load_model": "rwalk.assets",
    "resolve_model_path": "rwalk.assets",
    "validate_model": "rwalk.assets",
    "EnvConfig": "rwalk.config",
    "Core": "rwalk.core",
    "ResidualWalkCore": "rwalk.core",
    "StepResult": "rwalk.core",
    "AdaptiveGaitEnv": "rwalk.envs.gym_env",
    "ResidualWalkEnv": "rwalk.envs.gym_env",
    "AdaptiveGaitVecEnv": "rwalk.envs.torchrl_env",
    "ResidualWalkVecEnv": "rwalk.envs.torchrl_env",
    "BezierGaitController": "rwalk.gait",
    "GaitParameters": "rwalk.gait",
    "LegGeometry": "rwalk.kinematics",
    "leg_fk": "rwalk.kinematics",
    "leg_ik": "rwalk.kinematics",
    "TerrainLevels": "rwalk.levels",
    "ObservationNoise": "rwalk.observations",
    "Pushes": "rwalk.perturbations",
    "Physics": "rwalk.physics",
    "Randomization": "rwalk.randomization",
    "GaitCosts": "rwalk.rewards",
    "RewardWeights": "rwalk.rewards",
    "BatchedSim": "rwalk.sim",
    "TASKS": "rwalk.tasks",
    "AdaptiveGaitConfig": "rwalk.tasks",
    "GaitBounds": "rwalk.tasks",
    "get_task": "rwalk.tasks",
}

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
    if name in _HOMES:
        import importlib

        return getattr(importlib.import_module(_HOMES[name]), name)
    raise AttributeError(f"module 'rwalk' has no attribute {name!r}")


def _register() -> None:
    try:
        import gymnasium
    except ImportError:  # a robot's runtime (rwalk.deploy) needs no Gymnasium
        return
    from rwalk.constants import EPISODE_STEPS  # torch loads later: a rank sets up first

    views = {GYM_ID: "ResidualWalkEnv", ADAPTIVE_GYM_ID: "AdaptiveGaitEnv"}
    for env_id, view in views.items():
        if env_id not in gymnasium.registry:
            # One episode length: make's TimeLimit (spec.max_episode_steps, the spec's 1000
            # unless make is given another); the env itself then has no limit of its own.
            gymnasium.register(
                id=env_id,
                entry_point=f"rwalk.envs.gym_env:{view}",
                max_episode_steps=EPISODE_STEPS,
                kwargs={"max_episode_steps": None},
            )


_register()
