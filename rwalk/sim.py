"""N MuJoCo simulations stepped together on a persistent thread pool.

A thin layer over ``mujoco.batch.Batch`` (MuJoCo >= 4.0), which runs
``mujoco.rollout``'s open-loop control sequences over per-simulation state
rows. Each row is the full ``mjSTATE_INTEGRATION`` state, so the solver
warmstart is carried from one call to the next (plain ``mujoco.rollout``
returns only ``mjSTATE_FULLPHYSICS`` and so restarts it from zero). One MjData
per worker thread serves all rows; results are bit-identical at any thread
count.
"""

from __future__ import annotations

import contextlib
import logging
import time

import mujoco
import numpy as np
from mujoco import batch as mjbatch

from rwalk.threads import cores

#: MuJoCo's warnings (e.g. an unstable simulation) go here instead of MUJOCO_LOG.TXT.
MUJOCO_LOGGER = logging.getLogger("rwalk.mujoco")


def _log_mujoco_warning(message: str) -> None:
    MUJOCO_LOGGER.warning(message)


# Without a handler MuJoCo appends every warning to MUJOCO_LOG.TXT in the working folder,
# unbounded. A handler the user installed first is left in place.
if mujoco.get_mju_user_warning() is None:
    mujoco.set_mju_user_warning(_log_mujoco_warning)


class BatchedSim:
    """``num_sims`` simulations of one model.

    Args:
        model: the compiled model (copied by the batch; see ``set_model``).
        num_sims: number of simulations (rows).
        num_threads: worker threads including the caller's; 0 for every core this process
            may run on (``rwalk.threads.cores``: its CPU affinity).
    """

    def __init__(self, model: mujoco.MjModel, num_sims: int, num_threads: int = 0) -> None:
        if num_sims < 1:
            raise ValueError(f"num_sims must be >= 1, got {num_sims!r}")
        if num_threads < 0:
            raise ValueError(f"num_threads must be >= 0 (0 = all cores), got {num_threads!r}")
        self.model = model
        self.batch = mjbatch.Batch(model, nsim=num_sims, nthread=num_threads or cores())
        self.num_sims = num_sims
        # Outputs must be bound before the calls that fill them.
        self.sensordata: np.ndarray = self.batch.bind("sensordata")
        """Sensor values of each row's last substep. Shape: (num_sims, nsensordata)."""
        self.qpos: np.ndarray = self.batch.bind("qpos")
        """Live view of each row's joint positions. Shape: (num_sims, nq)."""
        self.qvel: np.ndarray = self.batch.bind("qvel")
        """Live view of each row's joint velocities. Shape: (num_sims, nv)."""
        self.actuator_force: np.ndarray = self.batch.bind("actuator_force")
        """Servo torques of each row's last substep. Shape: (num_sims, nu)."""
        self.state: np.ndarray = self.batch.state
        """Live integration-state rows (warmstart included). Shape: (num_sims, nstate)."""
        # warning rows are mjWarningStat (lastinfo, number) per warning type
        self._warnings = self.batch.warning[..., 1]
        self.rollout_seconds = 0.0
        """Wall time spent in rollouts so far (a counter for benchmarks). Seconds."""

    def applied_force(self, body: int) -> np.ndarray:
        """Live view of the force MuJoCo applies to ``body``'s centre of mass in each row
        (``xfrc_applied[body, :3]``, world frame), part of the integration state: it
        stays on through rollouts until changed; a reset row starts at zero.
        Shape: (num_sims, 3). Newtons."""
        below = mujoco.mjtState.mjSTATE_XFRC_APPLIED.value - 1  # the state's earlier parts
        start = mujoco.mj_stateSize(self.model, below) + 6 * body
        return self.state[:, start : start + 3]

    @property
    def num_threads(self) -> int:
        return self.batch.nthread

    def set_model(self, model: mujoco.MjModel) -> None:
        """Run every row on ``model`` (same sizes), e.g. after editing its terrain."""
        self.model = model
        self.batch.set_models(model)

    def reset(self, ids: np.ndarray | None = None) -> None:
        """Reset rows to the model's defaults (zero warmstart) without computing anything."""
        self.batch.reset(ids, stage=mujoco.mjtStage.mjSTAGE_NONE.value)

    def forward(self, ids: np.ndarray | None = None) -> np.ndarray:
        """Compute sensors at the rows' current states.

        Returns:
            Rows whose computation failed. Shape: (M,) bool, M = len(ids) or num_sims.
        """
        return self._guard(lambda: self.batch.forward(ids), ids)

    def rollout(self, ctrl: np.ndarray, ids: np.ndarray | None = None) -> np.ndarray:
        """Advance rows by K substeps under an open-loop control sequence.

        Args:
            ctrl: servo targets per substep, C-contiguous float64.
                Shape: (M, K, nu), M = len(ids) or num_sims.
            ids: sorted row indices, or None for all rows.

        Returns:
            Rows that diverged or raised (MuJoCo has reset those to the model's
            defaults). Shape: (M,) bool.
        """
        nstep = ctrl.shape[1]
        start = time.perf_counter()
        try:
            return self._guard(lambda: self.batch.rollout(nstep, ctrl, record=(), ids=ids), ids)
        finally:
            self.rollout_seconds += time.perf_counter() - start

    def rollout_all(self, ctrl: np.ndarray) -> bool:
        """``rollout(ctrl)`` for every row, for tiny batches: one flag for all rows.

        Args:
            ctrl: servo targets, C-contiguous float64. Shape: (num_sims, K, nu).

        Returns:
            Whether any row diverged or raised (MuJoCo has reset those rows).
        """
        start = time.perf_counter()
        with contextlib.suppress(mjbatch.SimulationError):
            self.batch.rollout(ctrl.shape[1], ctrl, record=())
        self.rollout_seconds += time.perf_counter() - start
        return bool(self._warnings.any()) or bool(self.batch.status.any())

    def _guard(self, call, ids: np.ndarray | None) -> np.ndarray:
        # On an error, status marks the failed rows; the others ran to completion.
        with contextlib.suppress(mjbatch.SimulationError):
            call()
        rows = slice(None) if ids is None else ids
        return (self._warnings[rows].sum(axis=-1) > 0) | (self.batch.status[rows] != 0)
