"""The arm model against the simulators' truth files (``recording_set``: the project's
stand-ins, and the independent simulator's shared/data/recordings where present): the
truth angles through forward kinematics reproduce the truth positions, and through
orientations and back reproduce the truth angles."""

import numpy as np
import pytest
from armtrack.estimator.arm import (
    ANGLE_NAMES,
    POINTS,
    REPORTED_ANGLES,
    forward_kinematics,
    joint_angles,
)
from armtrack.estimator.arm.joints import ELEVATION
from armtrack.estimator.body import SegmentLengths

NAMES = ["abduction_120", "elbow_6axis", "elbow_6axis_long", "elbow_flexion", "left_reach_50hz",
         "pronation", "shoulder_abduction", "shoulder_flexion", "trunk_reach", "wrist_flexion"]
#: The truth files print 5 decimals (the stand-ins 6): positions to 5e-6 m, angles to
#: 5e-6° (≈ 1e-7 m of position at arm's length), so positions agree to 1e-5 m.
POSITION_TOLERANCE_M = 1e-5
#: ``shoulder_elevation`` is printed rounded from the unrounded angles, and near 0° it is
#: about the root-sum-square of flexion and abduction: from the printed (rounded, ±5e-6°)
#: ones it comes back within √2·5e-6 + 5e-6 ≈ 1.2e-5° (a stand-in at 10.31 s: flexion and
#: abduction 1e-6°, elevation printed 1e-6°, recomputed 1.4e-6°).
ELEVATION_TOLERANCE_DEG = 1.5e-5


def read_truth(recording_set, name):
    recording = recording_set.path(name).read_text()[:1000]
    header = dict(line[2:].split(": ", 1) for line in recording.splitlines()
                  if line.startswith("# "))
    return header["side"], float(header["height_m"]), recording_set.truth(name)


@pytest.mark.parametrize("name", NAMES)
def test_truth_angles_give_truth_positions_and_back(recording_set, name):
    side, height, truth = read_truth(recording_set, name)
    angles = {k: np.deg2rad(truth[k]) for k in ANGLE_NAMES}
    pose = forward_kinematics(angles, side, SegmentLengths.from_height(height))
    worst_p = max(
        np.abs(pose.p_thorax[p] - np.stack([truth[f"{p}_{a}"] for a in "xyz"], -1)).max()
        for p in POINTS)
    result = joint_angles(pose.R_thorax, side)
    off = {k: np.abs(np.rad2deg(result.angles[k]) - truth[k]).max() for k in REPORTED_ANGLES}
    worst_a = max(v for k, v in off.items() if k != ELEVATION)
    print(f"{recording_set.source} {name} ({side}, {height} m, {len(truth)} samples): "
          f"positions within {worst_p * 1e3:.4f} mm, angles back within {worst_a:.1e} deg, "
          f"elevation within {off[ELEVATION]:.1e} deg")
    assert worst_p < POSITION_TOLERANCE_M
    assert worst_a < 1e-9
    assert off[ELEVATION] < ELEVATION_TOLERANCE_DEG
