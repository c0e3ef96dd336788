"""One sensor's stream as the pipeline keeps it: its filter, and its samples and
orientations so far, in contiguous buffers that grow by doubling (a chunk costs its own
size, not the history's) and can drop what no estimate needs any more."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import InvalidArgument
from ..jit import compiler
from ..orientation import OrientationFilter, make_filter
from ..orientation.qcf import LEARNT_NONE
from . import drift as drift_module


def _not_increasing_python(t, last):
    """Whether a time in ``t`` [s] (N,) is not after the one before it (``last`` before
    the first; NaN: none)."""
    previous = last
    for i in range(t.shape[0]):
        if t[i] <= previous:
            return True
        previous = t[i]
    return False


def _compile():
    jit = compiler(nogil=True)
    return jit(_not_increasing_python) if jit else _not_increasing_python


_not_increasing = _compile()
#: A row of ``SensorTrack._h`` with no drift taken back: 0 rad, no knot.
_NONE_TAKEN_BACK = np.array([0.0, np.nan])


@dataclass
class SensorTrack:
    """Samples of one sensor: ``t`` [s], ``acc`` [m/s²], ``gyr`` [rad/s] and the filter's
    ``q`` (R_world_sensor, wxyz), in arrival order (t non-decreasing)."""

    name: str
    filter_name: str
    #: The gyroscope bias the filter starts from [rad/s] (sensor frame; None: zero), the
    #: kit's last learnt one for this sensor (``make_filter``).
    gyr_bias_prior: tuple[float, float, float] | None = None
    #: How far the kit's gyroscope lags its accelerometer [s] (``make_filter``).
    gyro_delay_s: float = 0.0
    #: The covariance of ``gyr_bias_prior`` [rad²/s²] (3 × 3; None: the filter's own),
    #: set by ``restart_filter``.
    gyr_bias_prior_cov: tuple | None = None
    filter: OrientationFilter = field(init=False)
    nine_axis: bool | None = field(default=None, init=False)
    #: The session left this 9-axis sensor's magnetometer out (``drop_magnetometer``).
    magnetometer_dropped: bool = field(default=False, init=False)
    first_t: float = field(default=np.inf, init=False)
    last_t: float = field(default=-np.inf, init=False)
    #: Rows forgotten so far: a kept row's absolute index is its position plus this.
    discarded: int = field(default=0, init=False)
    _t: np.ndarray = field(default_factory=lambda: np.empty(1024), init=False)
    _acc: np.ndarray = field(default_factory=lambda: np.empty((1024, 3)), init=False)
    _gyr: np.ndarray = field(default_factory=lambda: np.empty((1024, 3)), init=False)
    _q: np.ndarray = field(default_factory=lambda: np.empty((1024, 4)), init=False)
    #: Per sample the heading drift taken back so far [rad] (``drift``; 0: none) and the
    #: time [s] of the knot its drift is counted from (NaN: none).
    _h: np.ndarray = field(default_factory=lambda: np.zeros((1024, 2)), init=False)
    #: The magnetometer's chunks until calibration (``forget_magnetometer``), [µT].
    _mag: list | None = field(default_factory=list, init=False)
    # Packed samples (equal stamps): the first stamp, samples seen, and the current run
    # of equal stamps (its stamp and the index of its first sample), see ``_retime``.
    _t0: float = field(default=np.nan, init=False)
    _seen: int = field(default=0, init=False)
    _run_stamp: float = field(default=np.nan, init=False)
    _run_start: int = field(default=0, init=False)
    _drift: drift_module.DriftTakeBack | None = field(default=None, init=False)
    _start: int = field(default=0, init=False)  # first kept row
    _end: int = field(default=0, init=False)  # one past the last row

    def __post_init__(self) -> None:
        self.filter = self._new_filter()

    def _new_filter(self) -> OrientationFilter:
        return make_filter(self.filter_name, gyr_bias_prior=self.gyr_bias_prior,
                           gyro_delay_s=self.gyro_delay_s,
                           gyr_bias_prior_cov=self.gyr_bias_prior_cov)

    def append(self, t, acc, gyr, mag) -> None:
        """Run the filter over a chunk and keep it."""
        n = len(t)
        if n == 0:
            return
        if self.nine_axis is None:
            self._set_nine_axis(mag is not None)
        elif self.nine_axis != (mag is not None):
            raise InvalidArgument(f"sensor {self.name} changed between 6 and 9 axes mid-stream")
        if t[0] < self._run_stamp:  # (the last stamp as given, before ``_retime``)
            raise InvalidArgument(
                f"t goes backwards for sensor {self.name} ({t[0]} after {self._run_stamp})")
        t = self._retime(np.asarray(t, dtype=np.float64))
        q = self.filter.update(t, acc, gyr, None if self.magnetometer_dropped else mag).q
        if mag is not None and self._mag is not None:
            self._mag.append(np.array(mag, dtype=np.float64))
        if self._end + n > len(self._t):
            self._grow(n)
        end = self._end + n
        self._t[self._end:end] = t
        self._acc[self._end:end] = acc
        self._gyr[self._end:end] = gyr
        self._q[self._end:end] = q
        self._take_back_drift(self._end, end)
        self._end = end
        self.last_t = float(t[-1])
        if self.first_t == np.inf:
            self.first_t = float(t[0])

    def _set_nine_axis(self, nine_axis: bool) -> None:
        """The first chunk says whether the sensor has a magnetometer: a 9-axis one takes
        no drift back, and its buffer's rows say so from now on (``_grow`` keeps it)."""
        self.nine_axis = nine_axis
        if nine_axis:
            self._h[:] = _NONE_TAKEN_BACK

    def _take_back_drift(self, start: int, end: int) -> None:
        """A 6-axis sensor's heading drift between rests (``drift``) for the buffers' rows
        ``start:end``, into ``_h`` (zero on a 9-axis sensor)."""
        if self.nine_axis:  # its rows hold ``_NONE_TAKEN_BACK`` (``_grow``, ``append``)
            return
        if not drift_module.ENABLED:
            self._h[start:end] = _NONE_TAKEN_BACK
            return
        if self._drift is None:
            self._drift = drift_module.DriftTakeBack()
        self._drift.apply(self._t[start:end], self._acc[start:end], self._gyr[start:end],
                          self._q[start:end], self._h[start:end])

    def append_rows(self, rows: np.ndarray) -> None:
        """``append`` of stream rows (n, 10) float64 ``[t, ax, ay, az, gx, gy, gz, mx, my,
        mz]`` (NaN magnetometer: a 6-axis sensor), as the stream protocol checked them. The
        same numbers as ``append`` of their columns; with ``qcf`` compiled, the filter and
        the copy into the buffers are one call (a live stream's every message comes here)."""
        n = rows.shape[0]
        if n == 0:
            return
        nine_axis = not math.isnan(rows[0, 7])
        mag = None if not nine_axis else rows[:, 7:10]
        append = getattr(self.filter, "append_rows", None)
        if append is None:
            self.append(rows[:, 0], rows[:, 1:4], rows[:, 4:7], mag)
            return
        if self.nine_axis is None:
            self._set_nine_axis(nine_axis)
        elif self.nine_axis != nine_axis:
            raise InvalidArgument(f"sensor {self.name} changed between 6 and 9 axes mid-stream")
        first = float(rows[0, 0])
        if first < self._run_stamp:
            raise InvalidArgument(
                f"t goes backwards for sensor {self.name} ({first} after {self._run_stamp})")
        if self._end + n > len(self._t):
            self._grow(n)
        if nine_axis and self._mag is not None:
            self._mag.append(rows[:, 7:10].copy())
        stamps = rows[:, 0]
        retimed = self._retime(stamps)
        if retimed is not stamps:
            rows = rows.copy()
            rows[:, 0] = retimed
        if not append(rows, nine_axis and not self.magnetometer_dropped, self._t, self._acc,
                      self._gyr, self._q, self._end):
            self.append(rows[:, 0], rows[:, 1:4], rows[:, 4:7], mag)  # no compiled kernel
            return
        self._take_back_drift(self._end, self._end + n)
        self._end += n
        self.last_t = float(rows[n - 1, 0])
        if self.first_t == np.inf:
            self.first_t = first

    def _retime(self, t: np.ndarray) -> np.ndarray:
        """Samples that share a stamp (kits that pack several samples stamp them alike,
        ``docs/spec/recording.md``) spread at the mean interval so far after it: the k-th of
        a run at ``stamp + k · (stamp − first stamp) / (samples before it)``, so the
        filter integrates each over its own interval and estimates come at distinct
        times. Causal and independent of chunking; ``t`` itself when no stamp repeats."""
        n = len(t)
        if n == 0:
            return t
        if self._seen == 0:
            self._t0 = float(t[0])
        # the usual case, every stamp after the one before: cheaply (a live stream's
        # every message)
        if not _not_increasing(t, self._run_stamp):
            self._seen += n
            self._run_stamp = float(t[n - 1])
            self._run_start = self._seen - 1
            return t
        if not (np.diff(t) >= 0).all():  # the filter says what is wrong
            return t
        index = self._seen + np.arange(n)
        same = np.empty(n, dtype=bool)
        same[0] = t[0] == self._run_stamp
        same[1:] = t[1:] == t[:-1]
        starts = np.where(same, -1, index)
        run_start = np.maximum.accumulate(np.maximum(starts, np.where(
            np.arange(n) == 0, self._run_start if same[0] else index[0], -1)))
        self._seen += n
        self._run_stamp = float(t[-1])
        self._run_start = int(run_start[-1])
        if not same.any():
            return t
        k = index - run_start
        with np.errstate(invalid="ignore", divide="ignore"):
            interval = np.where(run_start > 0, (t - self._t0) / run_start, 0.0)
        # never past the next stamp: at most nine tenths of the mean interval each
        retimed = t + 0.9 * k * interval
        return np.maximum.accumulate(np.maximum(retimed, self.last_t))

    def reference_field(self, until: float) -> tuple[float, float, float] | None:
        """The reference field a fresh filter settles on over the samples up to ``until``
        [s]: norm [µT], dip [rad] and its evidence [rad]; None for a 6-axis sensor, a
        filter that learns none, or after ``forget_magnetometer``. The same whatever the
        chunks the samples came in."""
        if not self.nine_axis or self._mag is None or not self._mag:
            return None
        fresh = self._new_filter()
        if not hasattr(fresh, "reference_field"):
            return None
        t, acc, gyr, _ = self.arrays()
        n = int(np.searchsorted(t, until, "right"))
        if self.discarded or n == 0:
            return None
        fresh.update(t[:n], acc[:n], gyr[:n], np.concatenate(self._mag)[:n])
        return fresh.reference_field()

    def pose_field(self, start: float, end: float) -> tuple[float, float] | None:
        """The field's mean norm [µT] and dip [rad] over ``start…end`` [s], the dip as the
        angle between the accelerometer's and the magnetometer's readings, sample by
        sample (in a held pose the accelerometer reads the upright; a sway's accelerations
        average out): no filter's tilt enters, which while a never-resting sensor's bias
        is unknown is off by bias × the tilt time constant (degrees). None without
        magnetometer samples there."""
        if not self.nine_axis or self._mag is None or not self._mag or self.discarded:
            return None
        t, acc, _, _ = self.arrays()
        a, b = np.searchsorted(t, start, "left"), np.searchsorted(t, end, "right")
        if b <= a:
            return None
        mag, acc = np.concatenate(self._mag)[a:b], acc[a:b]
        norm = np.linalg.norm(mag, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            sine = -np.einsum("ni,ni->n", acc, mag) / (np.linalg.norm(acc, axis=1) * norm)
        sine = sine[np.isfinite(sine)]
        if not sine.size:
            return None
        return float(norm.mean()), float(np.arcsin(np.clip(sine, -1.0, 1.0)).mean())

    def forget_magnetometer(self) -> None:
        """Stop keeping the magnetometer's samples (they serve calibration only)."""
        self._mag = None

    def drop_magnetometer(self) -> None:
        """From now on, and for every sample kept, orient this 9-axis sensor without its
        magnetometer: a fresh filter re-runs over the kept samples (the caller does it
        before anything was discarded, at calibration) and takes the later ones."""
        self.magnetometer_dropped = True
        self.filter = self._new_filter()
        kept = slice(self._start, self._end)
        if self._end > self._start:
            self._q[kept] = self.filter.update(self._t[kept], self._acc[kept],
                                               self._gyr[kept], None).q

    def restart_filter(self, gyr_bias_prior: tuple[float, float, float],
                       covariance: tuple | None = None) -> None:
        """From now on, and for every sample kept, orient this sensor with a fresh filter
        that starts from ``gyr_bias_prior`` [rad/s] (sensor frame), known to ``covariance``
        [rad²/s²] (3 × 3; None: the filter's own): it re-runs over the kept samples (the
        caller does it before anything was discarded, at calibration), the drift taken
        back with it."""
        self.gyr_bias_prior = gyr_bias_prior
        self.gyr_bias_prior_cov = covariance
        self.filter = self._new_filter()
        self._drift = None
        kept = slice(self._start, self._end)
        if self._end > self._start:
            self._q[kept] = self.filter.update(
                self._t[kept], self._acc[kept], self._gyr[kept],
                None if not self.nine_axis or self.magnetometer_dropped else
                np.concatenate(self._mag)[self._start:self._end]).q
            self._take_back_drift(self._start, self._end)

    def still_taught(self, until: float) -> bool:
        """Whether stillness (a rest, or a still start) had taught this sensor's filter its
        gyroscope bias by ``until`` [s] (``stillness_bias``)."""
        return self.stillness_bias(until) is not None

    def stillness_bias(self, until: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The gyroscope bias [rad/s] (sensor frame) and its covariance [rad²/s²] (3 × 3,
        the filter's own) of this sensor's filter at ``until`` [s], where stillness (a
        rest, or a still start) had taught it by then: a fresh filter run over the samples
        kept up to then (at calibration all are kept), so a batch and a stream answer
        alike. None where no stillness had, or for a filter that learns no bias from
        stillness."""
        t, acc, gyr, _ = self.arrays()
        n = int(t.searchsorted(until, "right"))
        fresh = self._new_filter()
        learnt_bias = getattr(fresh, "learnt_bias", None)
        if n == 0 or learnt_bias is None:
            return None
        fresh.update(t[:n], acc[:n], gyr[:n], None)
        learnt = learnt_bias()
        if learnt is None or learnt.learnt == LEARNT_NONE:
            return None
        return np.array(learnt.bias), fresh.bias_covariance()

    def _grow(self, n: int) -> None:
        kept = slice(self._start, self._end)
        size = self._end - self._start
        capacity = max(len(self._t), 2 * (size + n))
        for name in ("_t", "_acc", "_gyr", "_q", "_h"):
            old = getattr(self, name)
            new = np.empty((capacity, *old.shape[1:]))
            new[:size] = old[kept]
            setattr(self, name, new)
        if self.nine_axis:
            self._h[size:] = _NONE_TAKEN_BACK
        self._start, self._end = 0, size

    def discard_before(self, t: float) -> None:
        """Forget samples before the last one at or before ``t`` (kept for slerp)."""
        times = self._t[self._start:self._end]
        keep_from = max(int(times.searchsorted(t, "right")) - 1, 0)
        self._start += keep_from
        self.discarded += keep_from

    def kept(self) -> int:
        """How many samples are kept."""
        return self._end - self._start

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(t, acc, gyr, q)`` of the samples kept (contiguous views, not copies)."""
        kept = slice(self._start, self._end)
        return self._t[kept], self._acc[kept], self._gyr[kept], self._q[kept]

    def headings_taken_back(self) -> np.ndarray:
        """The heading drift taken back at each sample kept [rad] (``drift``): the sensor's
        heading is ``Rz(h) · R(q)`` (a view)."""
        return self._h[self._start:self._end, 0]

    def drift_taken_back(self) -> np.ndarray:
        """``(headings_taken_back, knot_times)`` of the samples kept as one (N, 2) view."""
        return self._h[self._start:self._end]

    def knot_times(self) -> np.ndarray:
        """At each sample kept, the time [s] of the rest (knot) from which the drift not yet
        taken back is counted (``drift``; NaN: none yet, or a 9-axis sensor) (a view)."""
        return self._h[self._start:self._end, 1]

    def times(self) -> np.ndarray:
        """``t`` of the samples kept (a contiguous view)."""
        return self._t[self._start:self._end]

    def orientations(self) -> np.ndarray:
        """``q`` of the samples kept (a contiguous view)."""
        return self._q[self._start:self._end]

    def window(self, start: float, end: float):
        """``(acc, gyr, q)`` of the samples with ``start ≤ t ≤ end``."""
        t, acc, gyr, q = self.arrays()
        a, b = np.searchsorted(t, start, "left"), np.searchsorted(t, end, "right")
        return acc[a:b], gyr[a:b], q[a:b]
