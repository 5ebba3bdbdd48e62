"""The fixed base gait walks (issue: proof the base gait walks)."""

import numpy as np

from rwalk.analysis import walk
from rwalk.core import ResidualWalkCore
from rwalk.presets import base_gait_config


def test_base_gait_walks_straight_on_flat_ground():
    core = ResidualWalkCore(base_gait_config("model/world_flat.xml"), 64, seed=0)
    report = walk(core, steps=1000)  # 20 s at 50 Hz
    summary = report.summary()
    yaw0_spread = np.ptp(report.heading_change)  # starts differ in yaw by up to 0.2 rad
    assert report.seconds == 20.0
    assert summary["fall_rate"] == 0.0
    assert abs(summary["speed_ratio"] - 1.0) < 0.25
    assert summary["max_abs_heading_change"] < 0.1
    assert summary["max_abs_sideways_drift"] < 0.1
    assert yaw0_spread < 1e-6  # elliptic friction cones: the gait is heading-independent
