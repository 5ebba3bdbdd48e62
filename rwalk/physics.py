"""Physics settings applied over a world file's ``<option>`` and foot contacts.

The world files hold the adopted defaults (``docs/physics.md`` says how they were
chosen); a ``Physics`` with every field None changes nothing. The fidelity
harness (``rwalk-fidelity``) builds its reference and candidates from these.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import mujoco
import numpy as np

from rwalk.constants import FOOT_GEOMS

SOLVERS = {"PGS": mujoco.mjtSolver.mjSOL_PGS, "CG": mujoco.mjtSolver.mjSOL_CG,
           "Newton": mujoco.mjtSolver.mjSOL_NEWTON}  # fmt: skip
CONES = {"pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL, "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC}
INTEGRATORS = {"Euler": mujoco.mjtIntegrator.mjINT_EULER,
               "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
               "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
               "RK4": mujoco.mjtIntegrator.mjINT_RK4}  # fmt: skip
CONDIMS = (1, 3, 4, 6)


#: Longest physics timestep a config may ask for. Seconds.
MAX_TIMESTEP = 0.1
#: Most solver (and line-search) iterations a config may ask for (MuJoCo's default: 100).
MAX_ITERATIONS = 10_000


@dataclass(frozen=True)
class Physics:
    """Overrides of the world's physics; None keeps the world file's value."""

    timestep: float | None = None
    """Physics step. Seconds."""
    integrator: str | None = None
    """One of ``INTEGRATORS``."""
    solver: str | None = None
    """Constraint solver: one of ``SOLVERS``."""
    iterations: int | None = None
    """Most solver iterations per step."""
    ls_iterations: int | None = None
    """Most line-search iterations per solver iteration (CG, Newton)."""
    tolerance: float | None = None
    """Solver tolerance (0 runs every iteration)."""
    cone: str | None = None
    """Friction cone: one of ``CONES``."""
    foot_condim: int | None = None
    """Contact dimensionality of the foot geoms: 1, 3, 4 or 6."""
    foot_solref: tuple[float, float] | None = None
    """(time constant s, damping ratio) of the foot contacts."""

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> ValueError:
            return ValueError(f"Physics.{name} {why}, got {getattr(self, name)!r}")

        for name, table in (("integrator", INTEGRATORS), ("solver", SOLVERS), ("cone", CONES)):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, str) and value in table):
                raise bad(name, f"must be one of {sorted(table)}")
        for name, high in (("timestep", MAX_TIMESTEP), ("tolerance", 1.0)):
            value = getattr(self, name)
            if value is None:
                continue
            positive = name == "timestep"
            if not (
                _is_number(value)
                and math.isfinite(value)
                and (value > 0 if positive else value >= 0)
            ):
                raise bad(name, "must be a finite number " + ("> 0" if positive else ">= 0"))
            if value > high:
                raise bad(name, f"must be at most {high:g}")
        for name in ("iterations", "ls_iterations"):
            value = getattr(self, name)
            if value is not None and not (_is_int(value) and value >= 1):
                raise bad(name, "must be an integer >= 1")
            if value is not None and value > MAX_ITERATIONS:
                raise bad(name, f"must be at most {MAX_ITERATIONS}")
        if self.foot_condim is not None and self.foot_condim not in CONDIMS:
            raise bad("foot_condim", f"must be one of {CONDIMS}")
        ref = self.foot_solref
        if ref is not None and not (
            isinstance(ref, tuple) and len(ref) == 2
            and all(_is_number(v) and math.isfinite(v) and v > 0 for v in ref)
        ):  # fmt: skip
            raise bad("foot_solref", "must be a pair of positive numbers (timeconst, dampratio)")

    def apply(self, model: mujoco.MjModel) -> None:
        """Write the overrides into a compiled model, in place."""
        opt = model.opt
        if self.timestep is not None:
            opt.timestep = self.timestep
        if self.integrator is not None:
            opt.integrator = INTEGRATORS[self.integrator]
        if self.solver is not None:
            opt.solver = SOLVERS[self.solver]
        if self.iterations is not None:
            opt.iterations = self.iterations
        if self.ls_iterations is not None:
            opt.ls_iterations = self.ls_iterations
        if self.tolerance is not None:
            opt.tolerance = self.tolerance
        if self.cone is not None:
            opt.cone = CONES[self.cone]
        feet = np.array([model.geom(name).id for name in FOOT_GEOMS])
        if self.foot_condim is not None:
            model.geom_condim[feet] = self.foot_condim
        if self.foot_solref is not None:
            model.geom_solref[feet] = self.foot_solref

    def label(self) -> str:
        """The set fields as ``name=value``, comma separated ('world file' if none)."""
        parts = [f"{f.name}={getattr(self, f.name)}" for f in fields(self)
                 if getattr(self, f.name) is not None]  # fmt: skip
        return ", ".join(parts) or "world file"


def describe(model: mujoco.MjModel) -> dict[str, object]:
    """The settings ``Physics`` can change, as a model has them."""
    opt = model.opt
    foot = model.geom(FOOT_GEOMS[0]).id

    def name(table: dict, value: int) -> str:
        return next(k for k, v in table.items() if int(v) == int(value))

    return {
        "timestep": float(opt.timestep),
        "integrator": name(INTEGRATORS, opt.integrator),
        "solver": name(SOLVERS, opt.solver),
        "iterations": int(opt.iterations),
        "ls_iterations": int(opt.ls_iterations),
        "tolerance": float(opt.tolerance),
        "cone": name(CONES, opt.cone),
        "foot_condim": int(model.geom_condim[foot]),
        "foot_solref": tuple(float(v) for v in model.geom_solref[foot]),
    }


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)
