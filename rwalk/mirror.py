"""The robot's left-right mirror, as a signed permutation of a vector's values.

The robot is symmetric about its xz-plane (``model/robot.xml``: hips at ±4 cm,
equal legs and masses; abduction joints turn about x, hip and knee about y). A
state mirrored there is another state of the same robot: y, roll and yaw change
sign, the left and right legs swap (FL <-> FR, RL <-> RR), an abduction angle
changes sign while hip and knee angles stay. Because the trot pairs FL with RR,
the mirrored state walks half a gait cycle further on: FR's phase is FL's plus
one half.

A ``Mirror`` says, for each value of a vector, which value of the original it
takes and with which sign: ``mirrored[i] = signs[i] * x[index[i]]``. Pieces and
actions declare theirs (``ObsPiece.mirror``, ``Task.action_mirror``); a group of
pieces mirrors as their concatenation (``concat``). Applying a mirror twice
gives the original (tests/test_symmetry.py).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import NamedTuple

#: Leg order FL, FR, RL, RR mirrored: each left leg takes its right twin's place.
SWAPPED_LEGS = (1, 0, 3, 2)


class Mirror(NamedTuple):
    """The mirror of a vector: ``mirrored[i] = signs[i] * x[index[i]]``."""

    index: tuple[int, ...]
    signs: tuple[float, ...]

    @property
    def size(self) -> int:
        return len(self.index)


def identity(size: int) -> Mirror:
    """Values the mirror leaves as they are (speeds along x, heights, gait parameters)."""
    return Mirror(tuple(range(size)), (1.0,) * size)


def signed(signs: Sequence[float]) -> Mirror:
    """Values that stay in place, some changing sign."""
    return Mirror(tuple(range(len(signs))), tuple(float(s) for s in signs))


def per_leg(signs: Sequence[float], legs: int = 4) -> Mirror:
    """Leg-major values, ``len(signs)`` per leg: each leg takes its twin's values, each
    value with its sign (foot (x, y, z): (1, -1, 1); joints (abduction, hip, knee):
    (-1, 1, 1); contacts: (1,))."""
    width = len(signs)
    index = tuple(SWAPPED_LEGS[leg] * width + k for leg in range(legs) for k in range(width))
    return Mirror(index, tuple(float(s) for _ in range(legs) for s in signs))


def per_leg_with_samples(samples: Sequence[int], legs: int = 4) -> Mirror:
    """Leg-major values, one per sample point around each foot: the legs swap, and sample
    k takes sample ``samples[k]`` (the point it mirrors onto)."""
    width = len(samples)
    index = tuple(SWAPPED_LEGS[leg] * width + samples[k] for leg in range(legs)
                  for k in range(width))  # fmt: skip
    return Mirror(index, (1.0,) * (legs * width))


def concat(mirrors: Iterable[Mirror]) -> Mirror:
    """The mirror of vectors laid end to end."""
    index: list[int] = []
    signs: list[float] = []
    offset = 0
    for mirror in mirrors:
        index += [offset + i for i in mirror.index]
        signs += mirror.signs
        offset += mirror.size
    return Mirror(tuple(index), tuple(signs))


#: The spec's 65 sensor values (docs/environment.md's layout): torso position (x, -y,
#: z), quaternion (w, -x, y, -z), linear velocity (x, -y, z), angular velocity (-x, y,
#: -z: a pseudovector), joint angles and speeds (abduction -, hip +, knee +), feet
#: positions and velocities in the torso frame (x, -y, z), contacts.
SENSORS = concat([
    signed((1, -1, 1)), signed((1, -1, 1, -1)), signed((1, -1, 1)), signed((-1, 1, -1)),
    per_leg((-1, 1, 1)), per_leg((-1, 1, 1)), per_leg((1, -1, 1)), per_leg((1, -1, 1)),
    per_leg((1,)),
])  # fmt: skip
#: Foot residuals (x, y, z) per leg, in each hip's frame.
RESIDUALS = per_leg((1, -1, 1))
#: sin, cos of 2π x the gait phase: the mirrored state is half a cycle on.
PHASE = signed((-1, -1))
