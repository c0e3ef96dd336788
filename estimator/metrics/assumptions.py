"""Warnings when a session's data contradict what its kit assumes
(``estimator/arm/coverage.py``, ``docs/extensions/measured-angles.md``).

With a forearm sensor and no upper-arm sensor the elbow's angles assume the upper arm
hangs still beside the trunk. The elbow has two degrees of freedom: the part of the
forearm's rotation against the assumed upper arm that the elbow cannot make (the
``elbow_carrying`` residual, about the upper arm's X axis) is the forearm raised sideways
— the upper arm abducted, or the phone slipped. Sustained over ``WINDOW_S`` beyond
``CARRYING_DEG`` (calibration poses excluded: the T-pose is the arm raised), it
contradicts the assumption. A *forward* raise of the upper arm turns the forearm about
the same axis as elbow flexion: from the forearm alone it reads as elbow flexion and
cannot be told apart (stated, not checked).

An upright, still trunk (an upper arm or forearm without a trunk sensor) cannot be told
from the arm's own sensor: it is stated, not checked.
"""

from __future__ import annotations

import numpy as np

#: RMS of the elbow's residual over a window [deg] that contradicts a hanging upper arm.
CARRYING_DEG = 20.0
#: Window of that RMS [s].
WINDOW_S = 2.0


def assumption_warnings(t: np.ndarray, residuals: dict[str, np.ndarray],
                        sensors: tuple[str, ...], from_s: float) -> list[str]:
    """Sentences for the assumptions the data contradict, from ``from_s`` [s] on (after
    the calibration poses). ``t`` [s] (N,), ``residuals`` by name [rad] (N,)."""
    worn = set(sensors)
    if not ("forearm" in worn and "upper_arm" not in worn) or len(t) < 2:
        return []
    keep = t >= from_s
    t, carrying = t[keep], np.rad2deg(residuals["elbow_carrying"][keep])
    if len(t) < 2:
        return []
    # windowed mean of the square, by cumulative sums over time
    square = np.concatenate(([0.0], np.cumsum(carrying[1:] ** 2 * np.diff(t))))
    end = np.searchsorted(t, t + WINDOW_S, "right") - 1
    span = t[end] - t
    full = span >= 0.9 * WINDOW_S
    if not full.any():
        return []
    rms = np.sqrt((square[end] - square)[full] / span[full])
    worst = int(np.argmax(rms))
    if rms[worst] <= CARRYING_DEG:
        return []
    starts = t[full][rms > CARRYING_DEG]
    return [f"the forearm phone's elbow angles assume the upper arm hangs still beside the "
            f"trunk, but the forearm was raised sideways by {rms[worst]:.0f}° rms (from "
            f"{starts[0]:.1f} s, {len(starts) / max(1, full.sum()) * 100:.0f} % of the "
            "time after calibration): the upper arm moved, or the phone slipped; those "
            "elbow angles are not reliable"]
