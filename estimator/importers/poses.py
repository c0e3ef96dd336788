"""Proposing calibration poses from still periods: the N-pose (arm hanging) and the T-pose
(arm out sideways, 90° from the N-pose), as a ready ``--calibration`` value."""

from __future__ import annotations

import math

import numpy as np

from ..recording import SensorStream

#: Sensors whose gravity direction tells the arm's pose, in order of preference.
ARM_SENSORS = ("upper_arm", "forearm", "hand")
STILL_RATE = 0.15  # rad/s
STILL_ACC = 0.6  # m/s², deviation of |a| from its median
MIN_STILL_S = 1.5
GRID_HZ = 50.0
TRIM_S = 0.25


def still_runs(streams: dict[str, SensorStream]) -> list[tuple[float, float]]:
    """Periods [s] of at least ``MIN_STILL_S`` in which every sensor is still."""
    start = max(float(s.t[0]) for s in streams.values())
    end = min(float(s.t[-1]) for s in streams.values())
    if end - start < MIN_STILL_S:
        return []
    grid = np.arange(start, end, 1.0 / GRID_HZ)
    still = np.ones(len(grid), dtype=bool)
    for s in streams.values():
        rate = np.linalg.norm(s.gyr - np.median(s.gyr, axis=0), axis=1)
        norm = np.linalg.norm(s.acc, axis=1)
        ok = (rate < STILL_RATE) & (np.abs(norm - np.median(norm)) < STILL_ACC)
        still &= np.interp(grid, s.t, ok.astype(float)) > 0.999
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(np.int8), [0]])))
    runs = []
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        t0, t1 = float(grid[a]), float(grid[b - 1])
        if t1 - t0 >= MIN_STILL_S:
            runs.append((t0, t1))
    return runs


def _direction(stream: SensorStream, run: tuple[float, float]) -> np.ndarray:
    inside = (stream.t >= run[0]) & (stream.t <= run[1])
    mean = stream.acc[inside].mean(axis=0)
    return mean / np.linalg.norm(mean)


def propose_calibration(streams: dict[str, SensorStream]) -> str | None:
    """A ``calibration`` value (``npose A B; tpose C D``) from the still periods, or None
    when no arm sensor or no still period fits. The N-pose is the first still period in
    which the arm sensor's +Y points up (default mounting) or, failing that, the first;
    the T-pose the first later still period with the arm turned 60–120° from it."""
    arm = next((s for s in ARM_SENSORS if s in streams), None)
    if arm is None:
        return None
    runs = still_runs(streams)
    if not runs:
        return None
    ref = streams[arm]
    directions = [_direction(ref, r) for r in runs]
    npose = next((i for i, d in enumerate(directions) if d[1] > 0.8), 0)
    tpose = None
    for j in range(npose + 1, len(runs)):
        angle = math.degrees(math.acos(float(np.clip(directions[npose] @ directions[j], -1, 1))))
        if 60.0 <= angle <= 120.0:
            tpose = j
            break
    parts = [_window("npose", runs[npose])]
    if tpose is not None:
        parts.append(_window("tpose", runs[tpose]))
    return "; ".join(parts)


def _window(name: str, run: tuple[float, float]) -> str:
    a = math.ceil((run[0] + TRIM_S) * 10) / 10
    b = math.floor((run[1] - TRIM_S) * 10) / 10
    return f"{name} {a:.1f} {b:.1f}"
