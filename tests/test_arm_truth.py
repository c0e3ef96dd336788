"""The arm model against the independent simulator's truth files (shared/data/recordings):
the truth angles through forward kinematics reproduce the truth positions, and through
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
from armtrack.estimator.body import SegmentLengths

NAMES = ["abduction_120", "elbow_6axis", "elbow_6axis_long", "elbow_flexion", "left_reach_50hz",
         "pronation", "shoulder_abduction", "shoulder_flexion", "trunk_reach", "wrist_flexion"]
#: The truth files print 5 decimals: positions to 5e-6 m, angles to 5e-6° (≈ 1e-7 m of
#: position at arm's length), so positions agree to 1e-5 m.
POSITION_TOLERANCE_M = 1e-5


def read_truth(shared_dir, name):
    recording = (shared_dir / "data" / "recordings" / f"{name}.csv").read_text()[:1000]
    header = dict(line[2:].split(": ", 1) for line in recording.splitlines()
                  if line.startswith("# "))
    table = np.genfromtxt(shared_dir / "data" / "recordings" / f"{name}.truth.csv",
                          delimiter=",", names=True)
    return header["side"], float(header["height_m"]), table


@pytest.mark.parametrize("name", NAMES)
def test_truth_angles_give_truth_positions_and_back(shared_dir, name):
    side, height, truth = read_truth(shared_dir, name)
    angles = {k: np.deg2rad(truth[k]) for k in ANGLE_NAMES}
    pose = forward_kinematics(angles, side, SegmentLengths.from_height(height))
    worst_p = max(
        np.abs(pose.p_thorax[p] - np.stack([truth[f"{p}_{a}"] for a in "xyz"], -1)).max()
        for p in POINTS)
    result = joint_angles(pose.R_thorax, side)
    worst_a = max(np.abs(np.rad2deg(result.angles[k]) - truth[k]).max() for k in REPORTED_ANGLES)
    print(f"{name} ({side}, {height} m, {len(truth)} samples): positions within "
          f"{worst_p * 1e3:.4f} mm, angles back within {worst_a:.1e} deg")
    assert worst_p < POSITION_TOLERANCE_M
    assert worst_a < 1e-9
