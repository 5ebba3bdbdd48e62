"""Physics randomisation: each env's own physics, drawn at every reset, from one table.

``PHYSICS_PARAMS`` is the table: one ``PhysicsParam`` row per randomised
quantity, with its name, the ``Randomization`` field holding its range (rows may
share one: ``com_offset`` ranges both ``com_x`` and ``com_y``), its training range,
the model's own value, how it writes which model fields, and the centre and
spread that normalise it in the privileged ``physics`` piece. Drawing, applying,
normalising, the ``Randomization`` config's fields and the model fields that
``mujoco.batch.Batch.expand`` gives each env all loop over the table: a new
randomised parameter is one row.

``PhysicsRandomizer`` applies a ``Randomization`` to a batch, vectorised: no Python
per env. Env i of a core seeded s draws its k-th physics from the key
(s + i, "physics", k) of ``rwalk.rng``, one uniform number per row.

Ranges (a 0.8 kg robot on 0.3 N·m hobby servos; see docs/robustness.md for the
references: legged_gym and MuJoCo Playground's Go1):
friction 0.5–1.3 (legged_gym 0.5–1.25; the nominal rubber foot is 1.2), payload
−0.05–+0.12 kg on the 0.56 kg torso (−6 %…+15 % of the robot, legged_gym ±1 kg
of 12 kg), centre of mass ±1 cm on a 18 cm torso, servo gain and torque limit
×0.85–1.15 (walk-these-ways' motor strength ×0.9–1.1), joint damping and
armature ×0.8–1.2, latency 0–2 substeps (0–8 ms).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np
import torch
from torch import Tensor

from rwalk import rng
from rwalk.constants import FLOOR_GEOM, FOOT_GEOMS, GROUND_GEOM, JOINT_NAMES, TORSO_BODY

#: Random stream of the physics draws (see ``rwalk.rng``).
PHYSICS_STREAM = "physics"
#: Contact friction of the model (the larger of foot 1.2 and ground 1.0).
NOMINAL_FRICTION = 1.2


class Target:
    """A model field a parameter writes: ``field`` at ``select(model)`` (an index into one
    model's array; rows of every env are written at once)."""

    def __init__(self, field: str, select: Callable[[mujoco.MjModel], tuple]) -> None:
        self.field, self.select = field, select


def _friction_geoms(model: mujoco.MjModel) -> tuple:
    """Column 0 (sliding) of the ground, the floor under a heightfield, and the feet."""
    names = [GROUND_GEOM, FLOOR_GEOM, *FOOT_GEOMS]
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name) for name in names]
    return (np.array([i for i in ids if i >= 0]), 0)


def _torso(*column: int) -> Callable[[mujoco.MjModel], tuple]:
    return lambda model: (model.body(TORSO_BODY).id, *column)


def _leg_dofs(model: mujoco.MjModel) -> tuple:
    return (np.array([int(model.joint(name).dofadr[0]) for name in JOINT_NAMES]),)


def _servos(*column) -> Callable[[mujoco.MjModel], tuple]:
    return lambda model: (slice(None), *column)


@dataclass(frozen=True)
class PhysicsParam:
    """One randomised physics quantity (a row of ``PHYSICS_PARAMS``)."""

    name: str
    """Its column in ``PhysicsRandomizer.params`` and the ``physics`` piece."""
    range: str
    """The ``Randomization`` field with its (min, max) range."""
    default: tuple[float, float]
    """The training range (that field's default)."""
    nominal: float
    """The model's own value (``Randomization.nominal()``)."""
    centre: float
    spread: float
    """The ``physics`` piece holds (value - centre) / spread: about [-1, 1] in training."""
    op: str
    """How a drawn value v writes each target: "set" (v), "add" (model + v), "scale"
    (model x v); "latency": v whole substeps of servo delay, no model field."""
    targets: tuple[Target, ...] = ()
    minimum: float | None = None
    """Lower bound of the range's values (None: any)."""
    above: bool = False
    """The range's values must be strictly above ``minimum``."""
    doc: str = ""
    mirror: float = 1.0
    """-1 for a quantity that changes sign in the robot's left-right mirror (a shift
    along y); the physics piece mirrors with it."""


#: The randomised physics, in the order of the draws and of the ``physics`` piece.
PHYSICS_PARAMS: tuple[PhysicsParam, ...] = (
    PhysicsParam("friction", "friction", (0.5, 1.3), NOMINAL_FRICTION, 0.9, 0.4, "set",
                 (Target("geom_friction", _friction_geoms),), minimum=0.0,
                 doc="Sliding friction of the feet and the ground (MuJoCo takes the larger of "
                     "the two geoms'; both are set). The model's is 1.2."),
    PhysicsParam("payload", "payload", (-0.05, 0.12), 0.0, 0.035, 0.085, "add",
                 (Target("body_mass", _torso()),),
                 doc="Mass added to the torso (0.56 kg of the robot's 0.8). kg."),
    PhysicsParam("com_x", "com_offset", (-0.01, 0.01), 0.0, 0.0, 0.01, "add",
                 (Target("body_ipos", _torso(0)),),
                 doc="Shift of the torso's centre of mass along x and along y (each "
                     "drawn). Metres."),
    PhysicsParam("com_y", "com_offset", (-0.01, 0.01), 0.0, 0.0, 0.01, "add",
                 (Target("body_ipos", _torso(1)),), mirror=-1.0),
    PhysicsParam("kp_scale", "kp_scale", (0.85, 1.15), 1.0, 1.0, 0.15, "scale",
                 (Target("actuator_gainprm", _servos(0)), Target("actuator_biasprm", _servos(1))),
                 minimum=0.0, above=True,
                 doc="Factor on the servos' position gain (kp = 6 N·m/rad)."),
    PhysicsParam("force_scale", "force_scale", (0.85, 1.15), 1.0, 1.0, 0.15, "scale",
                 (Target("actuator_forcerange", _servos()),), minimum=0.0, above=True,
                 doc="Factor on the servos' torque limit (0.3 N·m)."),
    PhysicsParam("damping_scale", "damping_scale", (0.8, 1.2), 1.0, 1.0, 0.2, "scale",
                 (Target("dof_damping", _leg_dofs),), minimum=0.0,
                 doc="Factor on the leg joints' damping."),
    PhysicsParam("armature_scale", "armature_scale", (0.8, 1.2), 1.0, 1.0, 0.2, "scale",
                 (Target("dof_armature", _leg_dofs),), minimum=0.0,
                 doc="Factor on the leg joints' armature (rotor inertia)."),
    PhysicsParam("latency", "latency", (0, 2), 0, 1.0, 1.0, "latency", minimum=0,
                 doc="Delay of the servo targets, in physics substeps (at most one control "
                     "period)."),
)  # fmt: skip
#: The model's own values of PHYSICS_PARAMS.
NOMINAL_PARAMS = tuple(p.nominal for p in PHYSICS_PARAMS)
_CENTRE = torch.tensor([p.centre for p in PHYSICS_PARAMS], dtype=torch.float64)
_SPREAD = torch.tensor([p.spread for p in PHYSICS_PARAMS], dtype=torch.float64)
_FIRST = {p.range: p for p in reversed(PHYSICS_PARAMS)}  # the first row of each range field
#: The ``Randomization`` fields (one range each), in PHYSICS_PARAMS order.
PHYSICS_RANGES = tuple(dict.fromkeys(p.range for p in PHYSICS_PARAMS))


def check_range(
    obj, name: str, low: float | None = None, above: bool = False, integer: bool = False
) -> None:
    """Raise a ValueError naming ``obj``'s field ``name`` unless it is a (min, max) pair
    of finite numbers (integers) with min <= max and min >= low (> low if ``above``)."""
    value = getattr(obj, name)
    field = f"{type(obj).__name__}.{name}"
    ok = (
        isinstance(value, tuple)
        and len(value) == 2
        and all(
            isinstance(v, int if integer else (int, float))
            and not isinstance(v, bool)
            and math.isfinite(v)
            for v in value
        )
    )
    if not ok:
        wanted = "integers" if integer else "finite numbers"
        raise ValueError(f"{field} must be a pair of {wanted} (min, max), got {value!r}")
    if value[0] > value[1]:
        raise ValueError(f"{field} has min > max: {value!r}")
    if low is not None and (value[0] < low or (above and value[0] == low)):
        raise ValueError(f"{field} must be {'>' if above else '>='} {low:g}, got {value!r}")


class _RandomizationMethods:
    """Per-env physics, drawn uniformly from each (min, max) at every reset.

    One field per range of ``PHYSICS_PARAMS`` (``friction``, ``payload``, ``com_offset``,
    ``kp_scale``, ``force_scale``, ``damping_scale``, ``armature_scale``, ``latency``),
    each a (min, max) pair defaulting to the training range. A range with min == max
    sets that value for every env (the robustness benchmark's held-out conditions);
    ``Randomization.nominal()`` changes nothing.
    """

    def __post_init__(self) -> None:
        for name in PHYSICS_RANGES:
            row = _FIRST[name]
            check_range(self, name, row.minimum, row.above, integer=row.op == "latency")

    @classmethod
    def nominal(cls, **ranges):
        """The model's own values (nothing randomised), with ``ranges`` overriding fields."""
        base = {name: (_FIRST[name].nominal,) * 2 for name in PHYSICS_RANGES}
        return cls(**(base | ranges))


def _range_field(name: str) -> tuple:
    row = _FIRST[name]
    kind = tuple[int, int] if row.op == "latency" else tuple[float, float]
    return (name, kind, dataclasses.field(default=row.default, metadata={"doc": row.doc}))


#: The config of physics randomisation: its fields are the ranges of PHYSICS_PARAMS.
Randomization = dataclasses.make_dataclass(
    "Randomization",
    [_range_field(name) for name in PHYSICS_RANGES],
    bases=(_RandomizationMethods,),
    frozen=True,
    namespace={"__module__": __name__, "__qualname__": "Randomization",
               "__doc__": _RandomizationMethods.__doc__ + "\n    Attributes:\n" + "".join(
                   f"        {name}: (min, max). {_FIRST[name].doc}\n" for name in PHYSICS_RANGES)},
)  # fmt: skip
PhysicsRandomization = Randomization


class PhysicsRandomizer:
    """A ``Randomization`` applied to N simulations: draws, model fields, latency.

    Args:
        randomization: the config's ranges (None: the model's own physics).
        model: the compiled model (its values are the nominal ones).
        batch: the ``mujoco.batch.Batch`` of the N simulations.
        num_envs: N.
        decimation: physics substeps per env step.

    Raises:
        ValueError: naming the field, for a payload that leaves the torso without
            mass or a latency beyond one control period.
    """

    def __init__(
        self, randomization, model: mujoco.MjModel, batch, num_envs: int, decimation: int
    ) -> None:
        self.randomization = randomization
        n, k = num_envs, decimation
        self.params = _CENTRE.new_tensor(NOMINAL_PARAMS).repeat(n, 1)
        """Each env's physics, in PHYSICS_PARAMS order (raw values). Shape: (N, P)."""
        self.draws = torch.zeros(n, dtype=torch.long)
        """Physics drawn so far by each env. Shape: (N,)."""
        self.latency = torch.zeros(n, dtype=torch.long)
        """Servo-target delay of each env. Shape: (N,). Substeps."""
        self._held = torch.zeros(n, k, len(JOINT_NAMES), dtype=torch.float64)
        """Each env's servo targets of the last control period (the delayed ones come
        from its end). Shape: (N, K, 12)."""
        self._batch = batch
        self._seed = 0
        self._torso_mass, self._decimation = float(model.body(TORSO_BODY).mass[0]), k
        self._per_env = randomization is not None
        """Whether the model fields of PHYSICS_PARAMS are per env (randomisable)."""
        if randomization is None:
            return
        self.set_ranges(randomization)
        arrays = {t.field: None for p in PHYSICS_PARAMS for t in p.targets}
        for name in arrays:
            expanded = batch.expand(name)
            flat = expanded.reshape(n, -1)
            assert np.shares_memory(flat, expanded), f"{name}: expanded rows are not a view"
            arrays[name] = flat
        self._writes = []
        """(column, op, rows of the env's flat field, flat indices, nominal values)."""
        for column, param in enumerate(PHYSICS_PARAMS):
            for target in param.targets:
                nominal = np.asarray(getattr(model, target.field))
                index = np.arange(nominal.size).reshape(nominal.shape)[target.select(model)]
                index = np.asarray(index).reshape(-1)
                self._writes.append(
                    (column, param.op, arrays[target.field], index, nominal.reshape(-1)[index])
                )

    def set_ranges(self, randomization) -> None:
        """Draw from ``randomization``'s ranges from the next reset on (a training stage
        may narrow them): running episodes keep their physics; a latency range of (0, 0)
        ends every env's delay at once.

        Raises:
            ValueError: naming the field, for a payload that leaves the torso without
                mass or a latency beyond one control period; or if these simulations
                were built without randomisation (their model fields are not per env).
        """
        if not self._per_env:
            raise ValueError("these simulations were built without physics randomisation")
        if self._torso_mass + randomization.payload[0] <= 0:
            raise ValueError(
                f"Randomization.payload {randomization.payload!r} leaves the torso "
                f"({self._torso_mass:g} kg) with no mass"
            )
        if randomization.latency[1] > self._decimation:
            raise ValueError(
                f"Randomization.latency {randomization.latency!r} exceeds one control period "
                f"({self._decimation} substeps)"
            )
        ranges = [getattr(randomization, p.range) for p in PHYSICS_PARAMS]
        self._low = torch.tensor([r[0] for r in ranges], dtype=torch.float64)
        self._high = torch.tensor([r[1] for r in ranges], dtype=torch.float64)
        self.randomization = randomization

    def seed(self, seed: int) -> None:
        """Key the draws by ``seed`` (env i draws from seed + i) and restart them."""
        self._seed = seed
        self.draws.zero_()

    def reset(self, rows: Tensor, settle_tail: np.ndarray) -> None:
        """Draw new physics for ``rows`` (before they settle) and write them into their
        simulations.

        Args:
            rows: env indices. Shape: (M,).
            settle_tail: the last K servo targets of settling: the delayed targets the
                first step applies. Shape: (K, 12).
        """
        if self.randomization is None:
            return
        u = rng.uniform_rows(self._seed, rows, PHYSICS_STREAM, self.draws, len(PHYSICS_PARAMS))
        values = self._low + u * (self._high - self._low)
        for column, param in enumerate(PHYSICS_PARAMS):
            if param.op == "latency":  # a whole number of substeps, each equally likely
                low, high = getattr(self.randomization, param.range)
                whole = low + torch.floor(u[:, column] * (high - low + 1)).to(torch.long)
                values[:, column] = whole.to(torch.float64)
                self.latency[rows] = whole
        self.params[rows] = values
        self.apply(rows)
        self._held[rows] = torch.from_numpy(settle_tail)

    def apply(self, rows: Tensor) -> None:
        """Write ``params`` of ``rows`` into their simulations (and derived constants)."""
        if self.randomization is None:
            return
        ids = rows.numpy()
        p = self.params[rows].numpy()
        for column, op, flat, index, nominal in self._writes:
            value = p[:, column : column + 1]
            if op == "add":
                value = nominal[None, :] + value
            elif op == "scale":
                value = nominal[None, :] * value
            flat[ids[:, None], index[None, :]] = value
        self._batch.set_const(ids.astype(np.int32))

    def lag(self) -> Tensor:
        """Each env's servo delay now, in substeps: its drawn ``latency``, or 0 wherever
        ``delay`` applies none (no randomisation, or a latency range of (0, 0), whose
        running episodes keep their older draws). Shape: (N,) int64."""
        return self.latency if self._delays() else torch.zeros_like(self.latency)

    def _delays(self) -> bool:
        """Whether ``delay`` delays anything: drawn physics with a latency range other
        than (0, 0)."""
        return self.randomization is not None and self.randomization.latency != (0, 0)

    def delay(self, ctrl: np.ndarray) -> np.ndarray:
        """The servo targets each env applies, ``latency`` substeps late: the end of
        the last period's targets, then the start of this one's. (N, K, 12) -> same."""
        if not self._delays():
            return ctrl
        current = torch.from_numpy(ctrl)
        k = ctrl.shape[1]
        both = torch.cat((self._held, current), dim=1)  # (N, 2K, 12)
        index = (k - self.latency)[:, None] + torch.arange(k)[None, :]
        applied = both.gather(1, index[:, :, None].expand(-1, -1, ctrl.shape[2]))
        self._held.copy_(current)
        return np.ascontiguousarray(applied.numpy())

    def normalised_params(self) -> Tensor:
        """The physics piece: each parameter centred and scaled. Shape: (N, P)."""
        return (self.params - _CENTRE) / _SPREAD

    def state(self) -> dict[str, Tensor]:
        """Per-env tensors to keep when the core is pickled."""
        return {
            "params": self.params, "draws": self.draws, "latency": self.latency,
            "held": self._held,
        }  # fmt: skip
