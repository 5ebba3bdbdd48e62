"""The residual-walk task (spec: ResidualWalkEnv.md): 12 foot residuals on a fixed trot.

The gait is the controller's table, looked up by an integer tick per env: the
fast path, and the same bits as the single env's float pipeline
(``rwalk.envs.single_step``).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from rwalk import mirror
from rwalk.constants import ACTION_DIM
from rwalk.mirror import Mirror
from rwalk.tasks.base import Recipe, Task


class ResidualWalk(Task):
    """Action (N, 12): (x, y, z) foot offsets of FL, FR, RL, RR x residual_scale metres."""

    name = "residual_walk"
    action_dim = ACTION_DIM
    action_layout = "12 foot residuals (FL, FR, RL, RR x x, y, z)"
    single_step = True
    # the last third at the model's physics: the recipe's last 140 of 420, plain's 100 of 300
    nominal_physics_share = 1 / 3
    # --recipe plain's last 50 of 300 with the speed kernel at 200 (the recipe has the
    # kernel from the first iteration and --late-iterations 0; docs/learning.md)
    late_stage = (1 / 6, {"late_tracking": 200.0})
    # the adaptive default's recipe on this task: a teacher that reads the drawn physics
    # and the ground under its feet, distilled into a blind GRU student, the gait costs
    # with power x2, the speed kernel from the first iteration; servos drawn from 0.75-1.15
    # of their gain and torque, a latency of 0-3 substeps and actions of +-30 mm (weak
    # servos met issue 32's floors with them on two seeds), and three times the noise on
    # the forward speed the policy reads (the delayed loop runs through it: latency's
    # error down on four seeds), its student on half the teacher's envs (the same floors
    # on four teachers in about half the student's time; docs/learning.md)
    recipe = Recipe(
        env_fields={
            "costs.power": 2.0, "shaping.tracking": 300.0, "shaping.sigma": 0.02,
            "terrain_levels.kinds": ("flat", "rough", "slopes", "steps", "stones"),
            "randomization.kp_scale": (0.75, 1.15), "randomization.force_scale": (0.75, 1.15),
            "randomization.latency": (0, 3), "residual_scale": 0.03,
            "observation_noise.torso_forward_speed": 0.045,
        },
        train={"teacher": True, "teacher_obs": ("physics", "heights_under_feet"),
               "student_iterations": 160, "student_actor": "gru", "distill_levels": True,
               "late_iterations": 0},
        max_iterations=420, student_env_share=0.5,
    )  # fmt: skip

    def __init__(self, config, world, num_envs: int) -> None:
        super().__init__(config, world, num_envs)
        self.tick = torch.zeros(num_envs, dtype=torch.long)
        """Physics substeps since gait phase 0, modulo the cycle, at the start of the
        next step. Shape: (N,)."""

    @classmethod
    def action_mirror(cls) -> Mirror:
        return mirror.RESIDUALS

    @classmethod
    def deploy_spec(cls, core) -> dict:
        """The gait's tables, exact: the runtime looks targets up by tick, as the env does."""
        controller = core.controller
        gait = {"targets": controller.target_table.tolist(),
                "phase_features": controller.phase_table.tolist()}  # fmt: skip
        return {"runtime": "table", "gait": gait}

    def reset(self, rows: Tensor) -> None:
        self.tick[rows] = self.world.settled_tick

    def act(self, action: Tensor) -> tuple[np.ndarray, Tensor]:
        controller = self.world.controller
        residuals = action.view(self.num_envs, 4, 3) * self.config.residual_scale
        k = self.world.decimation
        ctrl, _ = controller.joint_targets(self.tick, k, residuals)
        swing = controller.is_swing(self.tick + (k - 1))
        # In place, like every state update of a step: callers step inside
        # torch.inference_mode (rsl-rl does) and reset outside it.
        self.tick.add_(k).remainder_(controller.period)
        return ctrl.numpy(), swing

    @property
    def phase(self) -> Tensor:
        return self.world.controller.phase(self.tick)

    @property
    def sensed_phase(self) -> Tensor:
        return self.world.controller.phase(self.tick - 1)

    def phase_features(self) -> Tensor:
        return self.world.controller.phase_features(self.tick)

    def state(self) -> dict[str, Tensor]:
        return super().state() | {"tick": self.tick}
