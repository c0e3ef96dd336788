"""Joint angles and forward kinematics one sample at a time, compiled: the same numbers as
``inverse.JointAngleSolver`` followed by ``forward.forward_kinematics`` (to 1e-9), at a
fraction of their cost on the small chunks of a live stream.

Input: the joints' relative rotations ``R_parent_child`` (N, 4, 3, 3) in chain order
(clavicle, upper arm, forearm, hand), already mirrored to the right arm for a left arm
(``inverse._relative_rotations``). Output per sample: the nine angles and
``shoulder_elevation`` [rad] (N, 10), the three residuals [rad] (N, 3), positions of
shoulder, elbow, wrist, hand [m] in the thorax frame (N, 4, 3) and ``R_thorax_segment``
of clavicle … hand (N, 4, 3, 3), both for the arm's own side.

State (float64, ``STATE_SIZE``): ``[0:3]`` last shoulder flexion, abduction, rotation ·
``[3]`` has a last · ``[4]`` branch · ``[5]`` last sample in the singular zone ·
``[6:12]`` last clavicle protraction, elevation, elbow flexion, pronation,
wrist flexion, deviation · ``[12]`` have those.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import compiler

STATE_SIZE = 13
#: Samples per block of a chunk's relative rotations (``_chunk_python``).
_BLOCK = 1024
_TWO_PI = 2.0 * math.pi


def _kernel_python(rel, side_sign, lengths, zone_sin, normal, state, angles, residuals,
                   positions, R_thorax):
    """``side_sign`` +1 right, −1 left; ``lengths`` (4,) clavicle, upper arm, forearm, hand
    [m]; ``normal`` (3, 2) shoulder flexion/abduction/rotation normal ranges [rad]."""
    pi = math.pi
    for n in range(rel.shape[0]):
        # -- sternoclavicular: Y·X·Z (eps −1): protraction, −elevation, axial residual
        R = rel[n, 0]
        prot, elev_neg, axial = _tait_bryan(R, 1, 0, 2, -1.0)
        # -- elbow: Z·X·Y (eps +1): flexion, carrying residual, pronation
        R = rel[n, 2]
        ef, carrying, pron = _tait_bryan(R, 2, 0, 1, 1.0)
        # -- wrist: X·Z·Y (eps −1): flexion, −deviation, twist residual
        R = rel[n, 3]
        wf, dev_neg, twist = _tait_bryan(R, 0, 2, 1, -1.0)
        others = (prot, -elev_neg, ef, pron, wf, -dev_neg)
        for i in range(6):  # on the principal branch (inverse.py's docstring)
            v = others[i]
            state[6 + i] = v
            angles[n, (0, 1, 5, 6, 7, 8)[i]] = v
        state[12] = 1.0
        residuals[n, 0], residuals[n, 1], residuals[n, 2] = axial, carrying, twist

        # -- shoulder: Z·X·Y with its singular zone and branches (inverse.py)
        R = rel[n, 1]
        a, b, c = _tait_bryan(R, 2, 0, 1, 1.0)
        p0, p1, p2 = a, -b, c
        r1 = -pi + b
        if -b >= 0.0:
            r1 = pi + b
        q0, q1, q2 = _wrap(a + pi), r1, _wrap(c + pi)
        in_zone = math.cos(p1) < zone_sin
        if in_zone:
            held = state[0] if state[3] != 0.0 else 0.0
            ch, sh = math.cos(held), math.sin(held)
            # M = Rz(−held) R
            m00 = ch * R[0, 0] + sh * R[1, 0]
            m02 = ch * R[0, 2] + sh * R[1, 2]
            m11 = -sh * R[0, 1] + ch * R[1, 1]
            m21 = R[2, 1]
            v0, v1, v2 = held, -math.atan2(m21, m11), math.atan2(m02, m00)
        else:
            if state[3] == 0.0:
                cost0 = _beyond(p0, p1, p2, normal)
                cost1 = _beyond(q0, q1, q2, normal)
                state[4] = 1.0 if cost1 < cost0 else 0.0
            elif state[5] != 0.0:
                gap0 = (abs(_wrap(p0 - state[0])) + abs(_wrap(p1 - state[1]))
                        + abs(_wrap(p2 - state[2])))
                gap1 = (abs(_wrap(q0 - state[0])) + abs(_wrap(q1 - state[1]))
                        + abs(_wrap(q2 - state[2])))
                state[4] = 1.0 if gap1 < gap0 else 0.0
            if state[4] == 0.0:
                v0, v1, v2 = p0, p1, p2
            else:
                v0, v1, v2 = q0, q1, q2
        if state[3] != 0.0:
            v0 = _continue(state[0], v0)
            v1 = _continue(state[1], v1)
            v2 = _continue(state[2], v2)
        state[0], state[1], state[2], state[3] = v0, v1, v2, 1.0
        state[5] = 1.0 if in_zone else 0.0
        angles[n, 2], angles[n, 3], angles[n, 4] = v0, v1, v2

        # -- elevation: between the humerus's −Y and the thorax's −Y (R_thorax_humerus)
        C, H = rel[n, 0], rel[n, 1]
        h01 = C[0, 0] * H[0, 1] + C[0, 1] * H[1, 1] + C[0, 2] * H[2, 1]
        h11 = C[1, 0] * H[0, 1] + C[1, 1] * H[1, 1] + C[1, 2] * H[2, 1]
        h21 = C[2, 0] * H[0, 1] + C[2, 1] * H[1, 1] + C[2, 2] * H[2, 1]
        angles[n, 9] = math.atan2(math.sqrt(h01 * h01 + h21 * h21), h11)

        # -- forward kinematics from the angles (right-arm chain, mirrored for a left arm)
        _forward(angles[n], side_sign, lengths, positions[n], R_thorax[n])


def _tait_bryan(R, i, j, k, eps):
    sb = eps * R[i, k]
    cb = math.sqrt(R[i, i] * R[i, i] + R[i, j] * R[i, j])
    b = math.atan2(sb, cb)
    if cb < 1e-12:
        return math.atan2(eps * R[k, j], R[j, j]), b, 0.0
    return math.atan2(-eps * R[j, k], R[k, k]), b, math.atan2(-eps * R[i, j], R[i, i])


def _wrap(x):
    return (x + math.pi) % _TWO_PI - math.pi


def _continue(last, v):
    """``v`` moved by whole turns to within half a turn of ``last`` (as ``np.unwrap``)."""
    d = v - last
    dm = (d + math.pi) % _TWO_PI - math.pi
    if dm == -math.pi and d > 0.0:
        dm = math.pi
    return v + (dm - d)


def _beyond(f, a, r, normal):
    total = 0.0
    values = (f, a, r)
    for i in range(3):
        if values[i] < normal[i, 0]:
            total += normal[i, 0] - values[i]
        elif values[i] > normal[i, 1]:
            total += values[i] - normal[i, 1]
    return total


def _turn_by_elemental(R, axis, angle):
    """``R · E`` into ``R`` (3, 3), ``E`` the elemental rotation about ``axis`` by
    ``angle`` [rad]: each entry the full three-term sum ``Σ R[r, m] E[m, c]``, the zeros'
    products included (the numbers, down to the signs of zeros, of the product with ``E``
    built as a matrix), without building ``E`` or a product matrix per elemental."""
    c, s = math.cos(angle), math.sin(angle)
    if axis == 0:
        e00, e01, e02, e10, e11, e12, e20, e21, e22 = 1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c
    elif axis == 1:
        e00, e01, e02, e10, e11, e12, e20, e21, e22 = c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c
    else:
        e00, e01, e02, e10, e11, e12, e20, e21, e22 = c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0
    for r in range(3):
        a0, a1, a2 = R[r, 0], R[r, 1], R[r, 2]
        R[r, 0] = a0 * e00 + a1 * e10 + a2 * e20
        R[r, 1] = a0 * e01 + a1 * e11 + a2 * e21
        R[r, 2] = a0 * e02 + a1 * e12 + a2 * e22


def _forward(angle, side_sign, lengths, positions, R_out):
    R = np.eye(3)
    # (axis, angle index, sign) of each elemental, chain order (joints.py)
    axes = (1, 0, 2, 0, 1, 2, 1, 0, 2)
    index = (0, 1, 2, 3, 4, 5, 6, 7, 8)
    signs = (1.0, -1.0, 1.0, -1.0, 1.0, 1.0, 1.0, 1.0, -1.0)
    ends = (2, 5, 7, 9)  # elementals that close a segment: clavicle, humerus, forearm, hand
    e = 0
    for seg in range(4):
        while e < ends[seg]:
            _turn_by_elemental(R, axes[e], signs[e] * angle[index[e]])
            e += 1
        for r in range(3):
            for c in range(3):
                R_out[seg, r, c] = R[r, c]
    # positions: shoulder = R_TC (0, 0, l_c); each next point 1 segment length down its −Y
    for k in range(3):
        positions[0, k] = R_out[0, k, 2] * lengths[0]
    for seg in range(1, 4):
        for k in range(3):
            positions[seg, k] = positions[seg - 1, k] - lengths[seg] * R_out[seg, k, 1]
    if side_sign < 0.0:  # the mirror image through the sagittal plane: M R M, p M
        for seg in range(4):
            positions[seg, 2] = -positions[seg, 2]
            R_out[seg, 2, 0] = -R_out[seg, 2, 0]
            R_out[seg, 2, 1] = -R_out[seg, 2, 1]
            R_out[seg, 0, 2] = -R_out[seg, 0, 2]
            R_out[seg, 1, 2] = -R_out[seg, 1, 2]


def _relative_python(Rw, present, side_sign, rel):
    """``R_parent_child`` (N, 4, 3, 3) from ``R_world_segment`` (N, 5, 3, 3) of thorax …
    hand, as ``inverse._relative_rotations``: a missing segment (``present[s] == 0``)
    moves with its parent and its joint is exactly the identity; a missing thorax is the
    identity; mirrored to the right arm when ``side_sign`` < 0."""
    for n in range(Rw.shape[0]):
        parent = 0  # the nearest present proximal segment (0: thorax)
        for s in range(1, 5):
            out = rel[n, s - 1]
            if present[s] == 0:
                for r in range(3):
                    for c in range(3):
                        out[r, c] = 1.0 if r == c else 0.0
                continue
            for r in range(3):
                for c in range(3):
                    if present[parent] == 0:  # the thorax fixed as the identity
                        out[r, c] = Rw[n, s, r, c]
                    else:
                        out[r, c] = (Rw[n, parent, 0, r] * Rw[n, s, 0, c]
                                     + Rw[n, parent, 1, r] * Rw[n, s, 1, c]
                                     + Rw[n, parent, 2, r] * Rw[n, s, 2, c])
            if side_sign < 0.0:
                out[2, 0], out[2, 1] = -out[2, 0], -out[2, 1]
                out[0, 2], out[1, 2] = -out[0, 2], -out[1, 2]
            parent = s


def _to_world_python(Rw, present, R_out):
    """``R_out[:, 1:]`` holds ``R_thorax_segment``; make every entry ``R_world_segment``
    with the thorax of ``Rw`` (the identity when it has no sensor)."""
    for n in range(R_out.shape[0]):
        for s in range(1, 5):
            for c in range(3):
                x, y, z = R_out[n, s, 0, c], R_out[n, s, 1, c], R_out[n, s, 2, c]
                for r in range(3):
                    if present[0] != 0.0:
                        R_out[n, s, r, c] = (Rw[n, 0, r, 0] * x + Rw[n, 0, r, 1] * y
                                             + Rw[n, 0, r, 2] * z)
        for r in range(3):
            for c in range(3):
                if present[0] != 0.0:
                    R_out[n, 0, r, c] = Rw[n, 0, r, c]
                else:
                    R_out[n, 0, r, c] = 1.0 if r == c else 0.0


# The three steps of one chunk, called together so a live poll pays one dispatch. The
# names below are the pure-Python functions, or their compiled twins once numba is in.
_RELATIVE, _KERNEL, _TO_WORLD = _relative_python, _kernel_python, _to_world_python


def _chunk_python(Rw, present, side_sign, lengths, zone_sin, normal, state, rel, angles,
                  residuals, positions, R_out):
    # in blocks of rel's length: a long recording's relative rotations never make one
    # big temporary array (it stays in the cache, and no fresh memory is faulted in)
    block = rel.shape[0]
    for a in range(0, Rw.shape[0], block):
        b = min(a + block, Rw.shape[0])
        _RELATIVE(Rw[a:b], present, side_sign, rel[:b - a])
        _KERNEL(rel[:b - a], side_sign, lengths, zone_sin, normal, state, angles[a:b],
                residuals[a:b], positions[a:b], R_out[a:b, 1:])
        _TO_WORLD(Rw[a:b], present, R_out[a:b])


def _compile():
    jit = compiler(nogil=True)
    if jit is None:  # the pure-Python fallback: same numbers, slower
        return _kernel_python, _relative_python, _to_world_python, _chunk_python, False
    global _tait_bryan, _wrap, _continue, _beyond, _turn_by_elemental, _forward
    _tait_bryan, _wrap, _continue, _beyond = (jit(_tait_bryan), jit(_wrap), jit(_continue),
                                              jit(_beyond))
    _turn_by_elemental = jit(_turn_by_elemental)
    _forward = jit(_forward)
    global _RELATIVE, _KERNEL, _TO_WORLD
    _KERNEL, _RELATIVE, _TO_WORLD = jit(_kernel_python), jit(_relative_python), jit(
        _to_world_python)
    return _KERNEL, _RELATIVE, _TO_WORLD, jit(_chunk_python), True


kernel, relative, to_world, chunk, COMPILED = _compile()


class CompiledJoints:
    """Streaming joint angles and forward kinematics with the compiled kernel: ``update``
    takes chunks of ``R_world_segment`` stacked in ``SEGMENTS`` order."""

    def __init__(self, side: str, lengths, params) -> None:
        from .forward import check_side
        from .joints import NORMAL_RANGE_DEG

        self.side = check_side(side)
        self._side_sign = 1.0 if side == "right" else -1.0
        self._lengths = np.array([lengths.clavicle, lengths.upper_arm, lengths.forearm,
                                  lengths.hand])
        self._zone_sin = math.sin(params.singular_zone)
        self._normal = np.deg2rad([NORMAL_RANGE_DEG[f"shoulder_{n}"]
                                   for n in ("flexion", "abduction", "rotation")])
        self._state = np.zeros(STATE_SIZE)
        self._rel = np.empty((_BLOCK, 4, 3, 3))  # the kernel's work space, see _chunk_python

    def update(self, Rw: np.ndarray, present: np.ndarray):
        """``(angles (N, 10), residuals (N, 3), positions (N, 4, 3), R_world_segment
        (N, 5, 3, 3))`` of a chunk, from ``R_world_segment`` stacked (N, 5, 3, 3) in
        ``SEGMENTS`` order and ``present`` (5,), 1.0 where a segment has a sensor (the
        others are not read). Output segments: thorax as given, the others from the angles;
        see the module docstring for the orders."""
        n = Rw.shape[0]
        angles, residuals = np.empty((n, 10)), np.empty((n, 3))
        positions, R_out = np.empty((n, 4, 3)), np.empty((n, 5, 3, 3))
        chunk(Rw, present, self._side_sign, self._lengths, self._zone_sin, self._normal,
              self._state, self._rel[:max(min(n, _BLOCK), 1)], angles, residuals, positions,
              R_out)
        return angles, residuals, positions, R_out
