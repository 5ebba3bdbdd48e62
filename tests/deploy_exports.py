"""Export folders of small residual policies for the runtime's tests (needs torch: the
torch-free run of tests/test_deploy_runtime.py gets them from RWALK_DEPLOY_EXPORTS)."""

from __future__ import annotations

import contextlib
import dataclasses
import io
from pathlib import Path

import numpy as np

#: The policies exported, by folder: an MLP and a GRU of the residual task's robust run
#: (observation from start; the GRU also reads its last action), a commanded GRU of the
#: adaptive task ("target" actions) and a commanded MLP of it whose gait follows the
#: speed's schedule ("schedule" actions) and that reads its last action (16 values).
POLICIES = {
    "mlp": {"actor": "mlp"},
    "gru": {"actor": "gru",
            "policy_obs": ("observation_from_start", "phase", "lateral_offset", "last_action")},
    "adaptive": {"actor": "gru", "task": "adaptive_gait", "command_range": (0.05, 0.25),
                 "gait_action": "target"},
    "schedule": {"actor": "mlp", "task": "adaptive_gait", "command_range": (0.05, 0.25),
                 "gait_action": "schedule",
                 "policy_obs": ("observation_from_start", "phase", "lateral_offset", "command",
                                "last_action")},
}  # fmt: skip
#: The readings of the starts (a file beside the folders): env i's sensors after reset.
READINGS = "readings.npy"


def make_exports(root: Path) -> Path:
    """Write ``root/<name>`` for each of ``POLICIES`` and ``root/readings.npy``; the policies'
    weights are moved off their initial values so that their outputs (and states) show."""
    import torch

    from rwalk.export import export_policy
    from rwalk.rl.config import TrainArgs
    from rwalk.rl.runner import SafeRunner
    from rwalk.rl.training import make_env, rsl_rl_config

    for seed, (name, flags) in enumerate(POLICIES.items()):
        torch.manual_seed(seed)
        args = dataclasses.replace(
            TrainArgs(), num_envs=3, settle_steps=20, max_episode_steps=50, hidden_dims=(16,),
            robust=True, rnn_hidden_dim=8, **flags,
        )  # fmt: skip
        with contextlib.redirect_stdout(io.StringIO()):
            runner = SafeRunner(make_env(args), rsl_rl_config(args), log_dir=None, device="cpu")
        with torch.no_grad():
            for parameter in runner.alg.get_policy().parameters():
                parameter.add_(0.3 * torch.randn_like(parameter))
        export_policy(runner, root / name)
        if name == "mlp":
            np.save(root / READINGS, runner.env.core.sim.sensordata.copy())
    return root
