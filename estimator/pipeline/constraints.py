"""Joint constraints that keep a 6-axis kit's headings tied together over a long session.

Without a magnetometer each sensor's heading drifts on its own. The elbow and the wrist
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
no correction, causal, so chunks give what the whole recording gives.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Samples per block of the vectorised running sum (keeps exp() of relative times small).
_BLOCK = 2048


@dataclass
class HeadingConstraint:
    """Running estimate of a distal segment's heading error [rad] from a 2-DoF joint."""

    #: Forgetting time constant [s].
    tau: float = 20.0
    #: Weight of "no correction" [s·rad²]: as much as 0.2 s with the joint bent 30°.
    prior: float = 0.05
    _numerator: float = field(default=0.0, init=False)
    _denominator: float = field(default=0.0, init=False)
    _t_last: float | None = field(default=None, init=False)

    def update(self, t: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Heading correction δ [rad] (N,) at times ``t`` [s] from the joint's axes ``u``,
        ``v`` (N, 3) in the world."""
        if len(t) == 0:
            return np.zeros(0)
        D = u[:, 1] * v[:, 0] - u[:, 0] * v[:, 1]
        # weights are per second, so the estimate does not depend on the sample rate
        previous = self._t_last if self._t_last is not None else t[0]
        dt = np.diff(t, prepend=previous)
        numerator = self._running(t, -np.sum(u * v, axis=1) * D * dt, "_numerator")
        denominator = self._running(t, D * D * dt, "_denominator")
        self._t_last = float(t[-1])
        # the prior pulls toward no correction until the joint has been seen bent a while
        return numerator / (denominator + self.prior)

    def _running(self, t: np.ndarray, x: np.ndarray, name: str) -> np.ndarray:
        """S_k = e^{-(t_k - t_{k-1})/τ} S_{k-1} + x_k, vectorised in blocks."""
        out = np.empty_like(x)
        carry = getattr(self, name)
        t_prev = self._t_last if self._t_last is not None else (t[0] if len(t) else 0.0)
        for a in range(0, len(t), _BLOCK):
            tb, xb = t[a:a + _BLOCK], x[a:a + _BLOCK]
            rel = (tb - tb[0]) / self.tau
            decay_in = np.exp(-(tb[0] - t_prev) / self.tau)
            sums = np.cumsum(xb * np.exp(rel))
            out[a:a + _BLOCK] = np.exp(-rel) * (carry * decay_in + sums)
            carry, t_prev = out[a + len(tb) - 1], tb[-1]
        setattr(self, name, float(carry))
        return out
