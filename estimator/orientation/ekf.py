"""``ekf``: the thesis's per-link extended Kalman filter (Lovato 2024, ch. 3.3 and 4, App. A),
with the gyroscope bias its conclusions leave for future work.

State, 10 values: ``x = (ω, q, b)`` — the angular rate ω [rad/s] of the sensor in its own
axes, the quaternion ``q = R_world_sensor`` (wxyz, Hamilton; ENU world) and the gyroscope
bias b [rad/s].

Process model (eqs. 3.14–3.16 plus the bias):

    ω̇ = −ω / τ          first-order Gauss–Markov rate, time constant τ (thesis 0.2 s)
    q̇ = ½ q ⊗ (0, ω)    = ½ Q(q) ω, eq. (3.10)
    ḃ = 0               a random walk

driven by white noise: on ω with spectral density ``2 σ_ω² / τ`` (so σ_ω is the rate's
stationary standard deviation), none on q (the thesis: the kinematics are exact), and
``bias_walk²`` on b.

Discretisation, the thesis's Tustin (bilinear) approximation (section 4.2.2): with the
Jacobian ``F = ∂f/∂x`` at the current estimate and ``dt`` from the timestamps,

    F_d = (I − ½ dt F)⁻¹ (I + ½ dt F)              covariance transition
    x⁺  = x + (I − ½ dt F)⁻¹ dt f(x)                state transition
    Q_d = (I − ½ dt F)⁻¹ Q_c (I − ½ dt F)⁻ᵀ dt      process noise

— for the linear part of f (ω, b) the second is exactly ``F_d x``, the bilinear transform;
for the quaternion it is the linearly implicit trapezoidal step (the thesis's eq. 4.9 uses
forward Euler for the state; this one is second order and keeps ``|q|`` closer to 1).
``Q_d`` is the same bilinear map of the continuous noise: its cross terms between ω and q
(``¼ dt² Q(q) Q_ω``, exact to first order) let the gyroscope's new reading correct the
rotation of the step it ends; with ``Q_c dt`` alone the quaternion would lag a sample and
keep the Gauss–Markov model's decay of ω (a 2.5 % under-rotation at 100 Hz, τ = 0.2 s).

Measurements (eq. 3.17, sequential updates of the same sample are equivalent to one):

* gyroscope ``ω + b`` (the thesis: ω; the bias enters here);
* accelerometer ``R(q)ᵀ (0, 0, g)``: the thesis's link model adds the tangential and
  centripetal terms ``ω̇ × r + ω × (ω × r)`` of the sensor's lever arm r from the joint; a
  stand-alone IMU filter knows no lever arm, so r = 0 and every linear acceleration is
  measurement noise. Its standard deviation is ``acc_noise`` plus, per sample,
  ``lever_arm · (|ω|² + |ω̇|)`` — the size of those terms for a sensor ``lever_arm`` from
  its centre of rotation, with ω from the state and ω̇ from consecutive gyroscope
  readings — so the filter leans on the gyroscope while the segment turns fast;
* the quaternion norm ``|q| = 1`` with a tiny fictitious variance (r₇₇ of eq. 4.11); the
  quaternion is also renormalised after each update;
* with a magnetometer, the heading only (the thesis proposes the whole field vector
  ``R(q)ᵀ m₀``; that would let a disturbed field, and the inclination it assumes, tilt the
  estimate): the measured field is turned into the world by the predicted q,
  ``w = R(q) m``, and its bearing ``h = atan2(w_x, w_y)`` (east of north) must be 0 — the
  earth's field points north (+y) and down. The field's vertical part never enters, and
  the Jacobian is that of h along rotations about the world vertical only,
  ``∂h/∂q = 2 (q₃, q₂, −q₁, −q₀)``, so the correction turns the heading and reaches the
  tilt only through the covariance. A sample whose innovation exceeds ``mag_gate``
  standard deviations is skipped and flagged ``mag_disturbed``;
* at rest (below): a zero-rate measurement ``ω = 0``, which makes the bias the gyroscope's
  reading. Without it the bias is learnt only while the sensor turns (the accelerometer
  sees the bias about the horizontal axes; the one about the vertical needs the
  magnetometer or a turn that changes which axis is vertical).

Rest: ``|gyr − b| < rest_gyr`` and ``||acc| − g| < rest_acc`` without a break for at least
``rest_min_s``.

Start: the first sample sets q from the accelerometer and magnetometer (TRIAD), or, 6-axis,
from the accelerometer with the sensor's levelled x axis along world x (``base.py``);
ω = gyr, b = 0. Jacobians are analytic; ``tests/test_orientation_ekf.py`` checks them
against finite differences.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from ..errors import InvalidArgument
from ..rotations import matrix_to_quat
from .base import OrientationOutput, RestartableFilter, check_inputs, check_time

N_STATE = 10
W, Q, B = slice(0, 3), slice(3, 7), slice(7, 10)


@dataclass(frozen=True)
class EkfParams:
    """Model and noise parameters of the EKF (standard deviations unless said)."""

    tau: float = 0.2
    """Decorrelation time of the Gauss–Markov angular-rate model [s] (thesis: 0.2 s)."""
    rate_std: float = 2.0
    """Stationary standard deviation of the angular rate in that model [rad/s]."""
    bias_walk: float = 1e-4
    """Gyroscope bias random walk [rad/s/√s]."""
    gyr_noise: float = 0.005
    """Gyroscope white noise per sample [rad/s]."""
    acc_noise: float = 0.5
    """Accelerometer noise per sample [m/s²], including the linear acceleration the r = 0
    model leaves out."""
    mag_heading_noise: float = 0.05
    """Noise of the magnetometer's heading per sample [rad]."""
    norm_noise: float = 1e-3
    """Fictitious noise of the quaternion-norm measurement [-] (eq. 4.11, r₇₇)."""
    quat_std0: float = 0.01
    """Initial standard deviation of each quaternion component [-]."""
    bias_std0: float = 0.02
    """Initial standard deviation of each bias component [rad/s]."""
    gravity: float = 9.81
    """Gravity [m/s²]."""
    mag_gate: float = 5.0
    """Largest accepted heading innovation [standard deviations of the innovation]."""
    rest_gyr: float = 0.05
    """Rest: largest bias-corrected angular rate [rad/s]."""
    rest_acc: float = 0.5
    """Rest: largest deviation of ``|acc|`` from ``gravity`` [m/s²]."""
    rest_min_s: float = 1.0
    """Rest: shortest time both hold before the sensor counts as at rest [s]."""
    rest_rate_noise: float = 0.005
    """Noise of the zero-rate measurement at rest [rad/s]; ``inf`` turns it off."""
    lever_arm: float = 0.2
    """Distance of the sensor from its segment's centre of rotation [m] bounding the
    tangential and centripetal accelerations the r = 0 model leaves out: they enter as
    accelerometer noise ``lever_arm · (|ω|² + |ω̇|)``."""

    def __post_init__(self) -> None:
        may_be_zero = {"bias_walk", "lever_arm"}
        may_be_inf = {"mag_gate", "rest_gyr", "rest_acc", "rest_min_s", "rest_rate_noise"}
        for f in fields(self):
            value = getattr(self, f.name)
            ok = isinstance(value, int | float) and not math.isnan(value)
            ok = ok and (value >= 0 if f.name in may_be_zero else value > 0)
            ok = ok and (f.name in may_be_inf or math.isfinite(value))
            if not ok:
                bound = "≥ 0" if f.name in may_be_zero else "> 0"
                raise InvalidArgument(f"EkfParams.{f.name} must be a number {bound}"
                                      f"{'' if f.name in may_be_inf else ' and finite'}, "
                                      f"got {value!r}")


@dataclass
class EkfState:
    """After the last sample: ``x`` (10,) = (ω [rad/s], q wxyz, b [rad/s]), its covariance
    ``P`` (10, 10), that sample's time ``t`` [s] and how long the rest condition has held,
    ``rest_s`` [s] (−1 when it does not hold), and its gyroscope reading ``gyr`` [rad/s]."""

    x: np.ndarray
    P: np.ndarray
    t: float
    rest_s: float
    gyr: np.ndarray


# --- model: pure functions of one state vector --------------------------------------------

def quat_matrix(q: np.ndarray) -> np.ndarray:
    """``Q(q)`` (4, 3) of eq. (3.11): ``q ⊗ (0, ω) = Q(q) ω``."""
    q0, q1, q2, q3 = q
    return np.array([[-q1, -q2, -q3], [q0, -q3, q2], [q3, q0, -q1], [-q2, q1, q0]])


def rate_matrix(w: np.ndarray) -> np.ndarray:
    """``Ω(ω)`` (4, 4): ``q ⊗ (0, ω) = Ω(ω) q``."""
    wx, wy, wz = w
    return np.array([[0.0, -wx, -wy, -wz], [wx, 0.0, wz, -wy], [wy, -wz, 0.0, wx],
                     [wz, wy, -wx, 0.0]])


def process(x: np.ndarray, tau: float) -> np.ndarray:
    """``f(x) = ẋ`` (10,) of the continuous process model."""
    f = np.zeros(N_STATE)
    f[W] = -x[W] / tau
    f[Q] = 0.5 * quat_matrix(x[Q]) @ x[W]
    return f


def process_jacobian(x: np.ndarray, tau: float) -> np.ndarray:
    """``F = ∂f/∂x`` (10, 10) (App. A, with zero rows and columns for b)."""
    F = np.zeros((N_STATE, N_STATE))
    F[W, W] = -np.eye(3) / tau
    F[Q, W] = 0.5 * quat_matrix(x[Q])
    F[Q, Q] = 0.5 * rate_matrix(x[W])
    return F


def tustin_step(x: np.ndarray, dt: float, tau: float, Qc: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One Tustin step over ``dt`` [s] with ``A = I − ½dtF``: the next state
    ``x + A⁻¹ dt f(x)``, the transition ``F_d = A⁻¹ (I + ½dtF) = 2A⁻¹ − I`` and the process
    noise ``Q_d = A⁻¹ Q_c A⁻ᵀ dt`` of the spectral density ``Qc`` (10, 10) (zero if None)."""
    eye = np.eye(N_STATE)
    A_inv = np.linalg.inv(eye - 0.5 * dt * process_jacobian(x, tau))
    Qd = A_inv @ Qc @ A_inv.T * dt if Qc is not None else np.zeros((N_STATE, N_STATE))
    return x + A_inv @ (dt * process(x, tau)), 2.0 * A_inv - eye, Qd


def gravity_in_sensor(q: np.ndarray, g: float) -> np.ndarray:
    """``R(q)ᵀ (0, 0, g)`` (3,): what the accelerometer reads at rest (the DCM polynomial
    of the thesis's code, exact for unit q)."""
    q0, q1, q2, q3 = q
    return g * np.array([2.0 * (q1 * q3 - q0 * q2), 2.0 * (q2 * q3 + q0 * q1),
                         q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3])


def measurement(x: np.ndarray, g: float) -> np.ndarray:
    """``h(x)`` (7,): gyroscope ``ω + b``, accelerometer ``R(q)ᵀ (0, 0, g)``, ``|q|``."""
    return np.concatenate([x[W] + x[B], gravity_in_sensor(x[Q], g), [np.linalg.norm(x[Q])]])


def measurement_jacobian(x: np.ndarray, g: float) -> np.ndarray:
    """``H = ∂h/∂x`` (7, 10)."""
    q0, q1, q2, q3 = x[Q]
    H = np.zeros((7, N_STATE))
    H[0:3, W] = np.eye(3)
    H[0:3, B] = np.eye(3)
    H[3:6, Q] = 2.0 * g * np.array([[-q2, q3, -q0, q1], [q1, q0, q3, q2],
                                    [q0, -q1, -q2, q3]])
    H[6, Q] = x[Q] / np.linalg.norm(x[Q])
    return H


def field_bearing(q: np.ndarray, mag: np.ndarray) -> float:
    """Bearing [rad] east of north of the measured field ``mag`` (3,) turned into the world
    by ``q`` (normalised here): 0 when the heading is right."""
    w = _rotate(q / np.linalg.norm(q), mag)
    return math.atan2(w[0], w[1])


def heading_jacobian(q: np.ndarray) -> np.ndarray:
    """Row (10,) of the heading measurement: ``∂ field_bearing / ∂q`` along rotations about
    the world vertical, ``2 (q₃, q₂, −q₁, −q₀)``; zero on ω, b and tilt."""
    H = np.zeros(N_STATE)
    H[Q] = 2.0 * np.array([q[3], q[2], -q[1], -q[0]])
    return H


def initial_quat(acc: np.ndarray, mag: np.ndarray | None) -> np.ndarray:
    """``R_world_sensor`` (4,) wxyz from one sample: world up along ``acc``; north from
    ``mag`` (TRIAD), or, without it, the sensor's levelled x axis along world x."""
    up = acc / np.linalg.norm(acc)
    east = None
    if mag is not None:
        east = np.cross(mag, up)  # north × up = east
    if east is None or np.linalg.norm(east) < 1e-9 * np.linalg.norm(mag):
        # x along world x: east is the sensor's x with its vertical part removed
        east = np.array([1.0, 0.0, 0.0]) - up[0] * up
        if np.linalg.norm(east) < 1e-6:  # x vertical: levelled y along world y instead
            east = np.cross(np.array([0.0, 1.0, 0.0]) - up[1] * up, up)
    east = east / np.linalg.norm(east)
    north = np.cross(up, east)
    R_world_sensor = np.vstack([east, north, up])  # rows: world axes in sensor coordinates
    return matrix_to_quat(R_world_sensor)


# --- the filter ---------------------------------------------------------------------------

class ExtendedKalmanFilter(RestartableFilter):
    """The thesis's EKF on (ω, q) with a gyroscope bias (module docstring).

    ``update`` advances over one chunk from the state left by the previous one (a fresh
    start if none); ``update_batch`` runs a whole recording from a fresh state.
    """

    name = "ekf"

    def __init__(self, params: EkfParams | None = None) -> None:
        self.params = params if params is not None else EkfParams()
        self.state: EkfState | None = None
        p = self.params
        self._Qc = np.diag(np.r_[np.full(3, 2.0 * p.rate_std**2 / p.tau), np.zeros(4),
                                 np.full(3, p.bias_walk**2)])
        self._R = np.diag(np.r_[np.full(3, p.gyr_noise**2), np.full(3, p.acc_noise**2),
                                p.norm_noise**2])
        self._P0 = np.diag(np.r_[np.full(3, p.gyr_noise**2), np.full(4, p.quat_std0**2),
                                 np.full(3, p.bias_std0**2)])

    def update(self, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray,
               mag: np.ndarray | None = None) -> OrientationOutput:
        """Advance over one chunk: ``t`` [s] (N,), ``acc`` [m/s²] (N, 3), ``gyr`` [rad/s]
        (N, 3), ``mag`` [µT] (N, 3) or None."""
        t, acc, gyr, mag = check_inputs(t, acc, gyr, mag)
        n = t.shape[0]
        check_time(t, self.state.t if self.state is not None else None)
        q_out = np.empty((n, 4))
        bias_out = np.empty((n, 3))
        rest_out = np.zeros(n, dtype=bool)
        disturbed = np.zeros(n, dtype=bool)
        acc_norm = np.linalg.norm(acc, axis=1)
        for i in range(n):
            m = mag[i] if mag is not None else None
            if self.state is None:
                x = np.concatenate([gyr[i], initial_quat(acc[i], m), np.zeros(3)])
                self.state = EkfState(x=x, P=self._P0.copy(), t=float(t[i]), rest_s=-1.0,
                                      gyr=gyr[i].copy())
            else:
                rest_out[i], disturbed[i] = self._step(float(t[i]), acc[i], gyr[i], m,
                                                       float(acc_norm[i]))
            q_out[i] = self.state.x[Q]
            bias_out[i] = self.state.x[B]
        return OrientationOutput(q=q_out, gyr_bias=bias_out, rest=rest_out,
                                 mag_disturbed=disturbed)

    def _step(self, t: float, acc: np.ndarray, gyr: np.ndarray, mag: np.ndarray | None,
              acc_norm: float) -> tuple[bool, bool]:
        """Predict to ``t``, then correct with this sample. Returns (rest, mag disturbed)."""
        p, s = self.params, self.state
        dt = t - s.t
        x, Fd, Qd = tustin_step(s.x, dt, p.tau, self._Qc)
        P = Fd @ s.P @ Fd.T + Qd

        # rest: the condition must hold without a break for rest_min_s
        still = (np.linalg.norm(gyr - x[B]) < p.rest_gyr
                 and abs(acc_norm - p.gravity) < p.rest_acc)
        rest_s = (s.rest_s + dt if s.rest_s >= 0.0 else 0.0) if still else -1.0
        rest = rest_s >= p.rest_min_s

        z = np.concatenate([gyr, acc, [1.0]])
        h = measurement(x, p.gravity)
        H = measurement_jacobian(x, p.gravity)
        R = self._R.copy()
        w_dot = (gyr - s.gyr) / dt if dt > 0.0 else np.zeros(3)
        extra = p.lever_arm * (float(x[W] @ x[W]) + float(np.linalg.norm(w_dot)))
        R[3:6, 3:6] += extra * extra * np.eye(3)
        if rest and math.isfinite(p.rest_rate_noise):
            H = np.vstack([H, np.eye(3, N_STATE)])
            z = np.concatenate([z, np.zeros(3)])
            h = np.concatenate([h, x[W]])
            R = np.diag(np.r_[np.diag(R), np.full(3, p.rest_rate_noise**2)])
        x, P = _correct(x, P, z - h, H, R)

        disturbed = False
        if mag is not None:
            Hm = heading_jacobian(x[Q])
            e = -field_bearing(x[Q], mag)
            S = float(Hm @ P @ Hm) + p.mag_heading_noise**2
            if e * e > p.mag_gate**2 * S:
                disturbed = True
            else:
                x, P = _correct(x, P, np.array([e]), Hm[None, :],
                                np.array([[p.mag_heading_noise**2]]))

        x[Q] /= np.linalg.norm(x[Q])
        s.x, s.P, s.t, s.rest_s, s.gyr = x, P, t, rest_s, gyr.copy()
        return rest, disturbed


def _correct(x: np.ndarray, P: np.ndarray, innovation: np.ndarray, H: np.ndarray,
             R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kalman correction (eq. 4.7) with the Joseph form of the covariance update."""
    PHt = P @ H.T
    S = H @ PHt + R
    K = np.linalg.solve(S, PHt.T).T
    IKH = np.eye(N_STATE) - K @ H
    P = IKH @ P @ IKH.T + K @ R @ K.T
    return x + K @ innovation, 0.5 * (P + P.T)


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R(q) v`` for a unit quaternion q (4,) wxyz and a vector v (3,)."""
    w, u = q[0], q[1:]
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)
