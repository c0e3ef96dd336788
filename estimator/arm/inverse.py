"""Joint angles from segment orientations: the exact inverse of the chain in ``joints.py``.

Each joint's relative rotation ``R_parent_child`` is decomposed in its own axis sequence.
A 2-DoF joint (sternoclavicular, elbow, wrist) gets a 3-angle decomposition whose third
angle is a *residual*: zero for an exact chain, otherwise a measure of how far the two
segments' orientations disagree with the joint (a misaligned sensor, a soft-tissue
artefact). Residuals are returned beside the angles.

The shoulder (``Z·X·Y``) is singular at ±90° abduction, where only
``flexion ∓ rotation`` is determined. Following ``docs/spec/kinematics.md``:

* within ``singular_zone`` of the singularity, flexion is held at its last
  well-determined value and rotation takes the rest. With flexion ``f_h`` held,
  ``M = Rz(-f_h) R_clavicle_humerus = Rx(-abduction) Ry(rotation)`` exactly when the
  true flexion is ``f_h``; then rotation is ``atan2(M[0,2], M[0,0])`` (row 0 of
  ``Rx·Ry`` does not depend on abduction) and abduction is ``-atan2(M[2,1], M[1,1])``,
  which passes 90° continuously;
* outside the zone the decomposition has two branches, ``(f, a, r)`` and
  ``(f + π, π - a, r + π)``; the branch is the one continuous with the angles before
  (at the very start: the one that strays less beyond the AAOS normal ranges, the
  principal one, ``|abduction| ≤ 90°``, on a tie), so abduction goes on past 90°
  instead of flexion and rotation flipping by 180°;
* the shoulder's angles are unwrapped over time, so a motion past ±180° stays
  continuous. The clavicle's, elbow's and wrist's angles stay on the principal branch,
  (−180°, 180°], where every motion those joints can make lies: unwrapped, they would
  carry a whole turn picked up where their chain is singular (the middle angle at ±90°:
  a forearm-only kit's T-pose reads as the elbow turned 90° about X, as its upper arm is
  assumed hanging) into the rest of the session.

``shoulder_elevation`` — the angle between the upper arm's distal axis and the thorax's
inferior axis — has no singularity and is exact throughout.

The only loop is over the runs in and out of the singular zone (a handful per
repetition), never over samples. ``JointAngleSolver.update`` takes chunks and carries
the state, so a stream cut into chunks gives the same angles as the whole recording.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ..body import Side
from ..errors import InvalidArgument, InvalidShape
from ..rotations import angle_between, elemental, mirror_sagittal, tait_bryan_angles
from .forward import check_side
from .joints import ANGLE_NAMES, ELEVATION, JOINTS, NORMAL_RANGE_DEG, SEGMENTS

_TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class JointAngleParams:
    """Parameters of the inverse."""

    #: Half-width of the shoulder's singular zone around ±90° abduction [rad]. Noise in the
    #: humerus orientation is amplified by ``1 / sin(singular_zone)`` in flexion and rotation
    #: just outside the zone (5.8× at 10°); inside it flexion is held.
    singular_zone: float = np.deg2rad(10.0)

    def __post_init__(self) -> None:
        if not (0.0 < self.singular_zone < np.pi / 4):
            raise InvalidArgument(
                f"singular_zone must be in (0, π/4) rad, got {self.singular_zone!r}"
            )


@dataclass(frozen=True)
class JointAngles:
    """Joint angles over time [rad].

    ``angles``: name → ``(N,)`` for the nine angles of ``ANGLE_NAMES`` and
    ``shoulder_elevation``. ``residuals``: ``clavicle_axial``, ``elbow_carrying``,
    ``wrist_twist`` → ``(N,)``, the rotation the 2-DoF joints cannot express.
    """

    angles: dict[str, np.ndarray]
    residuals: dict[str, np.ndarray]

    def degrees(self) -> dict[str, np.ndarray]:
        """The angles in degrees, for reports and CSV."""
        return {name: np.rad2deg(value) for name, value in self.angles.items()}


@dataclass
class _ShoulderState:
    """What the shoulder's continuous decomposition carries from one chunk to the next."""

    last: np.ndarray | None = None  # (3,) flexion, abduction, rotation of the last sample
    branch: int = 0  # 0 principal, 1 the other (abduction past 90°); outside the zone
    in_zone: bool = False


@dataclass
class JointAngleSolver:
    """Streaming inverse kinematics: ``update`` with chunks of segment orientations."""

    side: Side
    params: JointAngleParams = field(default_factory=JointAngleParams)
    _shoulder: _ShoulderState = field(default_factory=_ShoulderState, init=False)

    def __post_init__(self) -> None:
        check_side(self.side)

    def update(self, R_world: Mapping[str, np.ndarray]) -> JointAngles:
        """Joint angles of one chunk.

        ``R_world``: segment name (``thorax``, ``clavicle``, ``upper_arm``, ``forearm``,
        ``hand``) → ``(N, 3, 3)`` rotation ``R_world_segment``. A missing segment moves
        with its parent (its joint stays at 0); a missing thorax is fixed in the world.
        """
        R_parent_child = _relative_rotations(R_world, self.side)
        angles: dict[str, np.ndarray] = {}
        residuals: dict[str, np.ndarray] = {}
        for joint in JOINTS:
            R = R_parent_child[joint.child]
            if joint.name == "shoulder":
                flexion, abduction, rotation = _shoulder_angles(R, self.params, self._shoulder)
                angles.update(shoulder_flexion=flexion, shoulder_abduction=abduction,
                              shoulder_rotation=rotation)
                continue
            values = tait_bryan_angles(R, joint.sequence)
            for name, sign, value in zip(joint.angles, joint.signs, values, strict=True):
                if name is None:
                    residuals[joint.residual] = value
                else:
                    angles[name] = sign * value
        # the others stay on their principal branch (the module's docstring)
        R_thorax_humerus = R_parent_child["clavicle"] @ R_parent_child["upper_arm"]
        down = np.array([0.0, -1.0, 0.0])
        angles[ELEVATION] = angle_between(R_thorax_humerus @ down, down)
        ordered = {name: angles[name] for name in (*ANGLE_NAMES, ELEVATION)}
        return JointAngles(angles=ordered, residuals=residuals)


def joint_angles(
    R_world: Mapping[str, np.ndarray], side: Side, params: JointAngleParams | None = None
) -> JointAngles:
    """Joint angles of a whole recording; the same as one ``JointAngleSolver.update``."""
    return JointAngleSolver(side, params or JointAngleParams()).update(R_world)


def _relative_rotations(R_world: Mapping[str, np.ndarray], side: Side) -> dict[str, np.ndarray]:
    """``R_parent_child`` per child segment, mirrored to the right arm for a left arm."""
    unknown = set(R_world) - set(SEGMENTS)
    if unknown:
        raise InvalidArgument(f"unknown segment(s) {sorted(unknown)}; expected {list(SEGMENTS)}")
    if not R_world:
        raise InvalidArgument("no segment orientations given")
    shapes = {np.shape(R) for R in R_world.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 3 or next(iter(shapes))[1:] != (3, 3):
        raise InvalidShape(f"segment orientations must all be (N, 3, 3), got {sorted(shapes)}")
    n = next(iter(shapes))[0]
    R_of = {"thorax": np.asarray(R_world.get("thorax", np.broadcast_to(np.eye(3), (n, 3, 3))))}
    for joint in JOINTS:
        R_of[joint.child] = np.asarray(R_world.get(joint.child, R_of[joint.parent]), dtype=float)
    identity = np.broadcast_to(np.eye(3), (n, 3, 3))
    relative = {
        j.child: np.swapaxes(R_of[j.parent], -1, -2) @ R_of[j.child] if j.child in R_world
        else identity  # exactly 0 for a joint whose segment has no sensor
        for j in JOINTS
    }
    if side == "left":
        relative = {k: mirror_sagittal(v) for k, v in relative.items()}
    return relative


def _wrap(x: np.ndarray) -> np.ndarray:
    return (x + np.pi) % _TWO_PI - np.pi


def _branches(R: np.ndarray) -> np.ndarray:
    """Both Z·X·Y readings of ``R_clavicle_humerus``: ``(2, N, 3)`` flexion, abduction,
    rotation [rad]; branch 1 is branch 0 with abduction reflected through 90°."""
    a, b, c = tait_bryan_angles(R, "zxy")
    principal = np.stack([a, -b, c], axis=-1)
    abduction = np.where(-b >= 0.0, np.pi + b, -np.pi + b)  # π - a for a ≥ 0, -π - a below
    reflected = np.stack([_wrap(a + np.pi), abduction, _wrap(c + np.pi)], axis=-1)
    return np.stack([principal, reflected])


_SHOULDER_NORMAL = np.deg2rad(
    [NORMAL_RANGE_DEG[f"shoulder_{n}"] for n in ("flexion", "abduction", "rotation")]
)


def _beyond_normal(values: np.ndarray) -> np.ndarray:
    """How far shoulder angles ``(..., 3)`` [rad] stray outside the normal ranges."""
    lo, hi = _SHOULDER_NORMAL[:, 0], _SHOULDER_NORMAL[:, 1]
    return (np.clip(lo - values, 0.0, None) + np.clip(values - hi, 0.0, None)).sum(axis=-1)


def _held_flexion_angles(R: np.ndarray, flexion: float) -> np.ndarray:
    """Abduction and rotation with flexion held at ``flexion`` [rad]: ``(N, 3)``."""
    M = elemental("z", -flexion) @ R
    abduction = -np.arctan2(M[:, 2, 1], M[:, 1, 1])
    rotation = np.arctan2(M[:, 0, 2], M[:, 0, 0])
    return np.stack([np.full_like(abduction, flexion), abduction, rotation], axis=-1)


def _continue_from(values: np.ndarray, previous: np.ndarray | None) -> np.ndarray:
    """``values`` (N, 3) unwrapped over time, continuing ``previous`` (3,)."""
    if previous is None:
        return np.unwrap(values, axis=0)
    return np.unwrap(np.concatenate([previous[None], values]), axis=0)[1:]


def _shoulder_angles(
    R: np.ndarray, params: JointAngleParams, state: _ShoulderState
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flexion, abduction, rotation [rad] of ``R_clavicle_humerus`` (N, 3, 3), continuous
    through the gimbal singularity; ``state`` carries the continuation between chunks."""
    n = R.shape[0]
    out = np.empty((n, 3))
    if n == 0:
        return out[:, 0], out[:, 1], out[:, 2]
    branches = _branches(R)
    # Distance from the singularity: cos of the principal abduction.
    in_zone = np.cos(branches[0, :, 1]) < np.sin(params.singular_zone)
    starts = np.concatenate(([0], np.flatnonzero(np.diff(in_zone)) + 1))
    ends = np.concatenate((starts[1:], [n]))
    for start, end in zip(starts, ends, strict=True):
        zone = bool(in_zone[start])
        if zone:
            held = 0.0 if state.last is None else float(state.last[0])
            values = _held_flexion_angles(R[start:end], held)
        else:
            if state.last is None:
                state.branch = int(np.argmin(_beyond_normal(branches[:, start, :])))
            elif state.in_zone:
                # Leaving the zone: the branch that continues the held angles.
                gap = np.abs(_wrap(branches[:, start, :] - state.last)).sum(axis=-1)
                state.branch = int(np.argmin(gap))
            values = branches[state.branch, start:end]
        values = _continue_from(values, state.last)
        out[start:end] = values
        state.last = values[-1].copy()
        state.in_zone = zone
    return out[:, 0], out[:, 1], out[:, 2]
