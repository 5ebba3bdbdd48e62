"""The task registry: task names to task classes, resolved by one function.

Views, runners and the core take a task by name or class; only ``get_task``
and ``resolve`` look names up. Adding a task is one module (a ``Task``
subclass, see ``rwalk.tasks.base``) and one line in ``TASKS``.
"""

from __future__ import annotations

from rwalk.config import EnvConfig
from rwalk.tasks.adaptive_gait import AdaptiveGait
from rwalk.tasks.base import Task
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


def resolve(task: type[Task] | str | None, config: EnvConfig) -> type[Task]:
    """The task of a core: a class as given, a registered name, or (None) the task whose
    config class ``config`` is.

    Raises:
        ValueError: an unknown name (listing the known ones), or a config of another task.
    """
    if task is None:
        task_type = task_for_config(config)
    elif isinstance(task, type) and issubclass(task, Task):
        task_type = task
    else:
        task_type = get_task(task)
    if type(config) is not task_type.config_type:
        raise ValueError(
            f"task {task_type.name!r} takes a {task_type.config_type.__name__}, got a "
            f"{type(config).__name__}"
        )
    return task_type
