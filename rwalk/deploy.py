"""A runtime for exported policies that imports no torch: numpy and onnxruntime only.

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

Bad readings (wrong length, NaN or inf) never reach a servo: a wrong length is
a ``ValueError``; a non-finite reading, or a non-finite policy output, makes
``step`` return the last safe targets again (``controller.held`` says so,
and a warning names the reading), and the next finite readings go on.

Runs both tasks' policies (MLP or recurrent): the residual task's fixed trot from
its exported tables, the adaptive task's gait from its parameters with the
functions the env uses (``rwalk.gaitmath``).
"""

from __future__ import annotations

import json
import math
import os
import warnings
from pathlib import Path

import numpy as np

from rwalk import exactmath
from rwalk.constants import OBS_CONTACT, OBS_DIM, OBS_LINVEL, OBS_POS, OBSERVATION_SENSORS
from rwalk.gaitmath import advance_phase, trot_targets
from rwalk.kinematics import LegGeometry, leg_ik

#: The readings ``Controller.step`` takes: (sensor name, width), in order (65 values).
SENSOR_LAYOUT = OBSERVATION_SENSORS
#: The pieces a deployed policy may read (the rest need the simulator: privileged).
DEPLOYABLE = ("observation", "observation_from_start", "phase", "lateral_offset",
              "cycle_speed", "command")  # fmt: skip
#: The tasks whose policies it runs.
TASKS = ("residual_walk", "adaptive_gait")
#: What an export folder holds for the runtime.
FILES = ("policy.json", "policy.onnx")


class Controller:
    """An exported policy with its gait and inverse kinematics, stepping one robot.

    Args:
        folder: an export folder (``policy.onnx`` and ``policy.json`` with its
            ``deploy`` section, as ``rwalk.export.export_policy`` writes them).
        threads: onnxruntime's intra-op threads (1: one core).

    Raises:
        FileNotFoundError: a missing file, named.
        ValueError: a ``policy.json`` that is not JSON, has no ``deploy`` section,
            names a task or piece this runtime cannot run, or disagrees with the
            ONNX graph (naming what).
    """

    def __init__(self, folder: str | os.PathLike[str], *, threads: int = 1) -> None:
        folder = Path(folder)
        for name in FILES:
            if not (folder / name).is_file():
                raise FileNotFoundError(f"export folder {str(folder)!r} has no {name}")
        layout = _read_layout(folder / "policy.json")
        deploy = layout["deploy"]
        self.pieces = [piece["name"] for piece in layout["input"]["pieces"]]
        cannot = [name for name in self.pieces if name not in DEPLOYABLE]
        if cannot:
            raise ValueError(
                f"the policy reads {cannot} (privileged: only the simulator knows them); "
                f"deploy a student (rwalk-train --distill) that reads {DEPLOYABLE}"
            )
        try:  # the deploy section is data: a missing or malformed entry is named
            self.width = int(layout["input"]["shape"][1])
            self.substeps = int(deploy["substeps"])
            """K: physics substeps per control period (rows of ``step``'s targets)."""
            self.dt = float(deploy["dt"])
            """Seconds per substep: how long each row of targets is held."""
            self.control_dt = self.substeps * self.dt
            self.geometry = LegGeometry(
                **{k: _tuples(v) for k, v in deploy["leg_geometry"].items()}
            )
            gait = (TableGait if deploy["task"] == "residual_walk" else AdaptiveGait)(
                deploy, self.geometry
            )
        except (KeyError, IndexError, TypeError, ValueError) as error:
            raise ValueError(
                f"{str(folder / 'policy.json')!r}: the deploy section is incomplete "
                f"or malformed ({type(error).__name__}: {error})"
            ) from None
        self.gait: TableGait | AdaptiveGait = gait
        """The gait and its state (phase; the adaptive task's parameters)."""
        self.period = gait.period
        self.window = int(deploy["cycle_steps"])
        self.session, self.state_shapes = _session(
            folder / "policy.onnx", layout, self.width, threads
        )
        """onnxruntime's session; the recurrent states' shapes (layers, 1, hidden)."""
        self.command: float | None = None
        """The target velocity (m/s) a commanded policy (piece ``command``) reads; set it."""
        self.held = False
        """Whether the last ``step`` returned held targets (bad readings or outputs)."""
        self._started = False

    def reset(self, readings, tick: int = 0) -> np.ndarray:
        """Begin a walk from the robot's current readings.

        Args:
            readings: the sensors (``SENSOR_LAYOUT``). Shape: (65,).
            tick: the gait's substep in its cycle at the start (the env's starts: its
                ``settled_tick``; 0 begins the trot at phase 0).

        Returns:
            The base gait's targets of the first period, the safe targets held until
            the first ``step``. Shape: (K, 12).
        """
        readings = self._check(readings)
        if not np.isfinite(readings).all():
            raise ValueError(f"reset needs finite readings; got {_bad(readings)}")
        if not 0 <= int(tick) < self.period or int(tick) != tick:
            raise ValueError(f"tick must be a whole number in [0, {self.period}), got {tick!r}")
        self.gait.reset(int(tick))
        self.x0, self.y0 = float(readings[OBS_POS.start]), float(readings[OBS_POS.start + 1])
        v0 = readings[OBS_LINVEL.start]
        self.recent = np.full(self.window, v0)
        self.recent_sum = v0 * self.window
        self.slot = 0
        self.state = [np.zeros(shape, dtype=np.float32) for shape in self.state_shapes]
        self._fresh, self._started, self.held = True, True, False
        self.safe = self.gait.joints(None)
        return self.safe

    def step(self, readings) -> np.ndarray:
        """One control period: readings in, the period's servo targets out.

        Args:
            readings: the sensors now (``SENSOR_LAYOUT``). Shape: (65,).

        Returns:
            Joint targets for each substep of the period, actuator order. Shape: (K, 12).

        Raises:
            ValueError: readings of the wrong shape; RuntimeError: before ``reset``.
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
        if not np.isfinite(action).all():
            return self._hold(f"a non-finite policy output {action[0].tolist()}")
        self.state = state
        action = np.minimum(np.maximum(action[0].astype(np.float64), -1.0), 1.0)
        self.safe = self.gait.joints(action)
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
            else:  # command
                if self.command is None or not math.isfinite(self.command):
                    raise ValueError(f"the policy reads a command: set controller.command "
                                     f"(m/s), got {self.command!r}")  # fmt: skip
                parts.append([float(self.command)])
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
        array = np.asarray(readings, dtype=np.float64)
        if array.shape != (OBS_DIM,):
            raise ValueError(f"readings must be {OBS_DIM} values (rwalk.deploy.SENSOR_LAYOUT), "
                             f"got shape {array.shape}")  # fmt: skip
        return array

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


def _read_layout(path: Path) -> dict:
    try:
        layout = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as error:
        raise ValueError(f"{str(path)!r} is not JSON: {str(error)[:200]}") from None
    try:
        pieces = layout["input"]["pieces"]
        deploy = layout["deploy"]
        task = deploy["task"]
    except (KeyError, TypeError):
        raise ValueError(
            f"{str(path)!r} has no deploy section (input.pieces, deploy.task): export the "
            f"policy with this rwalk (rwalk-sim2sim CHECKPOINT --export FOLDER)"
        ) from None
    if task not in TASKS:
        raise ValueError(f"{str(path)!r} is a {task!r} policy; rwalk.deploy runs {TASKS}")
    if not isinstance(pieces, list) or not all(isinstance(p, dict) for p in pieces):
        raise ValueError(f"{str(path)!r}: input.pieces must be a list of pieces")
    return layout


def _session(path: Path, layout: dict, width: int, threads: int):
    """onnxruntime's session, checked against the layout; the states' shapes (batch 1)."""
    try:
        import onnxruntime
    except ImportError:
        raise ImportError("rwalk.deploy needs onnxruntime: pip install 'rwalk[onnx]'") from None
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    try:
        session = onnxruntime.InferenceSession(
            str(path), options, providers=["CPUExecutionProvider"]
        )
    except Exception as error:  # onnxruntime raises its own kinds for a bad file
        raise ValueError(
            f"{str(path)!r} is not a loadable ONNX model: {str(error)[:200]}"
        ) from None
    inputs = session.get_inputs()
    recurrent = layout.get("recurrent")
    want = ["obs", *(recurrent["inputs"] if recurrent else [])]
    if [i.name for i in inputs] != want or inputs[0].shape[-1] != width:
        raise ValueError(
            f"{str(path)!r} takes {[(i.name, i.shape) for i in inputs]}; policy.json says "
            f"{want} with obs of width {width}"
        )
    if not recurrent:
        return session, []
    shapes = [(int(recurrent["layers"]), 1, int(recurrent["hidden"]))] * (len(want) - 1)
    for node, shape in zip(inputs[1:], shapes, strict=True):
        if node.shape[0] != shape[0] or node.shape[2] != shape[2]:
            raise ValueError(f"{str(path)!r}'s {node.name} has shape {node.shape}; policy.json "
                             f"says (layers, batch, hidden) = {shape}")  # fmt: skip
    return session, shapes


class TableGait:
    """The residual task's fixed trot: base targets looked up by tick, plus residuals."""

    def __init__(self, deploy: dict, geometry: LegGeometry) -> None:
        self.geometry = geometry
        self.substeps = int(deploy["substeps"])
        self.residual_scale = float(deploy["residual_scale"])
        self.targets = np.array(deploy["gait"]["targets"], dtype=np.float64)
        """Base foot targets at each tick of the cycle, hip frames. Shape: (P, 4, 3). m."""
        self.table = np.array(deploy["gait"]["phase_features"], dtype=np.float64)
        """(sin 2πφ, cos 2πφ) at each tick. Shape: (P, 2)."""
        self.period = len(self.targets)
        if self.targets.shape != (self.period, 4, 3) or self.table.shape != (self.period, 2):
            raise ValueError(f"policy.json's deploy.gait tables have shapes "
                             f"{self.targets.shape}, {self.table.shape}; want (P, 4, 3), "
                             f"(P, 2)")  # fmt: skip
        self.tick = 0

    def reset(self, tick: int) -> None:
        self.tick = tick

    def observation(self) -> np.ndarray:
        """What the task's spec observation adds to the sensors: nothing."""
        return np.zeros(0)

    def phase_features(self) -> np.ndarray:
        return self.table[self.tick]

    def joints(self, action: np.ndarray | None) -> np.ndarray:
        """This period's joint targets for a clipped action (None: the base gait's, the
        state unchanged); an action also moves the gait on by one period. (K, 12)."""
        targets = self.targets[(self.tick + np.arange(self.substeps)) % self.period]
        if action is not None:
            targets = targets + action.reshape(4, 3) * self.residual_scale
        joints, _ = leg_ik(targets, self.geometry, flag_unreachable=False)
        if action is not None:
            self.tick = (self.tick + self.substeps) % self.period
        return joints.reshape(self.substeps, 12)


class AdaptiveGait:
    """The adaptive task's gait: four parameters moved by the action (its "delta" or
    "target" reading), a continuous phase, foot paths by ``rwalk.gaitmath``, residuals."""

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
        if self.gait_action not in ("delta", "target"):
            raise ValueError(f"policy.json's deploy.adaptive.gait_action must be 'delta' or "
                             f"'target', got {self.gait_action!r}")  # fmt: skip
        self.reset(0)

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

    def joints(self, action: np.ndarray | None) -> np.ndarray:
        """This period's joint targets for a clipped action (None: the current gait with
        no residuals, the state unchanged); an action moves the parameters and the
        phase as the env does. Shape: (K, 12)."""
        params = self.params
        if action is not None:
            if self.gait_action == "delta":
                moved = params + action[:4] * self.delta
            else:
                target = self.centre + action[:4] * self.half_width
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
