"""The γ elbow in the pipeline: an upper-arm IMU plus wrist positions from a robot or a
camera (``docs/extensions/points.md``; the solver is :mod:`..arm.gamma`).

At each estimate time the wrist ``W`` (interpolated from its points) and the shoulder
``S`` give, with the upper arm's tilt from its IMU, the upper arm's heading (the closed
form γ, both roots, the physiological rule) and the elbow flexion. The upper arm's
orientation is replaced by the corrected one — so its heading no longer drifts with the
gyroscope — and, without a forearm IMU, the forearm's is built from it and the flexion
(pronation unmeasured: 0). With a forearm IMU the IMUs make the elbow (they measure
pronation too) and the points' flexion is a quality figure: their disagreement.

Where γ is ill-determined — the wrist nearly straight below or above the shoulder, or the
arm's plane nearly horizontal (``m = √(a² + b²) < MIN_CONDITION``), out of reach, or no
point within ``MAX_GAP_S`` — the sample is *flagged*: the last good heading correction is
held (the gyroscope carries the heading meanwhile) and, without a point, the last flexion.
Flagged samples are counted and kept out of accuracy figures.

Frames: world z up (the pipeline's); points are converted to the thorax frame when fed,
then to the world with the thorax's orientation at each estimate. Units: s, m, rad.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..arm.gamma import gamma_coefficients, solve_gamma
from ..body import SegmentLengths, Side
from ..recording.points import PointsFrame
from ..rotations import elemental

#: Points further apart than this [s] leave a hole: no wrist there (a camera's dropout).
MAX_GAP_S = 0.25
#: Below this ``m`` (unitless, of unit vectors: the sine of the wrist line's and of the arm
#: plane's tilt from vertical, multiplied) γ is too ill-conditioned to use: an error of
#: ε rad in the wrist's direction moves γ by about ε / m.
MIN_CONDITION = 0.2
#: Live streams: estimates wait for the wrist points at most this long [s] behind the IMUs.
MAX_POINTS_LAG_S = 1.0


def model_shoulder(side: Side, lengths: SegmentLengths) -> np.ndarray:
    """The arm model's shoulder centre in the thorax frame [m] (clavicle at rest)."""
    return np.array([0.0, 0.0, lengths.clavicle if side == "right" else -lengths.clavicle])


class WristTrack:
    """Wrist points fed in time order, kept in the thorax frame [m]; ``at(times)`` gives
    the wrist at estimate times by linear interpolation (NaN where there is a hole)."""

    def __init__(self, frame: PointsFrame, side: Side, lengths: SegmentLengths):
        model = model_shoulder(side, lengths)
        self.shoulder_thorax = frame.shoulder_in_thorax(model)
        self._R, self._o = frame.to_thorax(model)
        self._t = np.empty(0)
        self._p = np.empty((0, 3))
        self.first_t = np.inf
        self.last_t = -np.inf

    def append(self, t, p) -> None:
        """Points at times ``t`` [s] (N,), positions ``p`` [m] (N, 3) in the points frame."""
        t = np.asarray(t, dtype=float).reshape(-1)
        p = np.asarray(p, dtype=float).reshape(-1, 3)
        if not len(t):
            return
        self._t = np.concatenate([self._t, t])
        self._p = np.concatenate([self._p, (p - self._o) @ self._R.T])
        self.first_t = min(self.first_t, float(t[0]))
        self.last_t = float(t[-1])

    def at(self, times: np.ndarray) -> np.ndarray:
        """The wrist [m] (N, 3) in the thorax frame at ``times`` (N,); NaN where the points
        around a time are more than ``MAX_GAP_S`` apart or missing."""
        out = np.full((len(times), 3), np.nan)
        n = len(self._t)
        if not n:
            return out
        after = np.searchsorted(self._t, times, "left")  # first point at or after
        exact = (after < n) & (self._t[np.minimum(after, n - 1)] == times)
        inner = (after > 0) & (after < n) & ~exact
        i1 = np.minimum(after, n - 1)
        i0 = np.maximum(after - 1, 0)
        t0, t1 = self._t[i0], self._t[i1]
        ok = inner & (t1 - t0 <= MAX_GAP_S)
        w = np.divide(times - t0, t1 - t0, out=np.zeros(len(times)), where=ok & (t1 > t0))
        interp = self._p[i0] + w[:, None] * (self._p[i1] - self._p[i0])
        out[ok] = interp[ok]
        out[exact] = self._p[i1[exact]]
        return out

    def discard_before(self, t: float) -> None:
        """Forget points no later estimate needs (all but the last one before ``t``)."""
        keep = max(int(np.searchsorted(self._t, t, "left")) - 1, 0)
        if keep:
            self._t, self._p = self._t[keep:], self._p[keep:]


@dataclass
class GammaStats:
    """What the points did over a session: samples seen, flagged (γ held), without a
    point, and the squared flexion disagreement with a forearm IMU [rad²] summed."""

    samples: int = 0
    flagged: int = 0
    no_point: int = 0
    disagreement_sq: float = 0.0
    compared: int = 0

    @property
    def flagged_share(self) -> float:
        return self.flagged / self.samples if self.samples else 0.0

    @property
    def disagreement_rms_deg(self) -> float | None:
        """RMS of points' minus IMUs' elbow flexion [deg] where both exist, or None."""
        if not self.compared:
            return None
        return float(np.rad2deg(np.sqrt(self.disagreement_sq / self.compared)))


class GammaElbow:
    """The heading correction and elbow flexion from wrist points, held where flagged.
    Causal and stateful: chunks of estimate times in order give the same result as one."""

    def __init__(self, lengths: SegmentLengths, forearm_imu: bool):
        self.lengths = lengths
        self.forearm_imu = forearm_imu
        self._gamma = 0.0
        self._flexion = 0.0
        self.stats = GammaStats()
        #: per estimate, (heading held, no point), when a caller wants them (batch runs)
        self.flag_log: list[tuple[np.ndarray, np.ndarray]] | None = None

    @property
    def source(self) -> str:
        """Which source makes the elbow: ``imu`` (forearm IMU, points as a check) or
        ``points`` (the γ elbow)."""
        return "imu" if self.forearm_imu else "points"

    def apply(self, Rw: np.ndarray, present: np.ndarray, wrist_thorax: np.ndarray,
              shoulder_thorax: np.ndarray, upper: int, forearm: int
              ) -> tuple[np.ndarray, np.ndarray]:
        """Correct ``Rw[:, upper]`` (world ← upper arm, (N, 3, 3)) in place and, without a
        forearm IMU, set ``Rw[:, forearm]``; ``Rw[:, 0]`` is the thorax. Returns the points'
        elbow flexion [rad] (N,) and which samples were flagged (N,) bool."""
        R_wt = Rw[:, 0]
        S = R_wt @ shoulder_thorax
        W = np.einsum("nij,nj->ni", R_wt, wrist_thorax)
        R_tilt = Rw[:, upper].copy()
        l_u, l_f = self.lengths.upper_arm, self.lengths.forearm
        with np.errstate(invalid="ignore"):
            solution = solve_gamma(S, W, R_tilt, l_u, l_f, out_of_reach="nan")
            a, b, _ = gamma_coefficients(S, W, R_tilt)
        has_point = np.isfinite(W).all(axis=1)
        good = has_point & np.isfinite(solution.gamma) & (np.hypot(a, b) >= MIN_CONDITION)
        gamma = _hold(solution.gamma, good, self._gamma)
        R_upper = elemental("z", gamma) @ R_tilt
        # flexion: the wrist in the corrected upper arm's frame, from the elbow
        w = np.einsum("nji,nj->ni", R_upper, W - S)
        with np.errstate(invalid="ignore"):
            flexion_now = np.arctan2(w[:, 0], -(w[:, 1] + l_u))
        flexion = _hold(flexion_now, has_point, self._flexion)
        if len(gamma):
            self._gamma, self._flexion = float(gamma[-1]), float(flexion[-1])
        Rw[:, upper] = R_upper
        if not self.forearm_imu:
            Rw[:, forearm] = R_upper @ elemental("z", flexion)
            present[forearm] = 1.0
        self.stats.samples += len(gamma)
        self.stats.flagged += int((~good).sum())
        self.stats.no_point += int((~has_point).sum())
        if self.flag_log is not None:
            self.flag_log.append((~good, ~has_point))
        return flexion, ~good

    def flags(self) -> tuple[np.ndarray, np.ndarray]:
        """``(held, no_point)`` bool arrays over every estimate so far (``flag_log`` on)."""
        if not self.flag_log:
            return np.zeros(0, bool), np.zeros(0, bool)
        held, none = zip(*self.flag_log, strict=True)
        return np.concatenate(held), np.concatenate(none)

    def compare(self, points_flexion: np.ndarray, imu_flexion: np.ndarray,
                flagged: np.ndarray) -> None:
        """Add the disagreement of the points' and the IMUs' elbow flexion [rad]."""
        d = (points_flexion - imu_flexion)[~flagged]
        d = d[np.isfinite(d)]
        self.stats.disagreement_sq += float(np.dot(d, d))
        self.stats.compared += len(d)


def _hold(values: np.ndarray, valid: np.ndarray, last: float) -> np.ndarray:
    """``values`` where ``valid``, else the last valid value before (``last`` at first)."""
    index = np.where(valid, np.arange(len(values)), -1)
    np.maximum.accumulate(index, out=index)
    padded = np.concatenate([[last], values])
    return padded[index + 1]
