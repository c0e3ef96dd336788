"""``qcf``: the default orientation filter, a quaternion complementary filter.

Mahony's explicit complementary filter family (seed thesis §2.2.4), with what a clinic's
sensors need:

* the gyroscope integrated exactly (quaternion exponential) over each sample's own ``dt``,
  so gaps and timestamp jitter do no harm;
* tilt from the specific force low-passed *in the inertial frame* by a second-order filter
  (time constant ``tau_acc``), as in VQF: the body's own acceleration, whose integral is a
  bounded velocity, cancels out of it far better than out of a per-sample correction;
* the magnetometer acting on heading only (a rotation about the vertical, so a disturbed
  field never tilts the estimate), and ignored while its norm or dip departs from the
  reference; the reference is the field that stayed put in the earth frame while the
  sensor turned (not the first sample's: kits start on tables, near laptops), so a field
  disturbed from the first sample is replaced within seconds of moving; the heading
  follows a clean field at ``tau_mag``, or faster where the heading's own uncertainty
  (grown by the bias's σ about the vertical while the field was disturbed or not yet
  trusted: ``bias_sigma`` until a rest has taught the bias) outweighs a reading's (the
  field's accepted deviation, ``mag_norm_tolerance``, over its horizontal part, one
  independent reading per ``tau_mag``): the Kalman gain of that heading, when larger;
* the gyroscope bias estimated online: quickly whenever the sensor rests (rest detected
  from the low-passed gyroscope and accelerometer; half a second of stillness from the
  first sample already gives a provisional one, a sensor on foam or skin that vibrates
  about its fixed orientation included: there a movement is a departure from the
  stillness's own vibration, ``rest_vibration`` times its RMS, or a turn away from the
  low-passed rate's path beyond ``rest_tilt``), slowly from the
  corrections in motion (from the heading's, after a rest, with a weight that grows back
  as the bias may drift);
  in motion also by a Kalman step every ``tilt_window`` from the tilt corrections, which
  answer the drift R (b − b̂) through the specific force's low-pass: R (sensor → I) and
  R b̂ low-passed alike make the equation exact in its lag (as VQF does), so every axis of
  the bias is seen as the sensor's turning sweeps the horizontal through its frame; each
  window weighed by its noise (the larger of ``tilt_noise`` and the scatter the windows
  show, plus a MEMS scale-factor error, ``gyro_scale`` times the window's turn) against
  the bias's covariance, which grows by its random walk and which a rest resets;
  until a rest, also by a Kalman step every ``mag_window`` from how the field turns in the
  sensor frame and how the heading drifts, each weighed by its noise (the magnetometer's,
  or the scatter the windows show in a room whose field varies) against the bias's own
  covariance, so that the part of the bias a window barely sees (along the field, on a
  sensor that hardly turns: a swaying trunk's) is not taken from its noise;
  optionally starting from a remembered bias (``gyr_bias_prior``: the kit's last learnt
  one), which the first stillness replaces and the corrections in motion refine;
* a gyroscope that lags its accelerometer (``gyro_delay_s``, a property of the kit that it
  declares: the gyroscope's samples describe their time stamp minus it) integrated over the
  accelerometer's own interval by linear extrapolation (``qcf_kernel``); 0 by default.

Parameters are one set for every sensor and session; see ``QcfParams``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import InvalidArgument
from .base import OrientationOutput, check_inputs, check_time
from .qcf_kernel import EMPTY_MAG, KERNEL_PARAM_SIZE, PARAM_SIZE, STATE_SIZE, kernel, kernel_python
from .qcf_kernel import append_rows as append_rows_kernel


@dataclass(frozen=True)
class QcfParams:
    """Tuning of ``qcf``. Times in seconds, rates in rad/s, fields in µT."""

    #: Time constant of the second-order low-pass of the specific force in I [s].
    tau_acc: float = 4.0
    #: The same at rest, and the longest used while the filter warms up [s].
    tau_acc_rest: float = 0.5
    #: Time constant of the heading correction from the magnetometer [s] (the longest: a
    #: heading more uncertain than the field's reading follows it faster, see the module).
    tau_mag: float = 4.0
    #: Low-pass time constant of the rest detector [s].
    tau_lowpass: float = 0.5
    #: Rest: every rate sample within this of its low-pass [rad/s].
    rest_gyr: float = 0.05
    #: Rest: the low-passed rate minus the bias below this [rad/s] before any rest has
    #: taught the bias (loose: a MEMS bias can be this large, 5 ``bias_sigma``; a bias a
    #: prior or the corrections in motion know better, to covariance P, only within as
    #: many σ of P plus the low-pass's noise: a slow turn is no rest) …
    rest_rate: float = 0.05
    #: … and after (tight: slow movements are not rest).
    rest_rate_known: float = 0.02
    #: Time constant with which later rests update the bias [s] (it drifts with
    #: temperature); until this much rest has taught it, every rest's second counts alike.
    tau_bias_rest: float = 10.0
    #: A rest must have lasted this much longer before the orientation is held still
    #: through it (the zero-velocity update) [s].
    zupt_delay: float = 0.3
    #: Rest: the accelerometer (over ``tau_rest_acc``) within this of its low-pass [m/s²].
    rest_acc: float = 0.25
    #: Stillness must last this long before it counts as rest [s].
    rest_time: float = 1.0
    #: Bias gain from tilt corrections in motion [1/s] (an integral time of 1/ki).
    ki_bias: float = 0.02
    #: Bias gain from heading corrections in motion [1/s] (see ``mag_bias_half_time``).
    ki_bias_mag: float = 0.02
    #: Largest bias believed [rad/s].
    bias_max: float = 0.2
    #: Window over which the field's turning is summed for the bias [s] …
    mag_window: float = 2.0
    #: … the magnetometer's noise, per sample and axis [µT] …
    mag_noise: float = 0.4
    #: … and the random walk by which the bias may drift between windows [rad/s/√s].
    #: This estimator runs only until a rest has taught the bias.
    bias_walk: float = 2.5e-4
    #: Until a rest has taught the bias, a rest must also keep the low-passed specific
    #: force within this angle of its direction when the stillness began [rad]: a slow
    #: turn the loose ``rest_rate`` lets through (a trunk's sway) tilts it.
    rest_tilt: float = float(np.deg2rad(0.5))
    #: Relative deviation of |m| from the reference that marks a disturbed field.
    mag_norm_tolerance: float = 0.05
    #: Deviation of the field's dip from the reference that marks a disturbance [rad].
    mag_dip_tolerance: float = float(np.deg2rad(3.0))
    #: Time constant with which the reference field follows a clean field [s].
    tau_mag_reference: float = 30.0
    #: A disturbance steady for this long becomes the new reference [s].
    mag_reaccept: float = 60.0
    #: Longest ``dt`` integrated in one step [s]; longer gaps are treated as this.
    max_dt: float = 1.0
    #: Samples of a rest averaged before its mean replaces the bias estimate.
    rest_min_samples: float = 20.0
    #: Rest samples count toward the bias only once the rest has gone on this long after
    #: them [s], so the slow start of a movement never leaks into the bias.
    rest_guard: float = 1.0
    #: A sensor still from its first sample has a provisional bias after this much
    #: stillness [s] (before it is a rest) …
    rest_time_first: float = 0.5
    #: … from samples that the stillness outlasted by this much [s] …
    rest_guard_first: float = 0.2
    #: … once there are this many of them.
    rest_min_samples_first: float = 8.0
    #: The reference's evidence grows by this while it holds, besides the turn [rad/s].
    mag_hold_weight: float = 0.03
    #: A new reference whose heading differs from the estimate's by more than this
    #: restarts the heading from the running mean of its readings [rad] (a smaller
    #: difference is corrected at tau_mag).
    mag_restart: float = 0.35
    #: Low-pass of the accelerometer before its deviation is compared with ``rest_acc``
    #: [s]: a movement's deviation is slow and passes; a phone's sample noise (0.1 m/s²
    #: an axis, whose raw deviations passed 0.25 m/s² every few samples, so a phone was
    #: never at rest and never learnt its bias) is cut by 2–3×.
    tau_rest_acc: float = 0.05
    #: A field that stayed put in the earth frame (its norm within mag_norm_tolerance,
    #: its direction within twice mag_dip_tolerance of its mean) while the sensor turned
    #: this far becomes the reference in place of one confirmed by less turning [rad].
    mag_confirm_turn: float = 0.3
    #: After a rest, the heading corrections' bias gain is ``ki_bias_mag · s / (s + this)``,
    #: s the time since the rest [s]: it grows as the bias's variance does. A MEMS bias
    #: random walk of ~2.5·10⁻⁴ rad/s/√s reaches the ~1.5 mrad/s by which a room's field
    #: errors move the bias (its direction varying by degrees) after (1.5e-3 / 2.5e-4)² s.
    mag_bias_half_time: float = 36.0
    #: The spread of an unknown bias (a MEMS gyroscope's zero-rate offset) [rad/s].
    bias_sigma: float = 0.01
    #: The field-turning windows' scatter (a room's field varying as the sensor moves) is
    #: the mean over this many of them.
    mag_scatter_windows: float = 5.0
    #: The least noise of a window's tilt equation for the bias, per horizontal axis [rad].
    tilt_noise: float = 1e-3
    #: Window over which the tilt corrections are summed for the bias [s]: two of
    #: ``tau_acc``, so that a body's slow accelerations the low-pass leaves (a sway at
    #: 0.1–0.2 Hz) mostly cancel within it (2-s windows took them for bias).
    tilt_window: float = 8.0
    #: A MEMS gyroscope's scale-factor (and axis-misalignment) error: a window whose sensor
    #: turned θ [rad] drifted by up to this times θ that is no bias (real sensors: without
    #: it, RING's rigid chain lost 0.1° on its arm angles).
    gyro_scale: float = 0.005
    #: A stillness from the first sample takes, until it is a rest, a gyroscope sample
    #: within this many times its own RMS deviation so far (when above ``rest_gyr``), while
    #: the sensor's turn away from the low-passed rate's path stays within ``rest_tilt``: a
    #: sensor on foam or skin vibrates about a fixed orientation while the kit lies still.
    rest_vibration: float = 3.0

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if not (np.isfinite(value) and value > 0):
                raise InvalidArgument(f"QcfParams.{name} must be a positive number, got {value!r}")

    def as_array(self) -> np.ndarray:
        values = [self.tau_acc, self.tau_mag, self.tau_lowpass, self.rest_gyr,
                  self.rest_acc, self.rest_time, self.ki_bias, self.ki_bias_mag, self.bias_max,
                  self.mag_norm_tolerance, self.mag_dip_tolerance, self.tau_mag_reference,
                  self.mag_reaccept, self.max_dt, self.rest_min_samples, self.rest_guard,
                  self.tau_acc_rest, self.rest_rate, self.tau_bias_rest,
                  self.rest_rate_known, self.zupt_delay, self.mag_window,
                  self.bias_walk, self.mag_noise, self.rest_tilt,
                  self.rest_time_first, self.rest_guard_first, self.mag_confirm_turn,
                  self.rest_min_samples_first, self.mag_hold_weight, self.mag_restart,
                  self.tau_rest_acc, self.mag_bias_half_time, self.bias_sigma,
                  self.mag_scatter_windows, self.tilt_noise,
                  self.tilt_window, self.gyro_scale, self.rest_vibration]
        assert len(values) == PARAM_SIZE
        return np.array(values, dtype=np.float64)


#: How a filter's final gyroscope bias was last taught by stillness (``LearntGyroBias.learnt``).
LEARNT_NONE, LEARNT_STILL_START, LEARNT_REST = "none", "still start", "rest"


@dataclass(frozen=True)
class LearntGyroBias:
    """A filter's gyroscope bias after its last sample, and how far to trust it.

    ``bias`` [rad/s], sensor frame. ``learnt``: how stillness last taught it — ``"rest"``
    (a rest of ``rest_time`` or more), ``"still start"`` (a provisional bias from the first
    half second of a sensor still from its first sample) or ``"none"`` (never: the bias is
    the starting one, zero or the prior, moved only by the corrections in motion; it must
    not be remembered as a learnt one). ``still_s``: seconds of stillness it was averaged
    from [s]; ``age_s``: from then to the last sample [s] (NaN when ``learnt`` is none);
    ``prior``: whether the filter started from a remembered bias."""

    bias: tuple[float, float, float]
    learnt: str
    still_s: float
    age_s: float
    prior: bool

    @property
    def remembered(self) -> bool:
        """Whether a kit should remember this bias for its next session."""
        return self.learnt != LEARNT_NONE


def check_bias_prior_cov(cov, bias_sigma: float) -> tuple[tuple[float, ...], ...]:
    """A bias prior's covariance [rad²/s²]: 3 × 3, finite, symmetric, positive definite,
    and no axis's variance above ``bias_sigma``² (an unknown bias's); else
    ``InvalidArgument``."""
    try:
        values = np.asarray(cov, dtype=np.float64)
    except (TypeError, ValueError):
        values = np.empty(0)
    if values.shape != (3, 3) or not np.all(np.isfinite(values)) \
            or not np.allclose(values, values.T, rtol=0.0, atol=1e-12):
        raise InvalidArgument(f"a gyroscope bias prior's covariance must be a symmetric 3 x 3 "
                              f"matrix of finite numbers [rad^2/s^2], got {cov!r}")
    eigenvalues = np.linalg.eigvalsh(values)
    if eigenvalues[0] <= 0.0 or eigenvalues[-1] > bias_sigma**2 * (1.0 + 1e-9):
        raise InvalidArgument(f"a gyroscope bias prior's covariance must be positive definite "
                              f"and at most bias_sigma^2 = {bias_sigma**2} on every axis, "
                              f"got eigenvalues {eigenvalues.tolist()}")
    return tuple(tuple(float(v) for v in row) for row in values)


def check_bias_prior(prior, bias_max: float) -> tuple[float, float, float]:
    """A remembered gyroscope bias as three floats [rad/s], or InvalidArgument naming
    what is wrong."""
    values = np.asarray(prior, dtype=np.float64) if prior is not None else None
    if values is None or values.shape != (3,) or not np.all(np.isfinite(values)):
        raise InvalidArgument(f"a gyroscope bias prior must be 3 finite numbers [rad/s], "
                              f"got {prior!r}")
    if np.max(np.abs(values)) > bias_max:
        raise InvalidArgument(f"a gyroscope bias prior must be within ±{bias_max} rad/s per "
                              f"axis, got {values.tolist()}")
    return float(values[0]), float(values[1]), float(values[2])


#: The largest gyroscope delay a kit may declare [s] (``gyro_delay_s``): a few samples at
#: 100 Hz; a larger one is a clock fault, not a sensor's timing.
GYRO_DELAY_MAX_S = 0.05


def check_gyro_delay(value, what: str = "gyro_delay_s") -> float:
    """A kit's gyroscope delay behind its accelerometer as a float [s], or InvalidArgument
    naming ``what`` and the allowed range."""
    try:
        delay = float(value)
    except (TypeError, ValueError, OverflowError):
        delay = math.nan
    if isinstance(value, bool) or not 0.0 <= delay <= GYRO_DELAY_MAX_S:
        raise InvalidArgument(f"{what} must be a number of seconds from 0 to "
                              f"{GYRO_DELAY_MAX_S}, got {value!r}")
    return delay


@dataclass
class QcfState:
    """Everything carried between chunks (see ``qcf_kernel`` for the layout)."""

    vector: np.ndarray = field(default_factory=lambda: np.zeros(STATE_SIZE))

    @property
    def gyr_bias(self) -> np.ndarray:
        return self.vector[9:12].copy()


@dataclass
class QuaternionComplementaryFilter:
    """The ``qcf`` filter: ``update`` per chunk, ``update_batch`` for a whole recording."""

    params: QcfParams = field(default_factory=QcfParams)
    state: QcfState = field(default_factory=QcfState)
    #: Use the compiled kernel when numba is installed (False: the pure-Python fallback).
    compiled: bool = True
    #: The bias to start from [rad/s] (sensor frame), e.g. the kit's last learnt one for
    #: this sensor (``learnt_bias``); None: zero. A fresh state (``update_batch``) starts
    #: from it too.
    gyr_bias_prior: tuple[float, float, float] | None = None
    #: How far the kit's gyroscope lags its accelerometer [s]: its samples describe their
    #: time stamp minus this (0 to ``GYRO_DELAY_MAX_S``; 0: in step, today's numbers).
    gyro_delay_s: float = 0.0
    #: The covariance of ``gyr_bias_prior`` [rad²/s²] (3 × 3, sensor frame) where it is
    #: known better than ``QcfParams.bias_sigma`` along some axis (a swaying 6-axis kit's
    #: biases from the held poses, ``pipeline.calibrate.biases_from_poses``): the
    #: corrections in motion then move it along that axis only by what they show beyond it.
    #: None: ``bias_sigma``² on each axis.
    gyr_bias_prior_cov: tuple[tuple[float, ...], ...] | None = None
    name: str = field(default="qcf", init=False)

    def __post_init__(self) -> None:
        self.gyro_delay_s = check_gyro_delay(self.gyro_delay_s)
        self._params = np.append(self.params.as_array(), self.gyro_delay_s)
        assert self._params.shape == (KERNEL_PARAM_SIZE,)
        if self.gyr_bias_prior_cov is not None:
            if self.gyr_bias_prior is None:
                raise InvalidArgument("a gyroscope bias prior's covariance needs the prior "
                                      "(gyr_bias_prior)")
            self.gyr_bias_prior_cov = check_bias_prior_cov(self.gyr_bias_prior_cov,
                                                           self.params.bias_sigma)
        if self.gyr_bias_prior is not None:
            self.gyr_bias_prior = check_bias_prior(self.gyr_bias_prior, self.params.bias_max)
            if not self.state.vector[13]:
                self._start_from_prior(self.state)

    def _start_from_prior(self, state: QcfState) -> None:
        assert self.gyr_bias_prior is not None
        state.vector[9:12] = self.gyr_bias_prior
        if self.gyr_bias_prior_cov is not None:
            c = self.gyr_bias_prior_cov
            state.vector[161:167] = (c[0][0], c[1][1], c[2][2], c[0][1], c[0][2], c[1][2])
            state.vector[160] = 1.0

    def _fresh_state(self) -> QcfState:
        state = QcfState()
        if self.gyr_bias_prior is not None:
            self._start_from_prior(state)
        return state

    def update(self, t, acc, gyr, mag=None) -> OrientationOutput:
        t, acc, gyr, mag = check_inputs(t, acc, gyr, mag)
        n = t.shape[0]
        q = np.empty((n, 4))
        bias = np.empty((n, 3))
        rest = np.zeros(n, dtype=np.bool_)
        disturbed = np.zeros(n, dtype=np.bool_)
        run = kernel if self.compiled else kernel_python
        bad = run(t, acc, gyr, EMPTY_MAG if mag is None else mag, 0 if mag is None else 1,
                  self._params, self.state.vector, q, bias, rest, disturbed)
        if bad >= 0:  # the kernel checked the times first and changed nothing: say why
            check_time(t, self.state.vector[12] if self.state.vector[13] else None)
            raise InvalidArgument(f"t at sample {bad} is not after the previous one")
        return OrientationOutput(q=q, gyr_bias=bias, rest=rest, mag_disturbed=disturbed)

    def reference_field(self) -> tuple[float, float, float] | None:
        """The reference field the filter has settled on: norm [µT], dip [rad], and its
        evidence (the turn it held through plus its hold time, ``mag_hold_weight``)
        [rad]; None before the first sample."""
        v = self.state.vector
        if not v[13]:
            return None
        return float(v[27]), float(v[28]), float(v[74])

    def update_batch(self, t, acc, gyr, mag=None) -> OrientationOutput:
        self.state = self._fresh_state()
        return self.update(t, acc, gyr, mag)

    def learnt_bias(self) -> LearntGyroBias | None:
        """The gyroscope bias after the last sample and how it was learnt; None before
        the first sample."""
        v = self.state.vector
        if not v[13]:
            return None
        how = {1.0: LEARNT_STILL_START, 2.0: LEARNT_REST}.get(float(v[82]), LEARNT_NONE)
        learnt = how != LEARNT_NONE
        return LearntGyroBias(bias=(float(v[9]), float(v[10]), float(v[11])), learnt=how,
                              still_s=float(v[84]) if learnt else 0.0,
                              age_s=float(v[12] - v[83]) if learnt else float("nan"),
                              prior=self.gyr_bias_prior is not None)

    def bias_covariance(self) -> np.ndarray | None:
        """The covariance of the gyroscope bias after the last sample [rad²/s²] (3 × 3,
        sensor frame), as the filter weighs it; None before the first sample."""
        v = self.state.vector
        if not v[13]:
            return None
        p00, p11, p22, p01, p02, p12 = v[54:60]
        return np.array([[p00, p01, p02], [p01, p11, p12], [p02, p12, p22]])

    def append_rows(self, rows: np.ndarray, nine_axis: bool, t_out: np.ndarray,
                    acc_out: np.ndarray, gyr_out: np.ndarray, q_out: np.ndarray,
                    end: int) -> bool:
        """``update`` over stream rows (n, 10) float64 ``[t, acc, gyr, mag]``, their t,
        acc, gyr and q written at ``end`` of a track's buffers, in one compiled call (see
        ``qcf_kernel.append_rows_python``). False, doing nothing, when this filter has no
        compiled kernel: the caller feeds the columns to ``update`` instead."""
        if append_rows_kernel is None or not self.compiled:
            return False
        bad = append_rows_kernel(rows, 1 if nine_axis else 0, self._params,
                                 self.state.vector, t_out, acc_out, gyr_out, q_out, end)
        if bad >= 0:  # nothing was changed: say why
            t = np.ascontiguousarray(rows[:, 0])
            check_time(t, self.state.vector[12] if self.state.vector[13] else None)
            raise InvalidArgument(f"t at sample {bad} is not after the previous one")
        return True
