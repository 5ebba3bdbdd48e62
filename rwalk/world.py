"""The world of a core: the model and everything derived from it once.

``World(config, num_envs)`` loads the MJCF world (or builds it around a map of
terrain levels), applies the config's physics overrides and terrain scale, and
derives the leg geometry, the timing (physics timestep, substeps per env step)
and the base gait controller. It checks that the timing can run the gait and
that N envs fit in memory before anything is allocated for them.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from rwalk.assets import load_model
from rwalk.config import EnvConfig
from rwalk.constants import JOINT_NAMES, OBS_DIM
from rwalk.gait import BezierGaitController
from rwalk.kinematics import LegGeometry
from rwalk.levels import TerrainMap, build_model
from rwalk.terrain import Terrain


class World:
    """Model, terrain, leg geometry, timing and gait controller of a config.

    Args:
        config: the task's config.
        num_envs: N, for the memory check.

    Raises:
        ValueError: naming the world file or the field, for a bad timestep, a cycle
            time the control rate cannot follow, or joints that are not consecutive.
        MemoryError: if N envs would not fit in the available memory.
    """

    def __init__(self, config: EnvConfig, num_envs: int) -> None:
        levels = config.terrain_levels
        self.terrain_map: TerrainMap | None = None
        """The map of terrain levels (``config.terrain_levels``), or None."""
        if levels is None:
            self.model = load_model(config.model_path)
        else:
            self.model, self.terrain_map = build_model(config.model_path, levels)
        config.physics.apply(self.model)
        self.terrain = Terrain(self.model)
        if self.terrain.is_heightfield and levels is None:
            self.terrain.set_scale(self.model, config.terrain_scale)
        self.geometry = LegGeometry.from_model(self.model)
        self.dt = float(self.model.opt.timestep)
        """Physics timestep. Seconds."""
        if not (self.dt > 0 and np.isfinite(self.dt)):
            raise ValueError(f"{config.model_path}: option timestep must be > 0, got {self.dt!r}")
        self.decimation = config.substeps(self.dt)
        """Physics substeps per env step."""
        self.control_dt = self.dt * self.decimation
        """Duration of one env step. Seconds."""
        self.controller = BezierGaitController(config.gait, self.geometry, dt=self.dt)
        if self.controller.period < 2 * self.decimation:
            raise ValueError(
                f"GaitParameters.cycle_time ({config.gait.cycle_time!r} s) must span at least 2 "
                f"control steps ({2 * self.control_dt:g} s at decimation {self.decimation} x "
                f"timestep {self.dt:g} s): the controller could not follow swing and stance"
            )
        self.settled_tick = config.settle_steps * self.decimation % self.controller.period
        """Gait tick (substeps from phase 0, modulo the cycle) where settling leaves a start."""
        joint_adr = [int(self.model.joint(name).qposadr[0]) for name in JOINT_NAMES]
        if joint_adr != list(range(joint_adr[0], joint_adr[0] + len(joint_adr))):
            raise ValueError(f"joints {JOINT_NAMES} must be consecutive in qpos")
        self.joint_qpos = slice(joint_adr[0], joint_adr[0] + len(joint_adr))
        """The 12 leg joints' slice of qpos."""
        check_memory(self.model, config, num_envs, self.decimation)

    def set_terrain_scale(self, scale: float, config: EnvConfig) -> None:
        """Scale the heightfield's roughness in the model (0 flat .. 1 full).

        Raises:
            ValueError: naming the world if its ground is a plane, or the config field
                (a terrain-levels map, or per-env physics) that rules it out.
        """
        if self.terrain_map is not None:
            raise ValueError(
                "set_terrain_scale cannot change a terrain-levels map: each env's level "
                "sets its ground (EnvConfig.terrain_levels)"
            )
        if config.randomization is not None:
            raise ValueError(
                "set_terrain_scale cannot change the ground of a core with per-env physics "
                "(EnvConfig.randomization): mujoco.batch keeps per-env fields only on one "
                "model; build the core with the terrain_scale you want instead"
            )
        try:
            self.terrain.set_scale(self.model, scale)
        except ValueError as error:
            raise ValueError(f"{config.model_path}: {error}") from None

    def base_gait_ctrl(self, substeps: int) -> np.ndarray:
        """Zero-residual servo targets from phase 0. Shape: (substeps, 12) float64."""
        ctrl, _ = self.controller.joint_targets(torch.zeros(1, dtype=torch.long), substeps)
        return np.ascontiguousarray(ctrl[0].numpy())


def check_memory(model, config: EnvConfig, num_envs: int, decimation: int) -> None:
    """Raise MemoryError at once if N envs would not fit, instead of failing mid-build.

    A conservative estimate per env: its integration state and sensor rows (in the
    batch, and in the pool), the torch buffers, and ~20 temporaries of each control
    period's (K, 4, 3) targets in the step (measured: ~9 KB per env at K = 10); plus the
    servo targets of settling, held once.
    """
    nstate = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_INTEGRATION.value)
    row = 8 * (nstate + model.nsensordata + 4 * OBS_DIM)
    per_env = row + 8 * 20 * decimation * 12
    settling = 8 * 12 * config.settle_steps * decimation
    needed = num_envs * per_env + config.settle_pool * row + settling
    available = available_memory()
    if available is not None and needed > available:
        raise MemoryError(
            f"num_envs={num_envs} needs about {needed / 2**30:.1f} GiB ({per_env / 1024:.1f} KiB "
            f"per env) but {available / 2**30:.1f} GiB is available"
        )


def available_memory() -> int | None:
    """MemAvailable from /proc/meminfo, in bytes (None where there is none)."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None
