"""Names and paths shared by the model, the controller and the environments."""

from __future__ import annotations

from pathlib import Path

#: Legs in the spec's order: front-left, front-right, rear-left, rear-right.
LEG_NAMES: tuple[str, ...] = ("FL", "FR", "RL", "RR")
#: Joints of one leg, from the torso outwards.
JOINT_KINDS: tuple[str, ...] = ("abduction", "hip", "knee")
#: The 12 joints (and the position servos driving them), leg-major.
JOINT_NAMES: tuple[str, ...] = tuple(f"{leg}_{kind}" for leg in LEG_NAMES for kind in JOINT_KINDS)
#: Per leg: the body that the abduction, hip and knee joints move.
LEG_BODY_KINDS: tuple[str, ...] = ("hip_link", "thigh", "shin")
#: Dedicated foot geoms, the only robot geoms besides the torso that touch the ground.
FOOT_GEOMS: tuple[str, ...] = tuple(f"{leg}_foot" for leg in LEG_NAMES)
#: Sites at the foot centres.
FOOT_SITES: tuple[str, ...] = FOOT_GEOMS
TORSO_BODY = "torso"
TORSO_SITE = "imu"
#: Name of the ground geom in every world (a plane or a heightfield).
GROUND_GEOM = "ground"
#: Name of the flat plane under a heightfield that carries robots leaving the map.
FLOOR_GEOM = "floor"
#: Name of the heightfield asset in rough worlds.
TERRAIN_HFIELD = "terrain"
#: Standing keyframe of the robot.
STAND_KEYFRAME = "stand"

#: Sensors in the order of the spec's 65-D observation, with their widths.
OBSERVATION_SENSORS: tuple[tuple[str, int], ...] = (
    ("torso_pos", 3),
    ("torso_quat", 4),
    ("torso_linvel", 3),
    ("torso_angvel", 3),
    *((f"{joint}_pos", 1) for joint in JOINT_NAMES),
    *((f"{joint}_vel", 1) for joint in JOINT_NAMES),
    *((f"{leg}_foot_pos", 3) for leg in LEG_NAMES),
    *((f"{leg}_foot_vel", 3) for leg in LEG_NAMES),
    *((f"{leg}_contact", 1) for leg in LEG_NAMES),
)
OBS_DIM = sum(width for _, width in OBSERVATION_SENSORS)
ACTION_DIM = 3 * len(LEG_NAMES)

#: Slices of the observation vector (and of sensordata, which has the same layout).
OBS_POS = slice(0, 3)
OBS_QUAT = slice(3, 7)
OBS_LINVEL = slice(7, 10)
OBS_ANGVEL = slice(10, 13)
OBS_JOINT_POS = slice(13, 25)
OBS_JOINT_VEL = slice(25, 37)
OBS_FOOT_POS = slice(37, 49)
OBS_FOOT_VEL = slice(49, 61)
OBS_CONTACT = slice(61, 65)

#: The spec's episode: env steps before truncation, and steps of zero-residual gait that
#: settle each start (``EnvConfig``'s defaults; 20 s and 10 s at 50 Hz).
EPISODE_STEPS = 1000
SETTLE_STEPS = 500

MODEL_DIR = Path(__file__).resolve().parent / "model"
WORLD_TRAIN = "world_train.xml"
WORLD_FLAT = "world_flat.xml"
