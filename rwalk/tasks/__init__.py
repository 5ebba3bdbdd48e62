"""The task registry: every view and runner takes a task by name.

Adding a task is one module (a ``Task`` subclass, see ``rwalk.tasks.base``) and
one line here.
"""

from __future__ import annotations

from rwalk.config import EnvConfig
from rwalk.tasks.adaptive_gait import AdaptiveGait, AdaptiveGaitConfig, GaitBounds
from rwalk.tasks.base import ObsPiece, Task
from rwalk.tasks.residual_walk import ResidualWalk

TASKS: dict[str, type[Task]] = {
    ResidualWalk.name: ResidualWalk,
    AdaptiveGait.name: AdaptiveGait,
}


def get_task(name: str) -> type[Task]:
    """The task class registered as ``name``.

    Raises:
        ValueError: naming the unknown task and listing the known ones.
    """
    try:
        return TASKS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown task {name!r}; known tasks: {sorted(TASKS)}") from None


def task_for_config(config: EnvConfig) -> type[Task]:
    """The task whose config class is exactly ``type(config)``."""
    for task in TASKS.values():
        if type(config) is task.config_type:
            return task
    raise TypeError(f"no task takes a {type(config).__name__}; known tasks: {sorted(TASKS)}")


__all__ = [
    "TASKS", "AdaptiveGait", "AdaptiveGaitConfig", "GaitBounds", "ObsPiece", "ResidualWalk",
    "Task", "get_task", "task_for_config",
]  # fmt: skip
