"""``euler-cf``: the seed paper's Euler-angle complementary filter (Tsilomitrou et al. 2021,
section 3.1, eqs. 3–9), kept as the project's reference for what the paper did.

Per sample ``n`` with ``T = t[n] − t[n−1]`` (from the timestamps; the paper has a constant T):

* roll and pitch from the accelerometer, eq. (5): ``φ_a = atan2(A_x, A_z)``,
  ``θ_a = atan2(A_y, √(A_x² + A_z²))``;
* heading from the tilt-compensated magnetometer, eqs. (6)–(7): ``ψ_a = atan2(C_y, C_x)``;
* Euler rates from the gyroscope, eq. (4), evaluated at the accelerometer's ``φ_a, θ_a``
  (as the paper writes it, not at the filter's own angles);
* the complementary blend, eq. (8): ``x[n] = k (x[n−1] + ẋ T) + (1 − k) x_a[n]`` for
  ``x`` = φ, θ, ψ. Without a magnetometer ψ only integrates the gyroscope.

Convention (the paper's axes, read in our right-handed frames)
--------------------------------------------------------------
The paper's sensor axes (its MPU-9150's accelerometer and gyroscope: y longitudinal, along
the segment, x transverse, z normal to the board) are taken as ours, which
``docs/spec/recording.md`` mounts with ``+Y`` proximal and ``+Z`` out of the skin. Its angles
are roll φ about y, pitch θ about x and yaw ψ about the vertical, the "R_y(φ)R_x(θ)R_z(ψ)
configuration" (passive) of its ref. [46]. As a proper ENU orientation that is

    R_world_sensor = R_z(ψ) · R_x(θ) · R_y(−φ)

(intrinsic z, x, y; ``R_a`` the right-handed elemental rotation). ψ = 0 when the sensor's
y axis, levelled, points to magnetic north (world +y), growing counter-clockwise seen
from above; θ > 0 lifts y above the horizon; φ > 0 turns the sensor about its −y axis.
At rest ``R_world_sensorᵀ (0, 0, 1) = (sin φ cos θ, sin θ, cos φ cos θ) ∝ acc``.

The printed equations do not all agree with one right-handed convention. We take the
reading that keeps the most of them verbatim and correct the rest, each a misprint rather
than the method (the paper's results need a working filter):

1. eq. (5) is used as printed, with the two-argument ``atan2`` (the paper's text calls
   its atan2 an arctan with range [−π/2, π/2], which would fold every roll beyond ±90°;
   a forearm sensor on the lateral surface sits at φ ≈ ±90° throughout elbow flexion);
2. eq. (4) is used as printed except the sign of ``G_y`` in the roll row:
   ``φ̇ = −G_y + tan θ (sin φ G_x + cos φ G_z)``; with ``+G_y`` it contradicts eq. (5)
   (the gyroscope would turn roll one way and the accelerometer the other);
3. eq. (7) is the tilt compensation of ref. [46] for roll about x and pitch about y,
   written with this paper's letters (whose roll is about y and pitch about x), with a
   typo (``sin φ_a`` for ``sin θ_a`` in ``C_y``). Reading ``M`` in the MPU-9150
   magnetometer's own axes (its datasheet: ``M_x = m_y, M_y = m_x, M_z = −m_z`` in the
   accelerometer's frame — with the accelerometer's axes the heading would turn against
   the gyroscope's ψ̇) and giving the angles their roles back, the consistent form is, in our axes,
   ``C_x = m_y cos θ − m_x sin θ sin φ − m_z sin θ cos φ``,
   ``C_y = m_x cos φ − m_z sin φ``, ``ψ_a = atan2(C_y, C_x)``, exact at any tilt;
4. eq. (8) blends ψ and φ on the circle: ``x_g + (1 − k) wrap(x_a − x_g)``, which is
   eq. (8) whenever ``|x_a − x_g| < π``; read literally, a heading crossing ±180° would
   spin the estimate once around.

Weaknesses kept on purpose (the paper's method)
-----------------------------------------------
* Gimbal lock at θ = ±90°, i.e. when the sensor's y axis is vertical — a hanging or
  raised arm with the default mounting. Eq. (4) divides by ``cos θ_a`` (bounded below by
  ``MIN_COS_PITCH`` only to avoid a division by zero), and φ_a, ψ_a are ill-conditioned
  there; only ``ψ ∓ φ`` is defined.
* Tilt from the accelerometer at every sample with a fixed weight: linear acceleration
  tilts the estimate; eq. (4) is evaluated at the accelerometer's angles, so it too is
  disturbed by linear acceleration and noise.
* ``k`` is a weight per sample, so the blend's time constant ``T k / (1 − k)`` changes
  with the rate (k = 0.98 at 100 Hz: 0.49 s). No gyroscope bias estimate (``gyr_bias`` is
  zero); the bias leaves a steady tilt error of about ``bias · T k / (1 − k)``. No rest
  detection and no magnetic-disturbance rejection (``rest`` and ``mag_disturbed`` are
  all False).

A 6-axis start takes the heading of ``base.py``: ψ such that the sensor's x axis, levelled,
points along world x.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidArgument
from ..rotations import elemental, matrix_to_quat
from .base import OrientationOutput, RestartableFilter, check_inputs, check_time

#: Lower bound on ``cos θ_a`` in eq. (4): only guards the division at exactly ±90° pitch.
MIN_COS_PITCH = 1e-9


@dataclass(frozen=True)
class EulerCfParams:
    """Parameters of the paper's complementary filter."""

    k: float = 0.98
    """Weight of the gyroscope-propagated angle per sample, eq. (8) [-]. The paper gives
    ``k ∈ (0.5, 1)``, "close to 1", and no value; 0.98 is the usual choice. Allowed 0–1
    (1: gyroscope only, 0: accelerometer and magnetometer only)."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.k <= 1.0:
            raise InvalidArgument(f"k must be within 0–1, got {self.k!r}")


@dataclass
class EulerCfState:
    """Filter state after the last sample: roll ``phi``, pitch ``theta``, yaw ``psi`` [rad]
    (the convention of the module docstring) and that sample's time ``t`` [s]."""

    phi: float
    theta: float
    psi: float
    t: float


def accelerometer_angles(acc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (5): roll ``φ_a`` and pitch ``θ_a`` [rad] from ``acc`` [m/s²] (N, 3)."""
    ax, ay, az = acc[:, 0], acc[:, 1], acc[:, 2]
    return np.arctan2(ax, az), np.arctan2(ay, np.hypot(ax, az))


def compass_heading(mag: np.ndarray, phi: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Eqs. (6)–(7), consistent form: heading ``ψ_a`` [rad] from ``mag`` (N, 3) [any unit]
    tilt-compensated with roll ``phi`` and pitch ``theta`` [rad] (N,)."""
    mx, my, mz = mag[:, 0], mag[:, 1], mag[:, 2]
    sp, cp, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    c_x = my * ct - mx * st * sp - mz * st * cp
    c_y = mx * cp - mz * sp
    return np.arctan2(c_y, c_x)


def euler_rates(gyr: np.ndarray, phi: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Eq. (4) (with ``−G_y`` in the roll row): ``(φ̇, θ̇, ψ̇)`` [rad/s] (N, 3) from the
    body rates ``gyr`` [rad/s] (N, 3) at roll ``phi`` and pitch ``theta`` [rad] (N,)."""
    gx, gy, gz = gyr[:, 0], gyr[:, 1], gyr[:, 2]
    sp, cp = np.sin(phi), np.cos(phi)
    ct = np.cos(theta)
    ct = np.where(ct < 0.0, np.minimum(ct, -MIN_COS_PITCH), np.maximum(ct, MIN_COS_PITCH))
    turn = sp * gx + cp * gz
    return np.column_stack([-gy + np.sin(theta) / ct * turn, cp * gx - sp * gz, turn / ct])


def euler_to_quat(phi: np.ndarray, theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """``R_world_sensor = R_z(ψ) R_x(θ) R_y(−φ)`` as quaternions (N, 4) wxyz, w ≥ 0."""
    R = elemental("z", psi) @ elemental("x", theta) @ elemental("y", -np.asarray(phi))
    return matrix_to_quat(R)


def level_heading(phi: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Yaw ψ [rad] putting the sensor's levelled x axis along world x (6-axis start)."""
    return np.arctan2(np.sin(theta) * np.sin(phi), np.cos(phi))


class EulerComplementaryFilter(RestartableFilter):
    """The seed paper's complementary filter on roll, pitch and yaw (module docstring).

    ``update`` advances over one chunk from the state left by the previous one (a fresh
    start if none); ``update_batch`` runs a whole recording from a fresh state.
    """

    name = "euler-cf"

    def __init__(self, params: EulerCfParams | None = None) -> None:
        self.params = params if params is not None else EulerCfParams()
        self.state: EulerCfState | None = None

    def update(self, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray,
               mag: np.ndarray | None = None) -> OrientationOutput:
        """Advance over one chunk: ``t`` [s] (N,), ``acc`` [m/s²] (N, 3), ``gyr`` [rad/s]
        (N, 3), ``mag`` [µT] (N, 3) or None."""
        t, acc, gyr, mag = check_inputs(t, acc, gyr, mag)
        n = t.shape[0]
        prev_t = self.state.t if self.state is not None else None
        check_time(t, prev_t)
        if n == 0:
            return _empty_output()

        # Everything eqs. (4)–(7) need comes from the current sample only: vectorised.
        phi_a, theta_a = accelerometer_angles(acc)
        rates = euler_rates(gyr, phi_a, theta_a)
        psi_a = compass_heading(mag, phi_a, theta_a) if mag is not None else None
        dt = np.diff(t, prepend=t[0] if prev_t is None else prev_t)

        k = self.params.k
        phi = np.empty(n)
        theta = np.empty(n)
        psi = np.empty(n)
        state = self.state
        for i in range(n):
            if state is None:
                p0, th0 = float(phi_a[i]), float(theta_a[i])
                y0 = float(psi_a[i]) if psi_a is not None else float(level_heading(p0, th0))
                state = EulerCfState(p0, th0, y0, float(t[i]))
            else:
                T = float(dt[i])
                phi_g = state.phi + float(rates[i, 0]) * T
                theta_g = state.theta + float(rates[i, 1]) * T
                psi_g = state.psi + float(rates[i, 2]) * T
                state.phi = _wrap(phi_g + (1.0 - k) * _wrap(float(phi_a[i]) - phi_g))
                state.theta = k * theta_g + (1.0 - k) * float(theta_a[i])
                if psi_a is not None:
                    psi_g += (1.0 - k) * _wrap(float(psi_a[i]) - psi_g)
                state.psi = _wrap(psi_g)
                state.t = float(t[i])
            phi[i], theta[i], psi[i] = state.phi, state.theta, state.psi
        self.state = state

        flags = np.zeros(n, dtype=bool)
        return OrientationOutput(q=euler_to_quat(phi, theta, psi).reshape(n, 4),
                                 gyr_bias=np.zeros((n, 3)), rest=flags, mag_disturbed=flags.copy())


def _empty_output() -> OrientationOutput:
    return OrientationOutput(q=np.empty((0, 4)), gyr_bias=np.empty((0, 3)),
                             rest=np.empty(0, dtype=bool), mag_disturbed=np.empty(0, dtype=bool))


def _wrap(angle: float) -> float:
    """Angle [rad] into [−π, π]."""
    return math.remainder(angle, 2.0 * math.pi)
