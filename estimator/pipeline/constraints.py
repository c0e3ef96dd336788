"""Joint constraints that keep a kit's forearm and hand headings tied together.

Without a magnetometer (or where the kit's magnetometers disagree) each sensor's heading
drifts on its own. The elbow and the wrist
have two degrees of freedom each: the elbow cannot turn about the upper arm's X axis
(``R_humerus_forearm = Rz · Ry``), the wrist not about the hand's long axis
(``R_forearm_hand = Rx · Rz``). A heading error ``δ`` of the distal segment (a turn about
the vertical, ``Rz_world(δ)``) breaks that: for the elbow the residual is
``u · Rz(δ) v`` with ``u`` the upper arm's Z axis and ``v`` the forearm's Y axis (world);
for the wrist ``u`` is the forearm's X axis and ``v`` the hand's Z axis. Linearised about
``δ = 0`` the residual vanishes at ``δ = −(u·v) / D``, ``D = u_y v_x − u_x v_y``, and ``D²``
says how well the sample observes ``δ`` (zero with the elbow straight: then a heading error
is a pronation error no joint reveals). The correction is the ``D²``-weighted mean of these
per-sample values with exponential forgetting (time constant ``tau``) and a prior toward
no correction, causal, so chunks give what the whole recording gives; where two sensors'
headings drift apart steadily (6-axis sensors whose vertical biases no stillness taught:
a mean lags a drift of rate ``r`` by ``r·tau``) it is the weighted least-squares line
through them, ``δ`` now and its rate (``rate_prior``). Where the headings
are the gyroscopes' alone, each segment has first been turned by the drift taken back at
its sensor's rests (``drift``), and the pipeline then turns the whole arm to its sensors'
mean heading (``Pipeline._apply_constraints``).

The running sums and the turn of the segments run in one compiled pass per chunk
(``_constrain``): on a live stream's 10-sample chunks a dozen numpy calls cost far more
than the arithmetic.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from ..jit import compiler


def _line_python(numerator, denominator, moment, second, numerator1, prior, rate_prior):
    """``δ`` now of the weighted least-squares line (``_constrain``); the weighted mean
    alone where ``rate_prior`` is infinite."""
    a11 = denominator + prior
    if math.isinf(rate_prior):
        return numerator / a11
    a22 = second + rate_prior
    return (a22 * numerator - moment * numerator1) / (a11 * a22 - moment * moment)


def _constrain_python(t, Rw, parent, child, u_axis, v_axis, turned, tau, prior, rate_prior,
                      gate, state, delta, taken, knots):
    """For each sample ``n`` of times ``t`` [s] (N,): ``u = Rw[n, parent, :, u_axis]``,
    ``v = Rw[n, child, :, v_axis]`` (world axes of ``Rw`` (N, S, 3, 3)); the heading error
    taken as a line ``δ + r τ_i`` in the samples' ages ``τ_i = t_i − t`` [s] (``r``
    [rad/s]: how fast the two sensors' headings drift apart, the difference of their
    gyroscopes' vertical biases the filters have not learnt), fitted by least squares to
    every sample's ``u·v + D (δ + r τ_i) = 0`` weighed by ``w = D² Δt`` decayed by
    ``exp(−Δt/τ)``: the running sums ``Σ w δ_i`` and ``Σ w`` (numerator, denominator,
    ``δ_i = −u·v / D``), ``Σ w τ``, ``Σ w τ²`` and ``Σ w δ_i τ``, with priors toward no
    correction (``prior`` on δ [s·rad²], ``rate_prior`` on ``r`` [s³·rad²]; infinite: no
    rate, the weighted mean alone, ``_line``); ``delta[n]`` the correction [rad], ``δ``
    now; then each ``Rw[n, s]``, ``s`` in ``turned`` (int array), turned about the
    world's vertical by it. A sample whose residual after the correction so far,
    ``|u·v + D δ|``, exceeds ``gate`` breaks the joint by more than a heading drift does
    and counts for nothing.

    ``taken[n]`` [rad] (N, 2) is how far the child's (column 0) and the parent's (1)
    headings have been turned before the joint (the drift taken back at each sensor's
    rests), ``knots[n]`` [s] (N, 2) the time of the rest from which each one's drift not
    yet taken back counts (NaN: none). A step of ``taken`` takes back drift that came
    between that knot and now: a remembered sample seen a fraction ``f`` of the way
    through that gap had seen about ``f`` of it (the drift grows with the time moved), so
    its estimate turns by ``f`` of the step (``numerator −= step · Σ w f``, the sum kept
    per side as ``Σ w (t − knot)`` over the samples since the knot, and likewise
    ``Σ w δ τ −= step · Σ w f τ`` from ``Σ w (t − knot)²``); one seen before the
    knot had seen none of it and holds, and the step passes to the output as far as the
    joint has not seen it. ``state`` (15,): 0–1 the sums, 2 the last time [s], 3 1.0 once
    there is one, 4–5 the last ``taken``, 6–7 ``Σ w (t − knot)`` per side, 8–9 their
    knots, 10 ``Σ w τ``, 11 ``Σ w τ²``, 12 ``Σ w δ τ`` (ages from the last time), 13–14
    ``Σ w (t − knot)²`` per side."""
    numerator, denominator = state[0], state[1]
    moment, second, numerator1 = state[10], state[11], state[12]
    if state[3] == 0.0 and t.shape[0]:
        state[2] = t[0]
        for j in range(2):
            state[4 + j] = taken[0, j]
            state[6 + j] = 0.0
            state[8 + j] = knots[0, j]
            state[13 + j] = 0.0
    t_prev = state[2]
    last_dt, decay = math.nan, 1.0
    for n in range(t.shape[0]):
        moved = t[n] - t_prev
        dt = moved
        if dt != last_dt:  # a steady rate's interval repeats: so does its decay
            last_dt, decay = dt, math.exp(-dt / tau)  # per second: whatever the rate
        for j in range(2):
            knot = knots[n, j]
            if knot != state[8 + j] and not (math.isnan(knot) and math.isnan(state[8 + j])):
                state[8 + j] = knot  # a new gap: no sample has seen its drift yet
                state[6 + j] = 0.0
                state[13 + j] = 0.0
            step = taken[n, j] - state[4 + j]
            state[4 + j] = taken[n, j]
            if step != 0.0 and t[n] > knot:  # (NaN: False)
                signed = step if j == 0 else -step
                numerator -= signed * state[6 + j] / (t[n] - knot)
                # Σ w f τ, the ages still from the last time
                numerator1 -= signed * (state[13 + j] - (t_prev - knot) * state[6 + j]) \
                    / (t[n] - knot)
        t_prev = t[n]
        ux, uy, uz = Rw[n, parent, 0, u_axis], Rw[n, parent, 1, u_axis], Rw[n, parent, 2, u_axis]
        vx, vy, vz = Rw[n, child, 0, v_axis], Rw[n, child, 1, v_axis], Rw[n, child, 2, v_axis]
        d = uy * vx - ux * vy
        uv = ux * vx + uy * vy + uz * vz
        estimate = _line(numerator, denominator, moment, second, numerator1, prior,
                         rate_prior)
        if abs(uv + d * estimate) > gate:
            dt = 0.0
        # every remembered sample is ``moved`` older (τ_i → τ_i − moved), then decayed;
        # this sample's age is 0
        second = decay * (second - 2.0 * moved * moment + moved * moved * denominator)
        moment = decay * (moment - moved * denominator)
        numerator1 = decay * (numerator1 - moved * numerator)
        numerator = decay * numerator - uv * d * dt
        denominator = decay * denominator + d * d * dt
        for j in range(2):
            state[6 + j] *= decay
            state[13 + j] *= decay
            if t[n] > state[8 + j]:  # (NaN: False)
                since = t[n] - state[8 + j]
                state[6 + j] += d * d * dt * since
                state[13 + j] += d * d * dt * since * since
        # the priors pull toward no correction until the joint has been seen bent a while
        correction = _line(numerator, denominator, moment, second, numerator1, prior,
                           rate_prior)
        delta[n] = correction
        c, s = math.cos(correction), math.sin(correction)
        for segment in turned:
            for k in range(3):  # Rz(δ) · R: rows 0 and 1 turn, row 2 stays
                r0, r1 = Rw[n, segment, 0, k], Rw[n, segment, 1, k]
                Rw[n, segment, 0, k] = c * r0 - s * r1
                Rw[n, segment, 1, k] = s * r0 + c * r1
    if t.shape[0]:
        state[0], state[1], state[2], state[3] = numerator, denominator, t_prev, 1.0
        state[10], state[11], state[12] = moment, second, numerator1


def _turned_python(t, gyr, times, state, out):
    """The angle a sensor has turned [rad], ``∫|ω| dt`` over its samples (``t`` [s] (N,),
    ``gyr`` [rad/s] (N, 3)) up to each of ``times`` [s] (M,), written to ``out`` (M,);
    ``state[0]`` is the angle up to ``t[0]`` and becomes the angle up to the last sample
    at or before ``times[-1]`` (a pipeline's next chunk starts at that sample)."""
    total = state[0]
    i = 0
    for k in range(times.shape[0]):
        while i + 1 < t.shape[0] and t[i + 1] <= times[k]:
            i += 1
            total += (t[i] - t[i - 1]) * math.sqrt(gyr[i, 0] * gyr[i, 0] + gyr[i, 1] * gyr[i, 1]
                                                   + gyr[i, 2] * gyr[i, 2])
        out[k] = total
    state[0] = total


def _mean_turn_python(Rw, chain, offsets, turned, floor):
    """Turn the segments ``chain`` (int array, k) of ``Rw`` (N, S, 3, 3) about the world's
    vertical to the weighted mean of their sensors' own headings, in place: segment
    ``chain[j]`` has its own heading at the chain's minus ``offsets[j, n]`` [rad] ((k, N));
    weights ``1 / (floor + turned[j, n])`` with ``turned`` (k, N) the angle each sensor
    has turned [rad]."""
    if offsets.shape[0] != chain.shape[0] or turned.shape[0] != chain.shape[0]:
        raise ValueError("mean_turn: one row of offsets and of turned per chain segment")
    for n in range(Rw.shape[0]):
        total = 0.0
        shift = 0.0
        for j in range(chain.shape[0]):
            weight = 1.0 / (floor + turned[j, n])
            total += weight
            shift += weight * offsets[j, n]
        angle = -shift / total
        c, s = math.cos(angle), math.sin(angle)
        for segment in chain:
            for k in range(3):
                r0, r1 = Rw[n, segment, 0, k], Rw[n, segment, 1, k]
                Rw[n, segment, 0, k] = c * r0 - s * r1
                Rw[n, segment, 1, k] = s * r0 + c * r1


def _compile(function):
    jit = compiler(nogil=True)
    return jit(function) if jit else function


#: Length of ``_constrain``'s state.
CONSTRAIN_STATE_SIZE = 15
#: ``HeadingConstraint.rate_prior`` where two sensors' headings drift apart [s³·rad²]:
#: ``prior · tau²`` (0.05 · 20²), the same weight on the turn the rate makes over the
#: forgetting time as on the turn itself.
DRIFT_RATE_PRIOR = 20.0
_line = _compile(_line_python)
_constrain = _compile(_constrain_python)
mean_turn = _compile(_mean_turn_python)
turned_angle = _compile(_turned_python)


@functools.cache
def _segments(turned: tuple[int, ...]) -> np.ndarray:
    """``turned`` as the kernel's int64 array (one per tuple: a chunk's call builds none;
    never written)."""
    return np.array(turned, dtype=np.int64)


@dataclass
class HeadingConstraint:
    """Running estimate of a distal segment's heading error [rad] from a 2-DoF joint."""

    #: Forgetting time constant [s].
    tau: float = 20.0
    #: Weight of "no correction" [s·rad²]: as much as 0.2 s with the joint bent 30°.
    prior: float = 0.05
    #: Weight of "no drift" of the heading error [s³·rad²] (``_constrain``'s ``r``);
    #: infinite: none is fitted, the weighted mean alone (``DRIFT_RATE_PRIOR``: fitted).
    rate_prior: float = math.inf
    #: Largest residual a sample may show and count (``_constrain``): infinite between
    #: two sensors; against a virtual upper arm (a forearm-only kit) a few degrees, so the
    #: calibration's T-pose and any raise of the arm, which break the assumption, not
    #: the hinge, are left out.
    gate: float = math.inf
    #: The running sums, the last time, what was taken back (see ``_constrain``).
    _state: np.ndarray = field(default_factory=lambda: np.zeros(CONSTRAIN_STATE_SIZE),
                               init=False)
    #: Nothing taken back (zeros, NaN knots), rows for the longest chunk so far: the
    #: kernel reads only a chunk's rows, so a live stream's chunks share one pair.
    _none: tuple[np.ndarray, np.ndarray] = field(
        default_factory=lambda: (np.zeros((0, 2)), np.zeros((0, 2))), init=False)

    def apply(self, t: np.ndarray, Rw: np.ndarray, parent: int, child: int, u_axis: int,
              v_axis: int, turned: tuple[int, ...], taken: np.ndarray | None = None,
              knots: np.ndarray | None = None) -> np.ndarray:
        """Turn the segments ``turned`` of ``Rw`` (N, S, 3, 3) ``R_world_segment`` about the
        vertical, in place, by the heading correction of joint ``parent``–``child`` at times
        ``t`` [s] (N,): ``u`` is the parent's column ``u_axis``, ``v`` the child's column
        ``v_axis``; ``taken`` [rad] (N, 2) the child's and the parent's headings already
        turned by the drift taken back, ``knots`` [s] (N, 2) the times its gaps count from
        (``_constrain``; None: none). Returns the turn [rad] (N,)."""
        n = len(t)
        delta = np.empty(n)
        if taken is None or knots is None:
            if len(self._none[0]) < n:
                self._none = np.zeros((n, 2)), np.full((n, 2), np.nan)
            taken, knots = self._none
        _constrain(np.ascontiguousarray(t, dtype=np.float64), Rw, parent, child, u_axis,
                   v_axis, _segments(turned), self.tau, self.prior,
                   self.rate_prior, self.gate, self._state, delta,
                   np.ascontiguousarray(taken, dtype=np.float64),
                   np.ascontiguousarray(knots, dtype=np.float64))
        return delta

    def update(self, t: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Heading correction δ [rad] (N,) at times ``t`` [s] from the joint's axes ``u``,
        ``v`` (N, 3) in the world."""
        n = len(t)
        axes = np.empty((n, 2, 3, 1))
        axes[:, 0, :, 0], axes[:, 1, :, 0] = u, v
        delta = np.empty(n)
        _constrain(np.ascontiguousarray(t, dtype=np.float64), axes, 0, 1, 0, 0,
                   np.zeros(0, dtype=np.int64), self.tau, self.prior, self.rate_prior,
                   self.gate, self._state, delta, np.zeros((n, 2)), np.full((n, 2), np.nan))
        return delta
