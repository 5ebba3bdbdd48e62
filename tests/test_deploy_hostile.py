"""rwalk.deploy against crafted and broken files and inputs (a hostile tester's findings):
each ends in success or a one-line ValueError naming the file and the field, with bounded
memory and time, and no crafted file or reading puts a non-finite value into a target.

Each file is a real export (tests/deploy_exports.py) with one thing corrupted."""

from __future__ import annotations

import json
import math
import re
import warnings
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper
from test_deploy_runtime import _copy, _edit, export_folders

from rwalk import deploy
from rwalk.deploy import SENSOR_LAYOUT, Controller

NAN, INF = math.nan, math.inf


def _short(value) -> str:
    """A test id: the value's repr, at most 20 characters."""
    text = repr(value)
    return text if len(text) <= 20 else text[:17] + "..."


@pytest.fixture(scope="module")
def exports(tmp_path_factory) -> Path:
    return export_folders(tmp_path_factory)


@pytest.fixture
def readings(exports) -> np.ndarray:
    return np.load(exports / "readings.npy")[0]


def _refused(folder: Path, pattern: str) -> str:
    """Loading ``folder`` is a one-line ValueError naming a file and matching ``pattern``."""
    with pytest.raises(ValueError) as caught:
        Controller(folder)
    message = str(caught.value)
    assert type(caught.value) is ValueError and "\n" not in message, message
    assert re.search(r"policy\.(json|onnx)", message), message
    assert re.search(pattern, message), message
    return message


def _path(keys: tuple) -> str:
    """("deploy", "gait", "targets", 3, 1) -> 'deploy.gait.targets[3][1]'"""
    parts = [f"[{key}]" if isinstance(key, int) else f".{key}" for key in keys]
    return "".join(parts)[1:]


def _get(layout: dict, keys: tuple):
    for key in keys:
        layout = layout[key]
    return layout


def _set(keys: tuple, value):
    """An edit of policy.json that sets the value at ``keys``."""

    def change(layout):
        _get(layout, keys[:-1])[keys[-1]] = value

    return change


def _drop(keys: tuple):
    """An edit of policy.json that removes the entry at ``keys``."""

    def change(layout):
        del _get(layout, keys[:-1])[keys[-1]]

    return change


# (export, keys, bad value, what the message says after "must be")
BAD_NUMBERS = [
    ("mlp", ("deploy", "residual_scale"), NAN, r"a finite number in \[0, 10\], got nan"),
    ("mlp", ("deploy", "residual_scale"), INF, r"a finite number in \[0, 10\], got inf"),
    (
        "mlp",
        ("deploy", "leg_geometry", "thigh_length"),
        NAN,
        r"a finite number in \[0\.001, 10\], got nan",
    ),
    (
        "mlp",
        ("deploy", "leg_geometry", "thigh_length"),
        0,
        r"a finite number in \[0\.001, 10\], got 0",
    ),
    ("mlp", ("deploy", "leg_geometry", "thigh_length"), 1e308, r".*got 1e\+308"),
    ("mlp", ("deploy", "leg_geometry", "thigh_length"), "0.05", r".*got '0\.05'"),
    ("mlp", ("deploy", "leg_geometry", "joint_lower", 1), NAN, r".*got nan"),
    ("mlp", ("deploy", "leg_geometry", "joint_upper", 2), INF, r".*got inf"),
    (
        "mlp",
        ("deploy", "leg_geometry", "hip_positions", 0),
        [0.1, 0.0],
        r"a list of 3 numbers, got a list of 2",
    ),
    ("mlp", ("deploy", "gait", "targets", 3, 1, 2), NAN, r".*got nan"),
    (
        "mlp",
        ("deploy", "gait", "phase_features", 7, 0),
        -INF,
        r"a finite number in \[-1, 1\], got -inf",
    ),
    (
        "mlp",
        ("deploy", "gait", "phase_features"),
        [[0.0, 1.0]],
        r"a list of 150 lists, got a list of 1",
    ),
    ("mlp", ("deploy", "dt"), NAN, r".*got nan"),
    ("mlp", ("deploy", "cycle_steps"), 0, r"a whole number in \[1, 100000\], got 0"),
    ("mlp", ("deploy", "cycle_steps"), 10**12, r".*got 1000000000000"),
    ("mlp", ("deploy", "cycle_steps"), 30.0, r"a whole number .*got 30\.0"),
    ("mlp", ("deploy", "substeps"), 10**9, r"a whole number in \[1, 1000\], got 1000000000"),
    ("mlp", ("deploy", "substeps"), True, r"a whole number .*got True"),
    ("adaptive", ("deploy", "gait", "period"), 0, r"a whole number in \[1, 20000\], got 0"),
    (
        "adaptive",
        ("deploy", "gait", "duty_factor"),
        NAN,
        r"a finite number in \[0\.01, 0\.99\], got nan",
    ),
    (
        "adaptive",
        ("deploy", "gait", "duty_factor"),
        1.0,
        r"a finite number in \[0\.01, 0\.99\], got 1\.0",
    ),
    ("adaptive", ("deploy", "gait", "swing_points", 2, 1), NAN, r".*got nan"),
    ("adaptive", ("deploy", "gait", "neutral", 0, 2), None, r".*got None"),
    ("adaptive", ("deploy", "gait", "offsets", 1), INF, r"a finite number in \[0, 1\], got inf"),
    ("adaptive", ("deploy", "adaptive", "start", 0), NAN, r".*got nan"),
    (
        "adaptive",
        ("deploy", "adaptive", "delta", 3),
        -0.001,
        r"a finite number in \[0, 10\], got -0\.001",
    ),
    ("adaptive", ("deploy", "adaptive", "low", 2), 0, r"a finite number in \[0\.001, 10\], got 0"),
    (
        "adaptive",
        ("deploy", "adaptive", "gait_action"),
        "jump",
        r"one of \('delta', 'target', 'schedule'\), got 'jump'",
    ),
    (
        "schedule",
        ("deploy", "adaptive", "schedule", "window", 1),
        1.5,
        r"a finite number in \[0, 1\], got 1\.5",
    ),
    (
        "schedule",
        ("deploy", "adaptive", "schedule", "stride"),
        0.0,
        r"a finite number in \[0\.001, 10\], got 0\.0",
    ),
    ("schedule", ("deploy", "adaptive", "schedule", "speed"), NAN, r".*got nan"),
    (
        "schedule",
        ("deploy", "adaptive", "schedule", "step_rise"),
        -0.04,
        r"a finite number in \[0, 1\], got -0\.04",
    ),
    ("gru", ("recurrent",), [1, 2], r"an object \(or absent: an MLP\), got \[1, 2\]"),
    ("gru", ("recurrent", "hidden"), 10**9, r"a whole number in \[1, 4096\], got 1000000000"),
    ("gru", ("input", "shape", 1), -68, r"a whole number in \[1, 4096\], got -68"),
]


@pytest.mark.parametrize(
    ("actor", "keys", "value", "says"),
    BAD_NUMBERS,
    ids=[f"{_path(keys)}={value!r}" for _, keys, value, _ in BAD_NUMBERS],
)
def test_a_bad_deploy_value_is_a_one_line_error_naming_the_field(
    exports, tmp_path, actor, keys, value, says
):
    folder = _copy(exports, tmp_path, actor)
    _edit(folder, _set(keys, value))
    _refused(folder, rf"policy\.json': {re.escape(_path(keys))} must be {says}$")


MISSING = [
    ("mlp", ("deploy", "cycle_steps")),
    ("mlp", ("deploy", "leg_geometry", "shin_length")),
    ("mlp", ("deploy", "gait", "phase_features")),
    ("mlp", ("input", "pieces", 0, "name")),
    ("mlp", ("input", "shape")),
    ("adaptive", ("deploy", "gait", "duty_factor")),
    ("adaptive", ("deploy", "adaptive")),
    ("schedule", ("deploy", "adaptive", "schedule")),
    ("schedule", ("deploy", "adaptive", "schedule", "window")),
    ("gru", ("recurrent", "layers")),
]


@pytest.mark.parametrize(("actor", "keys"), MISSING, ids=[_path(keys) for _, keys in MISSING])
def test_a_missing_deploy_field_is_named(exports, tmp_path, actor, keys):
    folder = _copy(exports, tmp_path, actor)
    _edit(folder, _drop(keys))
    _refused(folder, rf"policy\.json': {re.escape(_path(keys))} is missing$")


def test_values_that_contradict_each_other_are_named(exports, tmp_path):
    folder = _copy(exports, tmp_path / "a")
    _edit(folder, _set(("deploy", "leg_geometry", "joint_lower", 0), 0.8))  # above 0.7
    _refused(folder, r"joint_lower must be <= joint_upper at each joint, got \[0\.8, ")
    folder = _copy(exports, tmp_path / "b", "adaptive")
    _edit(folder, _set(("deploy", "adaptive", "high", 0), 0.01))  # = low
    _refused(folder, r"deploy\.adaptive\.high must be above low by 1e-09 or more")
    folder = _copy(exports, tmp_path / "c", "adaptive")
    _edit(folder, _set(("deploy", "adaptive", "start", 2), 0.95))  # above high 0.9
    _refused(folder, r"deploy\.adaptive\.start must be within \[low, high\], got \[0\.025")
    folder = _copy(exports, tmp_path / "knee")  # each in range: the IK's reach is sqrt(-1e-15)
    legs = {"thigh_length": 6.777882967240282, "shin_length": 6.77788296724028}
    _edit(folder, lambda layout: layout["deploy"]["leg_geometry"].update(legs))
    _edit(folder, _set(("deploy", "leg_geometry", "joint_lower", 2), -math.pi))
    _refused(folder, r"deploy\.leg_geometry must be legs whose reach at the knee limits is "
                     r"real, got thigh and shin \[6\.777882967240282, 6\.77788296724028\], "
                     r"knee limits \[-3\.141592653589793, -0\.25\]$")  # fmt: skip
    folder = _copy(exports, tmp_path / "d")
    _edit(folder, lambda layout: layout["input"]["pieces"].pop())  # 67 values, D = 68
    _refused(folder, r"input\.pieces \['observation_from_start', 'phase'\] make 67 values; "
                     r"input\.shape\[1\] says 68$")  # fmt: skip


def test_nesting_and_size_are_capped_before_parsing(exports, tmp_path):
    folder = _copy(exports, tmp_path / "deep")
    layout = json.loads((folder / "policy.json").read_text())
    layout["deploy"]["leg_geometry"]["thigh_length"] = "DEEP"
    text = json.dumps(layout).replace('"DEEP"', "[" * 900 + "0.05" + "]" * 900)
    (folder / "policy.json").write_text(text)
    _refused(folder, r"policy\.json' nests lists and objects 903 deep; rwalk\.deploy reads "
                     r"at most 32$")  # fmt: skip
    limits = {"policy.json": deploy.MAX_JSON_BYTES, "policy.onnx": deploy.MAX_ONNX_BYTES}
    for name, most in limits.items():
        folder = _copy(exports, tmp_path / name)
        with (folder / name).open("r+b") as file:
            file.truncate(most + 1)  # sparse: nothing is written, and nothing must be read
        _refused(folder, rf"{name}' holds {most + 1} bytes; rwalk\.deploy reads at most {most}$")


def _graph(exports: Path, tmp_path: Path, change, actor: str = "mlp") -> Path:
    """A copy of an export whose ONNX graph ``change(graph)`` edits."""
    folder = _copy(exports, tmp_path, actor)
    model = onnx.load(folder / "policy.onnx")
    change(model.graph)
    (folder / "policy.onnx").write_bytes(model.SerializeToString())
    return folder


def _add_to_actions(graph, nodes: list, weights: dict[str, np.ndarray], extra: str) -> None:
    """Add the scalar ``extra`` (what ``nodes`` compute from ``obs``) to the actions."""
    (producer,) = [node for node in graph.node if "actions" in node.output]
    producer.output[list(producer.output).index("actions")] = "actions_base"
    graph.initializer.extend(numpy_helper.from_array(v, k) for k, v in weights.items())
    graph.node.extend([*nodes, helper.make_node("Add", ["actions_base", extra], ["actions"])])


def _zero_times(value: str) -> list:
    """Nodes: ``extra`` = 0 x the sum of ``value`` (a branch whose result does not show)."""
    return [
        helper.make_node("ReduceSum", [value], ["total"], keepdims=0),
        helper.make_node("Mul", ["total", "zero"], ["extra"]),
    ]


ZERO = {"zero": np.zeros((), np.float32)}


@pytest.mark.parametrize("kind", [TensorProto.DOUBLE, TensorProto.INT64], ids=["f64", "i64"])
def test_an_onnx_graph_must_take_float32(exports, tmp_path, kind):
    def wider_obs(graph):
        graph.input[0].type.tensor_type.elem_type = kind
        for node in graph.node:
            node.input[:] = ["obs32" if name == "obs" else name for name in node.input]
        graph.node.insert(0, helper.make_node("Cast", ["obs"], ["obs32"], to=TensorProto.FLOAT))

    folder = _graph(exports, tmp_path, wider_obs)
    name = TensorProto.DataType.Name(kind)
    _refused(folder, rf"policy\.onnx': input 'obs' must be float32, got {name}$")


@pytest.mark.parametrize(
    ("n", "says"),
    [
        (65536, r"'big' \('Expand' node ''\) has shape \(65536, 65536\) at batch 1: at most "
                r"MAX_TENSOR_VALUES = 134217728 values$"),
        (30000, r"has shape \(30000, 30000\) at batch 1: at most MAX_TENSOR_VALUES"),
        (2048, r"a step's work passes MAX_WORK = 2147483648 .* at the 'MatMul' node ''$"),
    ],
)  # fmt: skip
def test_an_onnx_graph_of_enormous_work_is_refused_at_load(exports, tmp_path, n, says):
    """A MatMul of an n x n tensor expanded from the input (16 GiB for 65536): refused
    before onnxruntime sees the graph, nothing runs."""

    def enormous(graph):
        nodes = [
            *_zero_times("obs"),
            helper.make_node("Expand", ["extra", "shape"], ["big"]),
            helper.make_node("MatMul", ["big", "big"], ["square"]),
            helper.make_node("ReduceSum", ["square"], ["sum"], keepdims=0),
            helper.make_node("Mul", ["sum", "zero"], ["extra2"]),
        ]
        _add_to_actions(graph, nodes, {**ZERO, "shape": np.array([n, n])}, "extra2")

    _refused(_graph(exports, tmp_path, enormous), says)


def test_an_onnx_graph_whose_sizes_come_from_its_input_is_refused(exports, tmp_path):
    def sized_by_obs(graph):
        nodes = [
            helper.make_node("ReduceMax", ["obs"], ["peak"], keepdims=1),
            helper.make_node("Cast", ["peak"], ["count"], to=TensorProto.INT64),
            helper.make_node("Reshape", ["count", "one"], ["count1"]),
            helper.make_node("ConstantOfShape", ["count1"], ["row"]),
            *_zero_times("row"),
        ]
        _add_to_actions(graph, nodes, {**ZERO, "one": np.array([1])}, "extra")

    folder = _graph(exports, tmp_path, sized_by_obs)
    _refused(folder, r"the size of 'row' \('ConstantOfShape' node ''\) is unknown before the "
                     r"graph runs")  # fmt: skip


def test_an_onnx_graph_of_ops_whose_work_it_cannot_bound_is_refused(exports, tmp_path):
    def outer_product(graph):
        nodes = [helper.make_node("Einsum", ["obs", "obs"], ["outer"], equation="bi,bj->ij"),
                 *_zero_times("outer")]  # fmt: skip
        _add_to_actions(graph, nodes, ZERO, "extra")

    folder = _graph(exports, tmp_path, outer_product)
    _refused(folder, r"policy\.onnx': the 'Einsum' node '' is not among rwalk\.deploy\.ONNX_OPS")


def test_an_onnx_graph_with_the_wrong_outputs_or_outside_weights_is_refused(exports, tmp_path):
    def thirteen_actions(graph):
        for tensor in graph.initializer:
            if tensor.name in ("mlp.2.weight", "mlp.2.bias"):
                wider = np.zeros((13, *tensor.dims[1:]), np.float32)
                tensor.CopyFrom(numpy_helper.from_array(wider, tensor.name))
        graph.output[0].type.tensor_type.shape.dim[1].dim_value = 13

    folder = _graph(exports, tmp_path / "a", thirteen_actions)
    _refused(folder, r"output 'actions' has shape \(1, 13\) at batch 1; want \(1, 12\)$")

    def no_states(graph):
        del graph.output[1]

    folder = _graph(exports, tmp_path / "b", no_states, "gru")
    _refused(folder, r"policy\.json's layout wants 2 float32 outputs")

    def outside(graph):
        tensor = graph.initializer[0]
        tensor.ClearField("raw_data")
        tensor.data_location = TensorProto.EXTERNAL
        tensor.external_data.add(key="location", value="weights.bin")

    folder = _graph(exports, tmp_path / "c", outside)
    _refused(folder, r"weight 'mlp\.0\.weight' is kept in another file")


BAD_READINGS = {
    "dict": lambda r: {
        f"{name}_{i}": v for i, (name, v) in enumerate(zip(_names(), r, strict=True))
    },
    "object array": lambda r: np.array([*r[:64], None], dtype=object),
    "object array of floats": lambda r: r.astype(object),
    "strings": lambda r: [str(v) for v in r],
    "a string": lambda r: ",".join(map(str, r)),
    "bytes": lambda r: r.tobytes(),
    "ragged": lambda r: [r[:30].tolist(), r[30:].tolist()],
    "booleans": lambda r: r > 0,
    "complex": lambda r: r + 0j,
}


def _names() -> list[str]:
    return [name for name, width in SENSOR_LAYOUT for _ in range(width)]


@pytest.mark.parametrize("make", BAD_READINGS.values(), ids=BAD_READINGS.keys())
def test_readings_that_are_not_numbers_are_a_value_error_naming_them(exports, readings, make):
    controller = Controller(exports / "mlp")
    bad = make(readings)
    with pytest.raises(ValueError, match=r"^readings must be 65 real numbers .* got \w+ of dtype"):
        controller.reset(bad)
    controller.reset(readings.tolist())  # a list of floats is fine
    with pytest.raises(ValueError, match=r"^readings must be 65 real numbers"):
        controller.step(bad)
    assert np.isfinite(controller.step(readings.astype(np.float32))).all()


@pytest.mark.parametrize("tick", [None, [3], "3", 2.5, NAN, INF, True, -1, 150, 10**30], ids=repr)
def test_a_reset_tick_that_is_not_a_whole_number_in_the_cycle_is_named(exports, readings, tick):
    controller = Controller(exports / "mlp")
    with pytest.raises(ValueError, match=r"^tick must be a whole number in \[0, 150\), got "):
        controller.reset(readings, tick=tick)
    controller.reset(readings, tick=np.int64(149))
    controller.reset(readings, tick=75.0)
    assert controller.gait.tick == 75


@pytest.mark.parametrize("command", ["fast", [0.1], NAN, -INF, True, 10**400, b"0.1"], ids=_short)
def test_a_command_that_is_not_a_finite_number_is_named(exports, readings, command):
    controller = Controller(exports / "adaptive")
    controller.reset(readings)
    with pytest.raises(ValueError, match=r"^controller\.command must be a finite number \(m/s\)"):
        controller.command = command
    assert controller.command is None
    controller.command = np.float32(0.15)
    assert controller.command == float(np.float32(0.15))
    assert np.isfinite(controller.step(readings)).all()


@pytest.mark.parametrize("threads", [0, -1, "2", 2.0, None, 10**6], ids=repr)
def test_threads_must_be_a_whole_number(exports, threads):
    with pytest.raises(ValueError, match=r"^threads must be a whole number in \[1, 256\]"):
        Controller(exports / "mlp", threads=threads)


def _leaves(value, keys: tuple = ()):
    """Every number of a JSON value, as (keys, number); of long tables, two rows."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _leaves(item, (*keys, key))
    elif isinstance(value, list):
        rows = range(len(value)) if len(value) <= 8 else (0, len(value) - 1)
        for i in rows:
            yield from _leaves(value[i], (*keys, i))
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield keys, value


#: What a hostile file puts in place of one number.
HOSTILE = [NAN, INF, -INF, 0, -1, 1e308, 5e-324, 10**30, "1", None, True, [1.0]]


@pytest.mark.parametrize("actor", ["mlp", "adaptive"])
def test_no_corrupted_number_of_the_deploy_section_reaches_a_servo(
    exports, tmp_path, readings, actor
):
    """Each number of the deploy section in turn set to each hostile value: the folder is
    refused in one line, or it loads and every target, even at the extreme actions, is
    finite."""
    folder = _copy(exports, tmp_path, actor)
    gait = ("deploy", "gait")
    if actor == "mlp":  # a 10-tick cycle: a smaller file, read hundreds of times
        _edit(folder, lambda layout: _get(layout, gait).update(
            {key: table[:10] for key, table in _get(layout, gait).items()}))  # fmt: skip
    layout = json.loads((folder / "policy.json").read_text())
    loaded = 0
    for keys, good in _leaves(layout["deploy"], ("deploy",)):
        for value in HOSTILE:
            _edit(folder, _set(keys, value))
            try:
                controller = Controller(folder)
            except ValueError as error:
                assert "\n" not in str(error) and "policy.json" in str(error), error
                continue
            loaded += 1
            controller.command = 0.1
            targets = [controller.reset(readings), controller.step(readings)]
            for sign in (-1.0, 0.0, 1.0):  # every action the clip lets through: corners
                targets.append(controller.gait.joints(np.full(controller.gait.action_dim, sign)))
            assert all(np.isfinite(t).all() for t in targets), (keys, value)
        _edit(folder, _set(keys, good))
    assert loaded > 0  # (some values are fine: 0 or -1 where in range)


@pytest.mark.parametrize("actor", ["mlp", "gru", "adaptive"])
def test_huge_tiny_and_non_finite_readings_give_finite_targets(exports, readings, actor):
    controller = Controller(exports / actor)
    controller.command = 0.1
    controller.reset(readings)
    rng = np.random.default_rng(0)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")  # the held periods' warnings
        for _ in range(20):
            wild = readings * 10.0 ** rng.integers(-320, 308, 65)
            wild[rng.random(65) < 0.05] = rng.choice([NAN, INF, -INF])
            targets = controller.step(wild)
            assert targets.shape == (5, 12) and np.isfinite(targets).all()
