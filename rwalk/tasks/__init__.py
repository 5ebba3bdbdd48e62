"""Tasks over the core, and their registry (``rwalk.tasks.registry``).

Adding a task is one module (a ``Task`` subclass, see ``rwalk.tasks.base``) and
one line in ``TASKS``.
"""

from rwalk.tasks.adaptive_gait import AdaptiveGait, AdaptiveGaitConfig, GaitBounds
from rwalk.tasks.base import Task
from rwalk.tasks.registry import TASKS, get_task, resolve, task_for_config
from rwalk.tasks.residual_walk import ResidualWalk

__all__ = [
    "TASKS", "AdaptiveGait", "AdaptiveGaitConfig", "GaitBounds", "ResidualWalk", "Task",
    "get_task", "resolve", "task_for_config",
]  # fmt: skip
