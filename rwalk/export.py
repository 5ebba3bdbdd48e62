"""Trained policies as files that run without rwalk: TorchScript and ONNX.

``export_policy(runner, folder)`` writes three files, each atomically:

- ``policy.pt``: TorchScript (``torch.jit.load``),
- ``policy.onnx``: ONNX, one self-contained file (no ``.onnx.data`` sibling),
  input ``obs`` of shape (batch, D) with a dynamic batch axis, output
  ``actions`` of shape (batch, 12),
- ``policy.json``: the input's layout, also stored in the ONNX file's
  ``metadata_props`` (keys ``input_pieces`` and ``rwalk_layout``).

Both models include the observation normaliser, as rsl-rl's own exports do:
they take raw observations. The input is the policy group of ``RslRlVecEnv``,
the pieces of ``--policy-obs`` concatenated in order; by default (D = 68):

| slice | piece | content |
| --- | --- | --- |
| 0:65 | ``observation`` | the spec's 65-D observation |
| 65:67 | ``phase`` | sin(2πφ), cos(2πφ) of the gait phase φ |
| 67:68 | ``lateral_offset`` | y − y0: torso y minus its value at the episode's start (m) |

The output is the action in [-1, 1] units (the env clips), foot offsets FL, FR,
RL, RR (x, y, z). ``policy_input(obs, info)`` builds one input row from the
Gymnasium env's observation and ``info`` (keys ``phase`` and
``lateral_offset``).

A recurrent policy (``--actor gru`` / ``lstm``) carries its state in the ONNX
graph's inputs and outputs: ``(obs, h_in[, c_in])`` -> ``(actions, h_out[,
c_out])``, each state of shape (layers, batch, hidden); feed zeros at an
episode's start and each step the outputs of the step before. ``policy.json``'s
``"recurrent"`` says which and how large. The TorchScript file of a recurrent
policy keeps its state itself for one env (``reset()`` at an episode's start).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import logging
import math
import os
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from rwalk.constants import ACTION_DIM, OBS_DIM
from rwalk.observations import piece_catalog
from rwalk.tasks.residual_walk import ResidualWalk

#: The Gymnasium ``info`` key each scalar piece is read from.
INFO_KEYS = {"phase": "phase", "lateral_offset": "lateral_offset", "command": "target_velocity"}
#: The policy group of ``RslRlVecEnv`` and ``rwalk-train`` by default.
DEFAULT_PIECES = ("observation", "phase", "lateral_offset")
#: ONNX opset of the export (rsl-rl's choice).
OPSET = 18


def input_layout(
    pieces: Sequence[str], catalog: Mapping[str, tuple[int, str]] | None = None
) -> list[dict[str, Any]]:
    """Slices of the input: name, start, size and content of each piece, in order.

    Args:
        catalog: size and content of each piece a task offers (``task_catalog``);
            None: the residual task's.
    """
    if catalog is None:
        catalog = task_catalog(ResidualWalk)
    unknown = [name for name in pieces if name not in catalog]
    if unknown or not pieces:
        raise ValueError(
            f"unknown observation pieces {unknown or pieces!r}; use pieces of {tuple(catalog)}"
        )
    layout, start = [], 0
    for name in pieces:
        size, content = catalog[name]
        layout.append({"name": name, "start": start, "size": size, "content": content})
        start += size
    return layout


def task_catalog(task) -> dict[str, tuple[int, str]]:
    """Size and content of every piece a task (class or instance) offers."""
    return piece_catalog(task.pieces(), task.observation)


def policy_input(
    obs: np.ndarray,
    info: Mapping[str, Any],
    pieces: Sequence[str] = DEFAULT_PIECES,
    last_action: np.ndarray | None = None,
) -> np.ndarray:
    """One input row of an exported policy, from the Gymnasium env's ``obs`` and ``info``.

    Args:
        obs: the Gymnasium env's observation: (65,) for ``ResidualWalkEnv``, (69,)
            for ``AdaptiveGaitEnv``.
        info: the ``info`` of the same ``reset``/``step`` (keys ``phase`` in [0, 1),
            ``lateral_offset`` in m, ``target_velocity`` in m/s and ``start_position``
            (x0, y0) in m, where ``pieces`` need them).
        pieces: the export's layout (``policy.json``'s ``pieces`` names).
        last_action: the action sent at the step before (zeros after ``reset``), where
            ``pieces`` hold ``last_action``: (12,), or (16,) with the adaptive task's obs;
            clipped to [-1, 1] as the env clips it.

    Returns:
        Shape: (D,) float32 (68 for the default pieces); stack rows for a batch.

    Raises:
        ValueError: for ``cycle_speed``, a window over past steps that ``rwalk.deploy``
            keeps and one ``obs`` does not.
    """
    obs = np.asarray(obs, dtype=np.float32)
    if obs.shape not in ((OBS_DIM,), (OBS_DIM + 4,)):
        raise ValueError(f"obs must have shape ({OBS_DIM},) or ({OBS_DIM + 4},), got {obs.shape}")
    parts = []
    for piece in input_layout(pieces):
        name = piece["name"]
        if name == "observation":
            parts.append(obs)
            continue
        if name == "observation_from_start":
            if "start_position" not in info:
                raise KeyError(
                    f"info has no 'start_position' (keys: {sorted(info)}); the policy reads it"
                )
            local = obs.astype(np.float64)
            local[0:2] -= np.asarray(info["start_position"], dtype=np.float64)
            parts.append(local.astype(np.float32))
            continue
        if name == "last_action":
            parts.append(_last_action(last_action, ACTION_DIM + obs.shape[0] - OBS_DIM))
            continue
        if name == "cycle_speed":
            raise ValueError("the piece 'cycle_speed' averages the speed over the last gait "
                             "cycle, which one obs does not hold: run the export with "
                             "rwalk.deploy.Controller, which keeps that window")  # fmt: skip
        key = INFO_KEYS[name]
        if key not in info:
            raise KeyError(f"info has no {key!r} (keys: {sorted(info)}); the policy reads it")
        value = float(info[key])
        if name == "phase":
            angle = 2.0 * math.pi * value
            parts.append(np.array([math.sin(angle), math.cos(angle)], dtype=np.float32))
        else:
            parts.append(np.array([value], dtype=np.float32))
    return np.concatenate(parts)


def _last_action(action: np.ndarray | None, width: int) -> np.ndarray:
    """The piece ``last_action`` of ``policy_input``: ``action`` checked, then clipped."""
    if action is None:
        raise ValueError("the policy reads its last action: pass last_action= (zeros after reset)")
    row = np.asarray(action, dtype=np.float64)
    if row.shape != (width,) or not np.isfinite(row).all():
        raise ValueError(f"last_action must be {width} finite numbers, got shape {row.shape}: "
                         f"{row.ravel()[:width].tolist()!r}")  # fmt: skip
    return np.clip(row, -1.0, 1.0).astype(np.float32)


class _GruOnnx(torch.nn.Module):
    """rsl-rl's ONNX model of a GRU policy with its state as a plain input and output:
    ``(obs, h_in)`` -> ``(actions, h_out)``. Shapes: obs (B, D), h (layers, B, hidden)."""

    kind, states = "gru", ("h",)

    def __init__(self, model: torch.nn.Module) -> None:
        super().__init__()
        self.model = model
        self.layers, self.hidden = model.num_layers, model.hidden_size

    def forward(self, obs: torch.Tensor, h_in: torch.Tensor):
        actions, h, _ = self.model(obs, h_in)
        return actions, h


class _LstmOnnx(_GruOnnx):
    """As ``_GruOnnx`` for an LSTM: ``(obs, h_in, c_in)`` -> ``(actions, h_out, c_out)``."""

    kind, states = "lstm", ("h", "c")

    def forward(self, obs: torch.Tensor, h_in: torch.Tensor, c_in: torch.Tensor):
        return self.model(obs, h_in, c_in)


def _policy_and_pieces(runner_or_policy, pieces: Sequence[str] | None):
    """The rsl-rl model, its env (the runner's or the evaluation policy's adapter; None for a
    bare model) and the pieces of its input (from that env if there is one)."""
    alg = getattr(runner_or_policy, "alg", None)
    policy = alg.get_policy() if alg is not None else runner_or_policy
    env = getattr(runner_or_policy, "env", None)
    if hasattr(runner_or_policy, "adapter"):  # an rwalk.evaluation.Policy of a checkpoint
        policy, env = runner_or_policy.model, runner_or_policy.adapter
    if not hasattr(policy, "as_jit") or not hasattr(policy, "obs_dim"):
        raise TypeError(
            f"export_policy takes an rsl-rl runner or its MLPModel / RNNModel, "
            f"got {type(runner_or_policy).__name__}"
        )
    catalog = task_catalog(env.core.task) if hasattr(env, "core") else None
    if pieces is None:
        groups = getattr(env, "groups", None)
        if groups is None:
            pieces = DEFAULT_PIECES
        else:
            pieces = tuple(name for group in policy.obs_groups for name in groups[group])
    layout = input_layout(pieces, catalog)
    size = sum(piece["size"] for piece in layout)
    if size != policy.obs_dim:
        raise ValueError(
            f"pieces {tuple(pieces)} have {size} values; the policy reads {policy.obs_dim}"
        )
    return policy, env, layout


def deploy_spec(core) -> dict[str, Any] | None:
    """What ``rwalk.deploy`` needs beside the ONNX graph to run a policy of ``core``'s
    task: the task's own part (``Task.deploy_spec``: its runtime, the gait's tables or
    constants, exact: JSON writes each float's shortest round-trip form), the timing,
    the residual scale, the legs and the cycle-speed window. None for a task without a
    deploy runtime."""
    own = core.task.deploy_spec(core)
    if own is None:
        return None
    return {
        "task": core.task.name,
        "substeps": core.decimation,
        "dt": core.world.dt,
        "sensors": "rwalk.deploy.SENSOR_LAYOUT: MuJoCo sensordata, 65 values",
        "cycle_steps": core.episodes.recent.shape[1],
        "leg_geometry": dataclasses.asdict(core.geometry),
        "residual_scale": core.config.residual_scale,
        **own,
    }


def export_policy(
    runner_or_policy, folder: str | os.PathLike[str], pieces: Sequence[str] | None = None
) -> tuple[Path, Path]:
    """Write ``policy.pt``, ``policy.onnx`` and ``policy.json`` into ``folder``.

    Args:
        runner_or_policy: an rsl-rl ``OnPolicyRunner`` (the layout comes from its
            ``RslRlVecEnv``), a checkpoint's ``rwalk.evaluation.Policy`` (from its
            adapter), or a bare policy model (``MLPModel``: no ``deploy`` section).
        folder: created if missing; nothing is written outside it.
        pieces: the input's pieces; None = the runner env's policy group, or
            ``DEFAULT_PIECES`` for a bare model.

    Returns:
        (TorchScript path, ONNX path).
    """
    from rwalk.rl.checkpoints import atomic_write, atomic_write_text

    policy, env, layout = _policy_and_pieces(runner_or_policy, pieces)
    folder = Path(folder)
    size = policy.obs_dim
    task = env.core.task if hasattr(env, "core") else None
    actions = task.action_dim if task is not None else ACTION_DIM
    layout_text = (
        task.action_layout if task is not None else "foot offsets FL, FR, RL, RR (x, y, z)"
    )
    description = {
        "input": {"name": "obs", "shape": ["batch", size], "dtype": "float32", "pieces": layout},
        "output": {
            "name": "actions",
            "shape": ["batch", actions],
            "content": f"{layout_text} in [-1, 1] units (the env clips)",
        },
        "observation_normalizer": "included: feed raw observations",
        "files": {"torchscript": "policy.pt", "onnx": "policy.onnx"},
    }
    deploy = deploy_spec(env.core) if task is not None else None
    if deploy is not None:  # a task without a deploy runtime exports without the section
        description["deploy"] = deploy

    scripted = torch.jit.script(policy.as_jit().to("cpu").eval())
    jit_path = atomic_write(folder / "policy.pt", lambda file: torch.jit.save(scripted, file))

    model = policy.as_onnx(verbose=False).to("cpu").eval()
    inputs, outputs, example, shapes = ["obs"], ["actions"], (torch.zeros(2, size),), [{0: ...}]
    if getattr(policy, "is_recurrent", False):
        model = (_LstmOnnx if model.rnn_type == "lstm" else _GruOnnx)(model).eval()
        state = (model.layers, 2, model.hidden)
        inputs += [f"{name}_in" for name in model.states]
        outputs += [f"{name}_out" for name in model.states]
        example += tuple(torch.zeros(state) for _ in model.states)
        shapes += [{1: ...} for _ in model.states]
        description["recurrent"] = {
            "kind": model.kind,
            "inputs": inputs[1:],
            "outputs": outputs[1:],
            "shape": ["layers", "batch", "hidden"],
            "layers": model.layers,
            "hidden": model.hidden,
            "content": "the recurrent layer's state: feed zeros at an episode's start, then "
            "each step the outputs of the step before",
        }
        description["files"]["torchscript"] = (
            "policy.pt (one env: it keeps the state itself; call reset() at an episode's start)"
        )
    batch = torch.export.Dim("batch", min=1)
    shapes = tuple({axis: batch for axis in shape} for shape in shapes)
    quiet = logging.getLogger("torch.onnx")
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # "torchvision is not installed" notes
    try:
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)  # torch.export's own deprecations
            program = torch.onnx.export(
                model,
                example,
                dynamo=True,
                external_data=False,
                opset_version=OPSET,
                input_names=inputs,
                output_names=outputs,
                dynamic_shapes=shapes,
                verbose=False,
            )
    finally:
        quiet.setLevel(level)
    proto = program.model_proto
    metadata = {
        "input_pieces": ",".join(f"{p['name']}:{p['size']}" for p in layout),
        "rwalk_layout": json.dumps(description),
    }
    for key, value in metadata.items():
        proto.metadata_props.add(key=key, value=value)
    onnx_path = atomic_write(
        folder / "policy.onnx", lambda file: file.write(proto.SerializeToString())
    )
    atomic_write_text(folder / "policy.json", json.dumps(description, indent=2) + "\n")
    return jit_path, onnx_path
