"""Quality of a session's estimates: what the joints' residuals say about the sensors.

The elbow and the wrist have two degrees of freedom; the part of the measured relative
rotation they cannot express (``elbow_carrying`` about the upper arm's X axis,
``wrist_twist`` about the hand's long axis) stays near zero when the sensors sit where
the session says. A large one means a sensor on the wrong segment (forearm and hand
swapped, say — gravity alone cannot tell them apart in the N- and T-pose, since both turn
with the arm) or a sensor that slipped.
"""

from __future__ import annotations

import numpy as np

from ..calibration import CalibrationWarning
from .estimates import Estimates

#: RMS of a residual [deg] above which the joint does not fit its sensors.
RESIDUAL_RMS_DEG = 10.0

_JOINTS = {"elbow_carrying": "elbow", "wrist_twist": "wrist"}


def residual_warnings(estimates: Estimates, sensors: tuple[str, ...]) -> list[CalibrationWarning]:
    """Warnings for joints whose residual RMS exceeds ``RESIDUAL_RMS_DEG``; only joints
    with a sensor on both of their segments are judged."""
    present = set(sensors)
    needed = {"elbow_carrying": {"upper_arm", "forearm"}, "wrist_twist": {"forearm", "hand"}}
    warnings = []
    for name, joint in _JOINTS.items():
        if not needed[name] <= present or len(estimates) == 0:
            continue
        rms = float(np.rad2deg(np.sqrt(np.mean(np.square(estimates.residuals[name])))))
        if rms > RESIDUAL_RMS_DEG:
            warnings.append(CalibrationWarning(
                "joint-residual", None,
                f"the {joint} turned {rms:.0f}° rms in a way it cannot: is an arm sensor on "
                f"the wrong segment (upper arm, forearm, hand swapped), or has one slipped?"))
    return warnings
