"""Finding, loading and checking the MJCF model."""

from __future__ import annotations

import os
from pathlib import Path

import mujoco

from rwalk.constants import (
    FOOT_GEOMS,
    FOOT_SITES,
    JOINT_NAMES,
    MODEL_DIR,
    OBSERVATION_SENSORS,
    TORSO_BODY,
    TORSO_SITE,
)


def resolve_model_path(path: str | os.PathLike[str]) -> Path:
    """Find a model file: as given (absolute or from the working directory), else
    among the models packaged with rwalk (so ``"model/world_train.xml"`` works
    from any directory and in a non-editable install).

    Raises:
        FileNotFoundError: naming the path and where it was looked for.
    """
    given = Path(path).expanduser()
    if given.is_file():
        return given.resolve()
    candidates = [given]
    if not given.is_absolute():
        parts = given.parts
        packaged = MODEL_DIR.joinpath(*parts[1:]) if parts and parts[0] == "model" else None
        for candidate in (packaged, MODEL_DIR / given.name):
            if candidate is not None and candidate.is_file():
                return candidate.resolve()
            if candidate is not None:
                candidates.append(candidate)
    tried = ", ".join(str(c) for c in dict.fromkeys(candidates))
    raise FileNotFoundError(f"model file {str(path)!r} not found (looked at: {tried})")


def validate_model(model: mujoco.MjModel, source: str = "model") -> None:
    """Check that a model has every joint, actuator, site, geom and sensor rwalk uses.

    Raises:
        ValueError: listing everything that is missing.
    """

    def names(kind: mujoco.mjtObj, count: int) -> set[str]:
        return {mujoco.mj_id2name(model, kind, i) for i in range(count)} - {None}

    required = {
        "body": ({TORSO_BODY}, names(mujoco.mjtObj.mjOBJ_BODY, model.nbody)),
        "joint": (set(JOINT_NAMES), names(mujoco.mjtObj.mjOBJ_JOINT, model.njnt)),
        "actuator": (set(JOINT_NAMES), names(mujoco.mjtObj.mjOBJ_ACTUATOR, model.nu)),
        "site": ({TORSO_SITE, *FOOT_SITES}, names(mujoco.mjtObj.mjOBJ_SITE, model.nsite)),
        "geom": (set(FOOT_GEOMS), names(mujoco.mjtObj.mjOBJ_GEOM, model.ngeom)),
        "sensor": (
            {name for name, _ in OBSERVATION_SENSORS},
            names(mujoco.mjtObj.mjOBJ_SENSOR, model.nsensor),
        ),
    }
    missing = [
        f"{kind} {name!r}"
        for kind, (wanted, present) in required.items()
        for name in sorted(wanted - present)
    ]
    if missing:
        raise ValueError(f"{source} lacks required elements: {', '.join(missing)}")
    # The observation is sensordata itself, so the sensors must come first, in order.
    offset = 0
    for name, width in OBSERVATION_SENSORS:
        sensor = model.sensor(name)
        if int(sensor.adr[0]) != offset or int(sensor.dim[0]) != width:
            raise ValueError(
                f"{source}: sensor {name!r} must have width {width} at offset {offset} of "
                f"sensordata (has {int(sensor.dim[0])} at {int(sensor.adr[0])})"
            )
        offset += width
    actuators = [model.actuator(i).name for i in range(model.nu)]
    if actuators != list(JOINT_NAMES):
        raise ValueError(
            f"{source}: actuators must be {list(JOINT_NAMES)} in that order, got {actuators}"
        )


def load_model(path: str | os.PathLike[str]) -> mujoco.MjModel:
    """Resolve, compile and validate a model file."""
    resolved = resolve_model_path(path)
    model = mujoco.MjModel.from_xml_path(str(resolved))
    validate_model(model, source=str(resolved))
    return model
