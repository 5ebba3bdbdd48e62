"""A runtime for exported policies that imports no torch: numpy, onnx and onnxruntime only.

A robot's loop, once per control period (``controller.control_dt``, 20 ms)::

    from rwalk.deploy import Controller

    controller = Controller("logs/rwalk/exported")  # policy.onnx + policy.json
    controller.reset(read_sensors())                # at the start of a walk
    while walking:
        targets = controller.step(read_sensors())   # (K, 12) joint angles, radians
        for row in targets:                         # one row per physics substep (4 ms)
            write_servos(row)
            wait(controller.dt)

``read_sensors()`` returns the training's sensor layout (``SENSOR_LAYOUT``: 65
values, MuJoCo's ``sensordata`` of the model's sensors: torso position,
orientation, velocities, the 12 joint positions and velocities, foot positions
and velocities in the torso frame, and foot contact forces; a real robot fills
what it measures and estimates the rest). Targets are in actuator order (FL,
FR, RL, RR x abduction, hip, knee). The controller holds the gait's phase, the
episode's start, the last gait cycle's speeds and a recurrent policy's state.

Numerics: the same operations as the env (``rwalk.kinematics.leg_ik`` on numpy
arrays, tables exported bit for bit in ``policy.json``), so a simulated robot
stepped with these targets follows the env's closed loop bit for bit when the
env runs the same ONNX policy (``rwalk.sim2sim``).

Loading trusts neither file: ``policy.json`` (at most ``MAX_JSON_BYTES``, nested at
most ``MAX_JSON_DEPTH`` deep, checked before it is parsed) has every number of its
deploy section checked for type, shape and range (the bounds below), and the ONNX
graph (at most ``MAX_ONNX_BYTES``) is inspected with ``onnx`` before onnxruntime
loads it: float32 inputs and outputs of the layout's shapes, only ``ONNX_OPS``, every
tensor's size known at batch 1, and its weights, tensors and work within
``MAX_WEIGHTS``, ``MAX_TENSOR_VALUES`` and ``MAX_WORK``. A bad file is a one-line
``ValueError`` naming the file and the field; a file that loads gives finite targets.

Bad readings never reach a servo: readings that are not 65 numbers are a
``ValueError``; a non-finite reading, or a non-finite policy output, makes
``step`` return the last safe targets again (``controller.held`` says so,
and a warning names the reading), and the next finite readings go on.

Runs both tasks' policies (MLP or recurrent): the residual task's fixed trot from
its exported tables, the adaptive task's gait from its parameters with the
functions the env uses (``rwalk.gaitmath``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
import os
import re
import reprlib
import warnings
from pathlib import Path

import numpy as np

from rwalk import exactmath
from rwalk.constants import OBS_CONTACT, OBS_DIM, OBS_LINVEL, OBS_POS, OBSERVATION_SENSORS
from rwalk.gaitmath import MAX_STEP_RISE, advance_phase, speed_schedule, trot_targets
from rwalk.kinematics import LegGeometry, leg_ik

#: The readings ``Controller.step`` takes: (sensor name, width), in order (65 values).
SENSOR_LAYOUT = OBSERVATION_SENSORS
#: The pieces a deployed policy may read (the rest need the simulator: privileged).
DEPLOYABLE = ("observation", "observation_from_start", "phase", "lateral_offset",
              "cycle_speed", "command", "last_action")  # fmt: skip
#: The tasks whose policies it runs.
TASKS = ("residual_walk", "adaptive_gait")
#: The gaits this runtime runs, by policy.json's ``deploy.runtime``: a fixed trot from its
#: tables, or the adaptive gait from its parameters. Exports from before the key name
#: their runtime by their task (``OLDER_RUNTIMES``).
RUNTIMES = ("table", "adaptive")
OLDER_RUNTIMES = dict(zip(TASKS, RUNTIMES, strict=True))
#: What an export folder holds for the runtime.
FILES = ("policy.json", "policy.onnx")
#: What the adaptive task's first four actions do (``AdaptiveGaitConfig.gait_action``).
GAIT_ACTIONS = ("delta", "target", "schedule")

# Bounds of policy.json, checked when a folder loads (an export's values in brackets).
#: Largest policy.json read (an export's: about 80 KB, mostly the 150-tick gait tables).
MAX_JSON_BYTES = 16 << 20
#: Deepest nesting of its lists and objects (an export's: 6).
MAX_JSON_DEPTH = 32
#: Most substeps of a control period (5).
MAX_SUBSTEPS = 1000
#: Most ticks of a gait cycle (150): the residual task's tables have this many rows at most.
MAX_PERIOD = 20_000
#: Most control periods of the cycle-speed window (30).
MAX_CYCLE_STEPS = 100_000
#: Widest policy input and most pieces (68 to 90 values in 3 to 6 pieces).
MAX_INPUT_WIDTH = 4096
MAX_PIECES = 16
#: Most layers and units of a recurrent state (rwalk-train's: 1 layer of at most 4096 units).
MAX_RNN_LAYERS = 8
MAX_RNN_HIDDEN = 4096
#: Largest length: legs, hip points, foot targets, gait sizes, residual scale (0.16). Metres.
MAX_LENGTH = 10.0
#: Slowest target velocity and shortest stride of a "schedule" gait action (m/s, m).
MIN_SPEED = 1e-3
#: Shortest thigh and shin (the IK divides by 2 x thigh x shin). Metres.
MIN_LEG_LENGTH = 1e-3
#: Largest joint limit (2.7). Radians.
MAX_ANGLE = 2.0 * math.pi
#: Range of a substep, ``dt`` (0.004). Seconds.
DT_RANGE = (1e-6, 1.0)
#: Range of the stance share of a cycle (0.65): the gait divides by it and by 1 - it.
DUTY_RANGE = (0.01, 0.99)
#: Most swing control points (7), and their largest value (1.28; units of half a stride
#: and of the step height).
MAX_SWING_POINTS = 32
MAX_SWING = 1e3
#: Range of the adaptive gait's cycle time (0.3 to 0.9; the phase advances by dt / it). s.
CYCLE_TIME_RANGE = (1e-3, 10.0)
#: Narrowest range (high - low) of an adapted parameter: the observation divides by it.
MIN_PARAM_SPAN = 1e-9

# Bounds of policy.onnx, checked with the onnx package before onnxruntime loads it. The
# largest policy rwalk-train makes (8 MLP layers of 4096 units after an LSTM of 4096 units:
# rwalk.rl.config's MAX_LAYERS and MAX_WIDTH) has about 1.9e8 weights, 2**26 values in its
# largest tensor and about 1e9 of work a step (its export slices the LSTM's weights): every
# bound leaves it room.
#: Most weights (initializer values) of the graph.
MAX_WEIGHTS = 1 << 28
#: Largest policy.onnx read: 4 bytes a weight, and 64 MiB for the graph and its metadata.
MAX_ONNX_BYTES = 4 * MAX_WEIGHTS + (64 << 20)
#: Most values of one tensor of the graph (a weight, or any node's input or output at batch 1).
MAX_TENSOR_VALUES = 1 << 27
#: Most work of one step at batch 1: the values every node reads and writes, plus the
#: multiply-adds of MatMul, Gemm and the recurrent nodes.
MAX_WORK = 1 << 31
#: Most nodes of the graph (an export's: 5 to 20).
MAX_NODES = 10_000
#: The ONNX ops (default domain) a graph may use: those of rsl-rl's MLPs, GRUs and LSTMs
#: with their normaliser, and others whose work is at most the values they read and write.
ONNX_OPS = frozenset({
    "Abs", "Add", "And", "BatchNormalization", "Cast", "CastLike", "Ceil", "Celu", "Clip",
    "Concat", "Constant", "ConstantOfShape", "Div", "Dropout", "Elu", "Equal", "Erf", "Exp",
    "Expand", "Flatten", "Floor", "GRU", "Gather", "Gelu", "Gemm", "Greater", "GreaterOrEqual",
    "HardSigmoid", "HardSwish", "Identity", "LSTM", "LayerNormalization", "LeakyRelu", "Less",
    "LessOrEqual", "Log", "LogSoftmax", "MatMul", "Max", "Mean", "Min", "Mish", "Mul", "Neg",
    "Not", "Or", "PRelu", "Pow", "RNN", "Reciprocal", "ReduceMax", "ReduceMean", "ReduceMin",
    "ReduceSum", "Relu", "Reshape", "Round", "Selu", "Shape", "Sigmoid", "Sign", "Size",
    "Slice", "Softmax", "Softplus", "Softsign", "Split", "Sqrt", "Squeeze", "Sub", "Sum",
    "Tanh", "Tile", "Transpose", "Unsqueeze", "Where", "Xor",
})  # fmt: skip


class Controller:
    """An exported policy with its gait and inverse kinematics, stepping one robot.

    Args:
        folder: an export folder (``policy.onnx`` and ``policy.json`` with its
            ``deploy`` section, as ``rwalk.export.export_policy`` writes them).
        threads: onnxruntime's intra-op threads (1: one core).

    Raises:
        FileNotFoundError: a missing file, named.
        ValueError: a file beyond its bounds (the module's ``MAX_*``), a ``policy.json``
            that is not JSON, has no ``deploy`` section, names a task or piece this
            runtime cannot run or holds a value of the wrong type, shape or range, or an
            ONNX graph that disagrees with it or whose work cannot be bounded (one line,
            naming the file and the field).
    """

    def __init__(self, folder: str | os.PathLike[str], *, threads: int = 1) -> None:
        folder = Path(folder)
        if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= 256:
            raise ValueError(f"threads must be a whole number in [1, 256], got {_show(threads)}")
        for name in FILES:
            if not (folder / name).is_file():
                raise FileNotFoundError(f"export folder {str(folder)!r} has no {name}")
        fields = _Fields(folder / "policy.json")
        layout = _read_layout(folder / "policy.json")
        deploy = layout["deploy"]
        self.pieces, self.width = _check_input(fields, layout)
        self.geometry = _check_deploy(fields, deploy)
        self.substeps: int = deploy["substeps"]
        """K: physics substeps per control period (rows of ``step``'s targets)."""
        self.dt = float(deploy["dt"])
        """Seconds per substep: how long each row of targets is held."""
        self.control_dt = self.substeps * self.dt
        gait = (TableGait if deploy["runtime"] == "table" else AdaptiveGait)(deploy, self.geometry)
        self.gait: TableGait | AdaptiveGait = gait
        """The gait and its state (phase; the adaptive task's parameters)."""
        self.period = gait.period
        self.window: int = deploy["cycle_steps"]
        states, state = _check_recurrent(fields, layout)
        self.session = _session(folder / "policy.onnx", ["obs", *states], self.width, state,
                                gait.action_dim, threads)  # fmt: skip
        """onnxruntime's session of the checked graph."""
        self.state_shapes = [state] * len(states)
        """The recurrent states' shapes (layers, 1, hidden); none for an MLP."""
        self._outputs = [(1, gait.action_dim), *self.state_shapes]
        built = _input_width(self.pieces, gait)
        if built != self.width:
            raise ValueError(f"{fields.where}: input.pieces {_show(self.pieces)} make {built} "
                             f"values; input.shape[1] says {self.width}")  # fmt: skip
        self._command: float | None = None
        self.last_action = np.zeros(gait.action_dim)
        """The last action the policy sent, clipped (zero from ``reset`` on: the piece
        ``last_action``); a held step sends none and keeps it."""
        self.held = False
        """Whether the last ``step`` returned held targets (bad readings or outputs)."""
        self._started = False

    @property
    def command(self) -> float | None:
        """The target velocity (m/s) a commanded policy (piece ``command``) reads, and a
        "schedule" gait follows; set it (a finite number, forward for a schedule, else
        ValueError)."""
        return self._command

    @command.setter
    def command(self, value) -> None:
        number = _real(value)
        if value is not None and not math.isfinite(number):
            raise ValueError(f"controller.command must be a finite number (m/s) or None, "
                             f"got {_show(value)}")  # fmt: skip
        scheduled = getattr(self.gait, "gait_action", None) == "schedule"
        if scheduled and value is not None and not number >= MIN_SPEED:
            raise ValueError(
                f"this policy's gait follows the target velocity's schedule: command a "
                f"forward speed (>= {MIN_SPEED:g} m/s), got {_show(value)}"
            )
        self._command = None if value is None else number

    def reset(self, readings, tick: int = 0) -> np.ndarray:
        """Begin a walk from the robot's current readings.

        Args:
            readings: the sensors (``SENSOR_LAYOUT``). Shape: (65,).
            tick: the gait's substep in its cycle at the start (the env's starts: its
                ``settled_tick``; 0 begins the trot at phase 0).

        Returns:
            The base gait's targets of the first period, the safe targets held until
            the first ``step``. Shape: (K, 12).

        Raises:
            ValueError: readings that are not 65 finite numbers, or a tick that is not a
                whole number in [0, period).
        """
        readings = self._check(readings)
        if not np.isfinite(readings).all():
            raise ValueError(f"reset needs finite readings; got {_bad(readings)}")
        number = _real(tick)
        if not (number.is_integer() and 0 <= number < self.period):
            raise ValueError(f"tick must be a whole number in [0, {self.period}), "
                             f"got {_show(tick)}")  # fmt: skip
        self.gait.reset(int(number))
        self.x0, self.y0 = float(readings[OBS_POS.start]), float(readings[OBS_POS.start + 1])
        v0 = readings[OBS_LINVEL.start]
        self.recent = np.full(self.window, v0)
        self.recent_sum = v0 * self.window
        self.slot = 0
        self.state = [np.zeros(shape, dtype=np.float32) for shape in self.state_shapes]
        self._fresh, self._started, self.held = True, True, False
        self.last_action = np.zeros(self.gait.action_dim)
        self.safe = self.gait.joints(None)
        return self.safe

    def step(self, readings) -> np.ndarray:
        """One control period: readings in, the period's servo targets out.

        Args:
            readings: the sensors now (``SENSOR_LAYOUT``). Shape: (65,).

        Returns:
            Joint targets for each substep of the period, actuator order. Shape: (K, 12).

        Raises:
            ValueError: readings that are not 65 numbers; RuntimeError: before ``reset``.
        """
        if not self._started:
            raise RuntimeError("call reset(readings) before step(readings)")
        readings = self._check(readings)
        if not np.isfinite(readings).all():
            return self._hold(f"non-finite readings {_bad(readings)}")
        if not self._fresh:  # the env's episode statistics, as Episodes.record keeps them
            velocity = readings[OBS_LINVEL.start]
            self.recent_sum += velocity - self.recent[self.slot]
            self.recent[self.slot] = velocity
            self.slot = (self.slot + 1) % self.window
        self._fresh = False
        feed = {"obs": self.policy_input(readings)[None]}
        feed.update(zip(self.state_names, self.state, strict=True))
        action, *state = self.session.run(None, feed)
        shapes = [action.shape, *(s.shape for s in state)]
        if shapes != self._outputs:  # (the graph's shapes were checked on load)
            raise ValueError(f"the ONNX graph returned shapes {shapes}; want {self._outputs}")
        if not np.isfinite(action).all():
            return self._hold(f"a non-finite policy output {action[0].tolist()}")
        self.state = state
        action = np.minimum(np.maximum(action[0].astype(np.float64), -1.0), 1.0)
        self.last_action = action
        self.safe = self.gait.joints(action, self._command)
        self.held = False
        return self.safe

    def policy_input(self, readings: np.ndarray) -> np.ndarray:
        """The policy's input row from finite readings, in the export's layout, as the
        env builds it (float64 pieces, then float32). Shape: (D,) float32."""
        obs = readings.copy()
        obs[OBS_CONTACT] = readings[OBS_CONTACT] > 0
        obs = np.concatenate([obs, self.gait.observation()])  # the task's spec observation
        parts = []
        for name in self.pieces:
            if name == "observation":
                parts.append(obs)
            elif name == "observation_from_start":
                local = obs.copy()
                local[OBS_POS.start] -= self.x0
                local[OBS_POS.start + 1] -= self.y0
                parts.append(local)
            elif name == "phase":
                parts.append(self.gait.phase_features())
            elif name == "lateral_offset":
                parts.append([obs[OBS_POS.start + 1] - self.y0])
            elif name == "cycle_speed":
                parts.append([self.recent_sum / self.window])
            elif name == "last_action":
                parts.append(self.last_action)
            else:  # command
                if self.command is None:
                    raise ValueError("the policy reads a command: set controller.command "
                                     "(m/s), got None")  # fmt: skip
                parts.append([self.command])
        with np.errstate(over="ignore"):  # a reading beyond float32: inf, then held in step
            row = np.concatenate(parts).astype(np.float32)
        if row.shape != (self.width,):
            raise ValueError(f"policy input of {row.shape[0]} values; the ONNX graph takes "
                             f"{self.width}")  # fmt: skip
        return row

    def _hold(self, why: str) -> np.ndarray:
        """The last safe targets again (the period's last row), saying why."""
        warnings.warn(f"rwalk.deploy: {why}; holding the last safe targets", stacklevel=3)
        self.held = True
        self.safe = np.repeat(self.safe[-1:], self.substeps, axis=0)
        return self.safe

    @staticmethod
    def _check(readings) -> np.ndarray:
        """Readings as float64, refused (ValueError naming them) unless 65 real numbers."""
        try:
            array = np.asarray(readings)
        except (TypeError, ValueError):  # ragged nesting, or an object numpy refuses
            array = np.asarray(None)
        if array.dtype.kind not in "fiu":
            raise ValueError(f"readings must be {OBS_DIM} real numbers (rwalk.deploy."
                             f"SENSOR_LAYOUT), got {type(readings).__name__} of dtype "
                             f"{array.dtype}")  # fmt: skip
        if array.shape != (OBS_DIM,):
            raise ValueError(f"readings must be {OBS_DIM} values (rwalk.deploy.SENSOR_LAYOUT), "
                             f"got shape {array.shape}")  # fmt: skip
        return array.astype(np.float64, copy=False)

    @property
    def state_names(self) -> list[str]:
        """The ONNX graph's state inputs (``h_in``, ``c_in``; none for an MLP)."""
        return [state.name for state in self.session.get_inputs()[1:]]


def _tuples(value):
    """JSON lists back to the tuples of a frozen dataclass's fields."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


def _bad(readings: np.ndarray) -> str:
    names = [f"{name}[{i}]" for name, width in SENSOR_LAYOUT for i in range(width)]
    bad = np.flatnonzero(~np.isfinite(readings))
    return ", ".join(f"{names[i]}={readings[i]}" for i in bad[:4]) + (
        " ..." if len(bad) > 4 else ""
    )


_SHOW = reprlib.Repr()
_SHOW.maxstring = _SHOW.maxother = _SHOW.maxlong = 40
_SHOW.maxlist = _SHOW.maxtuple = 6
_SHOW.maxdict = 4


def _show(value) -> str:
    """A short one-line repr of a bad value, for an error message."""
    return _SHOW.repr(value)


def _line(error: BaseException) -> str:
    """An exception's message on one line, at most 200 characters."""
    return " ".join(str(error).split())[:200]


def _real(value) -> float:
    """``value`` as a float if it is a real number (not a bool), else NaN."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return math.nan
    try:
        return float(value)
    except (OverflowError, TypeError, ValueError):
        return math.nan


def _read_capped(path: Path, limit: int) -> bytes:
    """A file's bytes, refused (naming it) if it holds more than ``limit``."""
    try:
        size = path.stat().st_size
        if size <= limit:
            with path.open("rb") as file:
                data = file.read(limit + 1)
            size = len(data)
    except OSError as error:
        raise ValueError(f"{str(path)!r} cannot be read: {_line(error)}") from None
    if size > limit:
        raise ValueError(f"{str(path)!r} holds {size} bytes; rwalk.deploy reads at most {limit}")
    return data


#: A JSON string (its brackets are not nesting).
_JSON_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)


def _nesting(text: str) -> int:
    """How deep the arrays and objects of a JSON text nest (0: none), without parsing it."""
    codes = np.frombuffer(_JSON_STRING.sub("", text).encode(), dtype=np.uint8)
    brackets = codes[np.isin(codes, np.frombuffer(b"[]{}", dtype=np.uint8))]
    return int(np.cumsum(np.where((brackets == 91) | (brackets == 123), 1, -1)).max(initial=0))


def _read_layout(path: Path) -> dict:
    """policy.json, within ``MAX_JSON_BYTES`` and ``MAX_JSON_DEPTH``, with its task checked."""
    data = _read_capped(path, MAX_JSON_BYTES)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise ValueError(f"{str(path)!r} is not JSON: {_line(error)}") from None
    depth = _nesting(text)
    if depth > MAX_JSON_DEPTH:
        raise ValueError(f"{str(path)!r} nests lists and objects {depth} deep; rwalk.deploy "
                         f"reads at most {MAX_JSON_DEPTH}")  # fmt: skip
    try:
        layout = json.loads(text)
    except (ValueError, RecursionError) as error:  # ValueError: JSON's, or a 5000-digit int
        raise ValueError(f"{str(path)!r} is not JSON: {_line(error)}") from None
    sections = [layout.get(key) if isinstance(layout, dict) else None
                for key in ("input", "deploy")]  # fmt: skip
    if not all(isinstance(section, dict) for section in sections) or not (
        "pieces" in sections[0] and "task" in sections[1]
    ):
        raise ValueError(
            f"{str(path)!r} has no deploy section (input.pieces, deploy.task): export the "
            f"policy with this rwalk (rwalk-sim2sim CHECKPOINT --export FOLDER)"
        )
    deploy = layout["deploy"]
    task = deploy["task"]
    runtime = deploy.get("runtime", OLDER_RUNTIMES.get(task) if isinstance(task, str) else None)
    if runtime not in RUNTIMES:
        raise ValueError(f"{str(path)!r} is a {_show(task)} policy with deploy.runtime "
                         f"{_show(runtime)}; rwalk.deploy runs {RUNTIMES}")  # fmt: skip
    deploy["runtime"] = runtime
    return layout


class _Fields:
    """Checked reads of policy.json's values: a bad one is a one-line ValueError naming the
    file and the value's dotted path (``deploy.leg_geometry.thigh_length``)."""

    def __init__(self, path: Path) -> None:
        self.where = repr(str(path))

    def fail(self, path: str, want: str, value, *, shown: str | None = None) -> ValueError:
        return ValueError(f"{self.where}: {path} must be {want}, got {shown or _show(value)}")

    def get(self, section: dict, path: str):
        """The entry of ``section`` that the last part of ``path`` names."""
        key = path.rsplit(".", 1)[-1]
        if key not in section:
            raise ValueError(f"{self.where}: {path} is missing")
        return section[key]

    def section(self, parent: dict, path: str) -> dict:
        value = self.get(parent, path)
        if not isinstance(value, dict):
            raise self.fail(path, "an object", value)
        return value

    def choice(self, parent: dict, path: str, choices: tuple[str, ...]) -> str:
        value = self.get(parent, path)
        if not isinstance(value, str) or value not in choices:
            raise self.fail(path, f"one of {choices}", value)
        return value

    def number(self, parent: dict, path: str, low, high, *, whole: bool = False):
        return self.check(self.get(parent, path), path, low, high, whole=whole)

    def check(self, value, path: str, low, high, *, whole: bool = False):
        """``value``: a JSON number (an int if ``whole``; never a bool) in [low, high]: finite."""
        kinds = int if whole else (int, float)
        if isinstance(value, bool) or not isinstance(value, kinds) or not low <= value <= high:
            want = (f"a whole number in [{low}, {high}]" if whole
                    else f"a finite number in [{low:g}, {high:g}]")  # fmt: skip
            raise self.fail(path, want, value)
        return value

    def array(self, parent: dict, path: str, shape: tuple, low: float, high: float) -> np.ndarray:
        """Nested lists of finite numbers in [low, high], as float64. ``shape``: a size per
        level, an int or a (fewest, most) range."""
        value = self.get(parent, path)
        self._nested(value, path, shape, low, high)
        return np.array(value, dtype=np.float64)

    def _nested(self, value, path: str, shape: tuple, low: float, high: float) -> None:
        if not shape:
            self.check(value, path, low, high)
            return
        size, *inner = shape
        fewest, most = size if isinstance(size, tuple) else (size, size)
        if not isinstance(value, list) or not fewest <= len(value) <= most:
            count = f"{fewest}" if fewest == most else f"{fewest} to {most}"
            want = f"a list of {count} {'lists' if inner else 'numbers'}"
            shown = f"a list of {len(value)}" if isinstance(value, list) else None
            raise self.fail(path, want, value, shown=shown)
        for i, item in enumerate(value):
            self._nested(item, f"{path}[{i}]", tuple(inner), low, high)


def _check_input(fields: _Fields, layout: dict) -> tuple[list[str], int]:
    """The input's piece names (deployable ones only) and its width D."""
    pieces = layout["input"]["pieces"]
    if not isinstance(pieces, list) or not 1 <= len(pieces) <= MAX_PIECES:
        raise fields.fail("input.pieces", f"a list of 1 to {MAX_PIECES} pieces", pieces)
    names = []
    for i, piece in enumerate(pieces):
        if not isinstance(piece, dict):
            raise fields.fail(f"input.pieces[{i}]", "an object", piece)
        names.append(fields.get(piece, f"input.pieces[{i}].name"))
        if not isinstance(names[-1], str):
            raise fields.fail(f"input.pieces[{i}].name", "a string", names[-1])
    cannot = [name for name in names if name not in DEPLOYABLE]
    if cannot:
        raise ValueError(
            f"the policy reads {_show(cannot)} (privileged: only the simulator knows them); "
            f"deploy a student (rwalk-train --distill) that reads {DEPLOYABLE}"
        )
    shape = fields.get(layout["input"], "input.shape")
    if not isinstance(shape, list) or len(shape) != 2:
        raise fields.fail("input.shape", '["batch", D]', shape)
    return names, fields.check(shape[1], "input.shape[1]", 1, MAX_INPUT_WIDTH, whole=True)


def _input_width(pieces: list[str], gait: TableGait | AdaptiveGait) -> int:
    """How many values ``Controller.policy_input`` builds for these pieces."""
    spec = OBS_DIM + len(gait.observation())
    sizes = {
        "observation": spec,
        "observation_from_start": spec,
        "phase": 2,
        "last_action": gait.action_dim,
    }
    return sum(sizes.get(name, 1) for name in pieces)


def _check_deploy(fields: _Fields, deploy: dict) -> LegGeometry:
    """Every number of the deploy section (type, shape, range: the module's bounds); the legs."""
    fields.number(deploy, "deploy.substeps", 1, MAX_SUBSTEPS, whole=True)
    fields.number(deploy, "deploy.dt", *DT_RANGE)
    fields.number(deploy, "deploy.cycle_steps", 1, MAX_CYCLE_STEPS, whole=True)
    fields.number(deploy, "deploy.residual_scale", 0.0, MAX_LENGTH)
    geometry = _check_legs(fields, fields.section(deploy, "deploy.leg_geometry"))
    gait = fields.section(deploy, "deploy.gait")
    if deploy["runtime"] == "table":
        period = (1, MAX_PERIOD)
        fields.array(gait, "deploy.gait.targets", (period, 4, 3), -MAX_LENGTH, MAX_LENGTH)
        rows = len(gait["targets"])
        fields.array(gait, "deploy.gait.phase_features", (rows, 2), -1.0, 1.0)
    else:
        _check_adaptive(fields, gait, fields.section(deploy, "deploy.adaptive"))
    return geometry


def _check_legs(fields: _Fields, legs: dict) -> LegGeometry:
    """``deploy.leg_geometry``: lengths, offsets and joint limits in range, as a LegGeometry."""
    where, most = "deploy.leg_geometry", MAX_LENGTH
    fields.array(legs, f"{where}.hip_positions", (4, 3), -most, most)
    fields.array(legs, f"{where}.abduction_offsets", (4,), -most, most)
    fields.number(legs, f"{where}.thigh_length", MIN_LEG_LENGTH, most)
    fields.number(legs, f"{where}.shin_length", MIN_LEG_LENGTH, most)
    fields.number(legs, f"{where}.foot_radius", 0.0, most)
    lower = fields.array(legs, f"{where}.joint_lower", (3,), -MAX_ANGLE, MAX_ANGLE)
    upper = fields.array(legs, f"{where}.joint_upper", (3,), -MAX_ANGLE, MAX_ANGLE)
    if not (lower <= upper).all():
        raise fields.fail(f"{where}.joint_lower", "<= joint_upper at each joint", None,
                          shown=f"{lower.tolist()} and {upper.tolist()}")  # fmt: skip
    geometry = LegGeometry(
        **{f.name: _tuples(legs[f.name]) for f in dataclasses.fields(LegGeometry)}
    )
    try:  # the IK's reach at the knee limits: a square root of the lengths and limits
        geometry.min_knee_reach, geometry.max_knee_reach  # noqa: B018 (computed to check)
    except ValueError:  # rounded below 0: a thigh and shin a hair apart, a knee at pi
        lengths, knees = [legs["thigh_length"], legs["shin_length"]], [lower[2], upper[2]]
        shown = f"thigh and shin {lengths}, knee limits {[float(k) for k in knees]}"
        want = "legs whose reach at the knee limits is real"
        raise fields.fail(where, want, None, shown=shown) from None
    return geometry


def _check_adaptive(fields: _Fields, gait: dict, adaptive: dict) -> None:
    """The adaptive task's trot constants and its parameters' start, range and steps."""
    fields.number(gait, "deploy.gait.period", 1, MAX_PERIOD, whole=True)
    fields.number(gait, "deploy.gait.duty_factor", *DUTY_RANGE)
    fields.number(gait, "deploy.gait.stance_depth", 0.0, MAX_LENGTH)
    fields.array(gait, "deploy.gait.offsets", (4,), 0.0, 1.0)
    points = ((2, MAX_SWING_POINTS), 2)
    fields.array(gait, "deploy.gait.swing_points", points, -MAX_SWING, MAX_SWING)
    fields.array(gait, "deploy.gait.neutral", (4, 3), -MAX_LENGTH, MAX_LENGTH)
    fields.choice(adaptive, "deploy.adaptive.gait_action", GAIT_ACTIONS)
    low, high, start = (
        fields.array(adaptive, f"deploy.adaptive.{key}", (4,), -MAX_LENGTH, MAX_LENGTH)
        for key in ("low", "high", "start")
    )
    fields.array(adaptive, "deploy.adaptive.delta", (4,), 0.0, MAX_LENGTH)
    if adaptive["gait_action"] == "schedule":
        schedule = fields.section(adaptive, "deploy.adaptive.schedule")
        fields.number(schedule, "deploy.adaptive.schedule.stride", MIN_SPEED, MAX_LENGTH)
        fields.array(schedule, "deploy.adaptive.schedule.window", (4,), 0.0, 1.0)
        fields.number(schedule, "deploy.adaptive.schedule.speed", MIN_SPEED, MAX_LENGTH)
        if "step_rise" in schedule:  # (absent from exports before it: 0)
            fields.number(schedule, "deploy.adaptive.schedule.step_rise", 0.0, MAX_STEP_RISE)
    for key in ("low", "high", "start"):  # the cycle time: the phase advances by dt / it
        fields.check(adaptive[key][2], f"deploy.adaptive.{key}[2]", *CYCLE_TIME_RANGE)
    if not (high - low >= MIN_PARAM_SPAN).all():
        raise fields.fail("deploy.adaptive.high", f"above low by {MIN_PARAM_SPAN:g} or more",
                          None, shown=f"low {low.tolist()}, high {high.tolist()}")  # fmt: skip
    if not ((low <= start) & (start <= high)).all():
        bounds = f"{start.tolist()}; low {low.tolist()}, high {high.tolist()}"
        raise fields.fail("deploy.adaptive.start", "within [low, high]", None, shown=bounds)


def _check_recurrent(fields: _Fields, layout: dict) -> tuple[list[str], tuple[int, int, int]]:
    """A recurrent policy's state inputs and their shape (layers, 1, hidden); an MLP: none."""
    recurrent = layout.get("recurrent")
    if recurrent is None:
        return [], (0, 1, 0)
    if not isinstance(recurrent, dict):
        raise fields.fail("recurrent", "an object (or absent: an MLP)", recurrent)
    names = fields.get(recurrent, "recurrent.inputs")
    if not (
        isinstance(names, list)
        and 1 <= len(names) <= 2
        and all(isinstance(name, str) and 0 < len(name) <= 64 for name in names)
        and all(name.isprintable() for name in names)
        and len(set(names)) == len(names)
        and "obs" not in names
    ):
        raise fields.fail("recurrent.inputs", "1 or 2 state names (h_in, c_in)", names)
    layers = fields.number(recurrent, "recurrent.layers", 1, MAX_RNN_LAYERS, whole=True)
    hidden = fields.number(recurrent, "recurrent.hidden", 1, MAX_RNN_HIDDEN, whole=True)
    return names, (layers, 1, hidden)


def _session(path: Path, names: list[str], width: int, state: tuple[int, int, int],
             actions: int, threads: int):  # fmt: skip
    """onnxruntime's session of the graph, once ``_check_graph`` has passed it.

    Args:
        names: the graph's inputs, ``obs`` then the states'.
        width: D, the input's width.
        state: the states' shape (layers, 1, hidden).
        actions: the action's width (12 or 16).
    """
    data = _read_capped(path, MAX_ONNX_BYTES)
    _check_graph(path, data, names, width, state, actions)
    try:
        import onnxruntime
    except ImportError:
        raise ImportError("rwalk.deploy needs onnxruntime: pip install 'rwalk[onnx]'") from None
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    try:  # the bytes checked, not the file again
        return onnxruntime.InferenceSession(data, options, providers=["CPUExecutionProvider"])
    except Exception as error:  # onnxruntime raises its own kinds for a bad file
        raise ValueError(f"{str(path)!r} is not a loadable ONNX model: {_line(error)}") from None


def _dims(info) -> list:
    """A value's dims: ints, names of dynamic ones (``batch``), None where unknown."""
    tensor = info.type.tensor_type
    return [d.dim_value if d.HasField("dim_value") else (d.dim_param or None)
            for d in tensor.shape.dim]  # fmt: skip


def _static(info) -> tuple[int, ...] | None:
    """A value's shape if every dim is known, else None."""
    tensor = info.type.tensor_type
    if not info.type.HasField("tensor_type") or not tensor.HasField("shape"):
        return None
    dims = tensor.shape.dim
    if not all(d.HasField("dim_value") and d.dim_value >= 0 for d in dims):
        return None
    return tuple(d.dim_value for d in dims)


def _check_graph(path: Path, data: bytes, names: list[str], width: int,
                 state: tuple[int, int, int], actions: int) -> None:  # fmt: skip
    """The ONNX graph, before onnxruntime sees it: the layout's float32 inputs and outputs,
    weights within ``MAX_WEIGHTS`` and kept in the file, and at batch 1 every tensor's
    size known and within ``MAX_TENSOR_VALUES``, and the step's work within ``MAX_WORK``."""
    try:
        import onnx
    except ImportError:
        raise ImportError("rwalk.deploy needs onnx: pip install onnx") from None
    where = repr(str(path))
    try:
        model = onnx.load_from_string(data)
    except Exception as error:  # protobuf's DecodeError and kin
        raise ValueError(f"{where} is not a loadable ONNX model: {_line(error)}") from None
    graph = model.graph
    if not graph.node:
        raise ValueError(f"{where} is not a loadable ONNX model: it has no graph")
    if len(graph.node) > MAX_NODES:
        raise ValueError(f"{where} has {len(graph.node)} nodes; at most MAX_NODES = {MAX_NODES}")
    inputs = _check_inputs(onnx, where, graph, names, width, state)
    _check_weights(onnx, where, model)
    if len(graph.output) != len(names) or any(
        output.type.tensor_type.elem_type != onnx.TensorProto.FLOAT for output in graph.output
    ):
        returns = _show([(o.name, _dims(o)) for o in graph.output])
        raise ValueError(f"{where} returns {returns}; policy.json's layout wants {len(names)} "
                         f"float32 outputs (the actions, then the states)")  # fmt: skip
    try:  # onnx raises many kinds for a graph it cannot follow
        shapes = _graph_shapes(onnx, model, inputs)
    except Exception as error:
        raise ValueError(f"{where}: onnx cannot infer the graph's shapes: {_line(error)}") from None
    _check_work(where, graph, shapes)
    wants = [(1, actions), *[state] * (len(names) - 1)]
    for output, want in zip(graph.output, wants, strict=True):
        if shapes.get(output.name) != want:
            raise ValueError(f"{where}: output {_show(output.name)} has shape "
                             f"{shapes.get(output.name)} at batch 1; want {want}")  # fmt: skip


def _check_inputs(onnx, where: str, graph, names: list[str], width: int,
                  state: tuple[int, int, int]) -> list:  # fmt: skip
    """The graph's inputs against the layout: names, float32, (batch, D) and the states'
    (layers, batch, hidden). Returns them with the batch set to 1."""
    weights = {tensor.name for tensor in graph.initializer}
    inputs = [info for info in graph.input if info.name not in weights]
    dims = [_dims(info) for info in inputs]
    obs = dims[0] if dims else []
    if [info.name for info in inputs] != names or not (
        len(obs) == 2 and obs[1] == width and _batch(obs[0])
    ):
        takes = [(info.name, shape) for info, shape in zip(inputs, dims, strict=True)]
        raise ValueError(f"{where} takes {_show(takes)}; policy.json says {names} with obs "
                         f"of width {width}")  # fmt: skip
    for info, shape in zip(inputs[1:], dims[1:], strict=True):
        if len(shape) != 3 or (shape[0], shape[2]) != (state[0], state[2]) or not _batch(shape[1]):
            raise ValueError(f"{where}'s {info.name} has shape {shape}; policy.json says "
                             f"(layers, batch, hidden) = {state}")  # fmt: skip
    fixed = []
    for info, shape in zip(inputs, dims, strict=True):
        kind = info.type.tensor_type.elem_type
        if kind != onnx.TensorProto.FLOAT:
            raise ValueError(f"{where}: input {_show(info.name)} must be float32, got "
                             f"{_type_name(onnx, kind)}")  # fmt: skip
        batch = [d if isinstance(d, int) else 1 for d in shape]
        fixed.append(onnx.helper.make_tensor_value_info(info.name, kind, batch))
    return fixed


def _batch(dim) -> bool:
    """Whether an input's dim takes the batch of 1 that ``step`` feeds: dynamic, or 1."""
    return not isinstance(dim, int) or dim == 1


def _type_name(onnx, kind: int) -> str:
    try:
        return onnx.TensorProto.DataType.Name(kind)
    except ValueError:
        return f"type {kind}"


def _check_weights(onnx, where: str, model) -> None:
    """Weights in the file (no external data, no sparse ones, no functions), each within
    ``MAX_TENSOR_VALUES`` and together within ``MAX_WEIGHTS``."""
    graph = model.graph
    if graph.sparse_initializer or model.functions:
        raise ValueError(f"{where} holds sparse weights or functions; rwalk.deploy runs "
                         f"plain graphs (as rwalk.export writes them)")  # fmt: skip
    tensors = list(graph.initializer)
    for node in graph.node:
        for attribute in node.attribute:
            tensors += [*([attribute.t] if attribute.HasField("t") else []), *attribute.tensors]
    total = 0
    for tensor in tensors:
        if tensor.data_location == onnx.TensorProto.EXTERNAL or tensor.external_data:
            raise ValueError(f"{where}: weight {_show(tensor.name)} is kept in another file; "
                             f"rwalk.deploy reads one self-contained file")  # fmt: skip
        dims = list(tensor.dims)
        values = math.prod(dims) if min(dims, default=0) >= 0 else -1
        if not 0 <= values <= MAX_TENSOR_VALUES:
            raise ValueError(f"{where}: weight {_show(tensor.name)} has shape {_show(dims)}: "
                             f"at most MAX_TENSOR_VALUES = {MAX_TENSOR_VALUES} values")  # fmt: skip
        total += values
    if total > MAX_WEIGHTS:
        raise ValueError(f"{where} has {total} weights; at most MAX_WEIGHTS = {MAX_WEIGHTS}")


def _graph_shapes(onnx, model, inputs: list) -> dict[str, tuple[int, ...] | None]:
    """Every tensor's shape at batch 1 (None: unknown before the graph runs), inferred by
    onnx on a copy of the graph whose large weights are left out (their shapes stand in)."""
    graph, helper = model.graph, onnx.helper
    small = [t for t in graph.initializer if math.prod(t.dims) <= 64]
    stand_ins = [helper.make_tensor_value_info(t.name, t.data_type, list(t.dims))
                 for t in graph.initializer if math.prod(t.dims) > 64]  # fmt: skip
    outputs = [helper.make_tensor_value_info(o.name, o.type.tensor_type.elem_type, None)
               for o in graph.output]  # fmt: skip
    light = helper.make_model(
        helper.make_graph(graph.node, "bounds", [*inputs, *stand_ins], outputs, small),
        opset_imports=model.opset_import, ir_version=model.ir_version,
    )  # fmt: skip
    inferred = onnx.shape_inference.infer_shapes(light, strict_mode=False, data_prop=True).graph
    shapes: dict[str, tuple[int, ...] | None] = {t.name: tuple(t.dims) for t in small}
    for info in (*inferred.input, *inferred.value_info, *inferred.output):
        shapes[info.name] = _static(info)
    return shapes


def _check_work(where: str, graph, shapes: dict[str, tuple[int, ...] | None]) -> None:
    """Only ``ONNX_OPS``; every tensor a node reads or writes of a known size within
    ``MAX_TENSOR_VALUES``; the step's work within ``MAX_WORK``."""
    work = 0
    for node in graph.node:
        standard = node.domain in ("", "ai.onnx")
        op = node.op_type if standard else f"{node.domain}.{node.op_type}"
        what = f"{_show(op)} node {_show(node.name)}"
        if not standard or node.op_type not in ONNX_OPS:
            raise ValueError(f"{where}: the {what} is not among rwalk.deploy.ONNX_OPS (the "
                             f"standard ops whose work it can bound)")  # fmt: skip
        for name in (*node.input, *node.output):
            shape = shapes.get(name) if name else ()
            if shape is None:
                raise ValueError(f"{where}: the size of {_show(name)} ({what}) is unknown "
                                 f"before the graph runs; rwalk.deploy needs every size "
                                 f"at batch 1 to bound the work")  # fmt: skip
            if math.prod(shape) > MAX_TENSOR_VALUES:
                raise ValueError(f"{where}: {_show(name)} ({what}) has shape {shape} at "
                                 f"batch 1: at most MAX_TENSOR_VALUES = {MAX_TENSOR_VALUES} "
                                 f"values")  # fmt: skip
        work += _node_work(node, shapes)
        if work > MAX_WORK:
            raise ValueError(f"{where}: a step's work passes MAX_WORK = {MAX_WORK} (values "
                             f"read and written, multiply-adds) at the {what}")  # fmt: skip


def _node_work(node, shapes: dict[str, tuple[int, ...] | None]) -> int:
    """A node's work at batch 1, an upper bound: the values it reads and writes, plus the
    multiply-adds of a MatMul or Gemm (output x inner size) or a recurrent node (steps x
    the weights W and R)."""
    reads = [shapes[name] or () for name in node.input if name]
    writes = [shapes[name] or () for name in node.output if name]
    work = sum(math.prod(shape) for shape in (*reads, *writes))
    if node.op_type in ("MatMul", "Gemm") and reads and writes:
        work += math.prod(writes[0]) * max(reads[0], default=1)
    elif node.op_type in ("GRU", "LSTM", "RNN") and reads:
        steps = math.prod(reads[0][:2])  # (seq, batch) or (batch, seq)
        work += steps * sum(math.prod(shape) for shape in reads[1:3])
    return work


class TableGait:
    """The residual task's fixed trot: base targets looked up by tick, plus residuals.
    Built from a deploy section that ``_check_deploy`` has passed."""

    action_dim = 12
    """The action's width: foot offsets FL, FR, RL, RR (x, y, z)."""

    def __init__(self, deploy: dict, geometry: LegGeometry) -> None:
        self.geometry = geometry
        self.substeps = int(deploy["substeps"])
        self.residual_scale = float(deploy["residual_scale"])
        self.targets = np.array(deploy["gait"]["targets"], dtype=np.float64)
        """Base foot targets at each tick of the cycle, hip frames. Shape: (P, 4, 3). m."""
        self.table = np.array(deploy["gait"]["phase_features"], dtype=np.float64)
        """(sin 2πφ, cos 2πφ) at each tick. Shape: (P, 2)."""
        self.period = len(self.targets)
        self.tick = 0

    def reset(self, tick: int) -> None:
        self.tick = tick

    def observation(self) -> np.ndarray:
        """What the task's spec observation adds to the sensors: nothing."""
        return np.zeros(0)

    def phase_features(self) -> np.ndarray:
        return self.table[self.tick]

    def joints(self, action: np.ndarray | None, command: float | None = None) -> np.ndarray:
        """This period's joint targets for a clipped action (None: the base gait's, the
        state unchanged); an action also moves the gait on by one period (the command
        changes nothing: the trot's speed is fixed). (K, 12)."""
        targets = self.targets[(self.tick + np.arange(self.substeps)) % self.period]
        if action is not None:
            targets = targets + action.reshape(4, 3) * self.residual_scale
        joints, _ = leg_ik(targets, self.geometry, flag_unreachable=False)
        if action is not None:
            self.tick = (self.tick + self.substeps) % self.period
        return joints.reshape(self.substeps, 12)


class AdaptiveGait:
    """The adaptive task's gait: four parameters moved by the action (its "delta",
    "target" or "schedule" reading), a continuous phase, foot paths by ``rwalk.gaitmath``,
    residuals. Built from a deploy section that ``_check_deploy`` has passed."""

    action_dim = 16
    """The action's width: the four parameters' moves, then the 12 foot offsets."""

    def __init__(self, deploy: dict, geometry: LegGeometry) -> None:
        self.geometry = geometry
        self.substeps = int(deploy["substeps"])
        self.dt = float(deploy["dt"])
        self.residual_scale = float(deploy["residual_scale"])
        gait, adaptive = deploy["gait"], deploy["adaptive"]
        self.period = int(gait["period"])
        self.duty_factor = float(gait["duty_factor"])
        self.stance_depth = float(gait["stance_depth"])
        self.offsets, self.swing_points, self.neutral = (
            np.array(gait[key], dtype=np.float64) for key in ("offsets", "swing_points", "neutral")
        )
        self.start, self.low, self.high, self.delta = (
            np.array(adaptive[key], dtype=np.float64) for key in ("start", "low", "high", "delta")
        )
        self.centre = 0.5 * (self.low + self.high)
        self.half_width = 0.5 * (self.high - self.low)
        self.gait_action = adaptive["gait_action"]
        if self.gait_action == "schedule":
            schedule = adaptive["schedule"]
            self.stride = float(schedule["stride"])
            self.span = np.array(schedule["window"], dtype=np.float64) * self.half_width
            self.speed = float(schedule["speed"])
            """The target velocity when the policy reads no command. m/s."""
            self.step_rise = float(schedule.get("step_rise", 0.0))
        self.reset(0)

    def scheduled(self, command: float | None) -> np.ndarray:
        """The gait the target velocity asks for (``rwalk.gaitmath.speed_schedule``)."""
        speed = self.speed if command is None else command
        return speed_schedule(np.array([speed]), self.stride, self.low, self.high,
                              self.start, self.step_rise, self.speed)[0]  # fmt: skip

    def reset(self, tick: int) -> None:
        self.params = self.start.copy()
        """step_height, step_length, cycle_time, body_height (m, s). Shape: (4,)."""
        self.phase = np.array([tick / self.period])
        """The continuous gait phase. Shape: (1,)."""

    def observation(self) -> np.ndarray:
        """The parameters as the spec observation's last 4 values (v - centre) / half_width."""
        return (self.params - self.centre) / self.half_width

    def phase_features(self) -> np.ndarray:
        angle = 2.0 * math.pi * self.phase
        return np.concatenate([exactmath.sin(angle), exactmath.cos(angle)])

    def joints(self, action: np.ndarray | None, command: float | None = None) -> np.ndarray:
        """This period's joint targets for a clipped action (None: the current gait with
        no residuals, the state unchanged); an action moves the parameters and the
        phase as the env does, with "schedule" around the gait that ``command`` (m/s, the
        export's fixed speed when None) asks for. Shape: (K, 12)."""
        params = self.params
        if action is not None:
            if self.gait_action == "delta":
                moved = params + action[:4] * self.delta
            else:
                if self.gait_action == "target":
                    target = self.centre + action[:4] * self.half_width
                else:
                    target = self.scheduled(command) + action[:4] * self.span
                moved = params + np.minimum(np.maximum(target - params, -self.delta), self.delta)
            params = np.minimum(np.maximum(moved, self.low), self.high)
        k = self.substeps
        phases = advance_phase(self.phase, params[2:3], self.dt, k)
        step_height, step_length, body_height = (params[i : i + 1, None, None] for i in (0, 1, 3))
        stance_z = -body_height + self.geometry.foot_radius - self.stance_depth
        targets, _ = trot_targets(phases[:, :k], step_height, step_length, stance_z,
                                  self.duty_factor, self.offsets, self.swing_points,
                                  self.neutral)  # fmt: skip
        if action is not None:
            targets = targets + action[4:].reshape(1, 1, 4, 3) * self.residual_scale
            self.params, self.phase = params, phases[:, k]
        joints, _ = leg_ik(targets, self.geometry, flag_unreachable=False)
        return joints.reshape(k, 12)
