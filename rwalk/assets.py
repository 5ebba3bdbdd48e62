"""Finding, loading and checking the MJCF model."""

from __future__ import annotations

import os
from pathlib import Path

import mujoco

from rwalk.constants import (
    FOOT_GEOMS,
    FOOT_SITES,
    GROUND_GEOM,
    JOINT_NAMES,
    MODEL_DIR,
    OBSERVATION_SENSORS,
    TORSO_BODY,
    TORSO_SITE,
)


def resolve_model_path(path: str | os.PathLike[str]) -> Path:
    """Find a model file: as given (absolute or from the working directory), else,
    for the exact names of the packaged models (``"model/world_train.xml"`` or
    ``"world_train.xml"``), the copy packaged with rwalk, so that those work from
    any directory and in a non-editable install. Any other path that does not
    exist is an error: a mistyped folder never falls back to a packaged file.

    Raises:
        FileNotFoundError: naming the path and where it was looked for.
    """
    given = Path(path).expanduser()
    if given.is_file():
        return given.resolve()
    tried = [str(given)]
    parts = given.parts
    if parts in ((given.name,), ("model", given.name)):
        packaged = MODEL_DIR / given.name
        if packaged.is_file():
            return packaged.resolve()
        tried.append(str(packaged))
    raise FileNotFoundError(f"model file {str(path)!r} not found (looked at: {', '.join(tried)})")


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
    if GROUND_GEOM not in required["geom"][1]:
        missing.append(f"geom {GROUND_GEOM!r} (the ground: a plane or a heightfield)")
    if missing:
        raise ValueError(f"{source} lacks required elements: {', '.join(missing)}")
    ground = int(model.geom(GROUND_GEOM).type[0])
    if ground not in (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD):
        raise ValueError(
            f"{source}: geom {GROUND_GEOM!r} must be a plane or a heightfield, got "
            f"{mujoco.mjtGeom(ground).name}"
        )
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
