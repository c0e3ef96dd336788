"""OpenSim exports, so a researcher can take a session into OpenSim.

**``.mot``** — joint angles as coordinates of the Rajagopal et al. (2015) full-body model,
in degrees (``inDegrees=yes``), one row per estimate. The model's shoulder is a
ball-and-socket joint turned about the humerus's Z (``arm_flex``), X (``arm_add``) and Y
(``arm_rot``) axes in that order, the same axes and order as ``docs/spec/kinematics.md``'s
shoulder chain, which turns about X by −abduction; so:

=================== ================================ =====================================
coordinate          from                             positive
=================== ================================ =====================================
``arm_flex_<s>``    ``shoulder_flexion``             flexion
``arm_add_<s>``     −``shoulder_abduction``          ADduction
``arm_rot_<s>``     ``shoulder_rotation``            internal rotation
``elbow_flex_<s>``  ``elbow_flexion``                flexion
``pro_sup_<s>``     ``forearm_pronation``            pronation (0: thumb forward)
``wrist_flex_<s>``  ``wrist_flexion``                palmar flexion
``wrist_dev_<s>``   ``wrist_deviation``              ulnar deviation
=================== ================================ =====================================

``<s>`` is ``r`` or ``l``; the contract gives a clinical motion the same sign on both
sides, as the model's coordinates do. Shoulder angles are humerothoracic (the model has no
clavicle coordinates); a trunk sensor's motion is not in the file.

**``.sto``** — segment orientations as an OpenSense orientations file
(``DataType=Quaternion``): one column per segment that has a sensor, named after the
model's body with ``_imu`` (``torso_imu``, ``humerus_r_imu``, ``radius_r_imu``,
``hand_r_imu``), each cell ``w,x,y,z``: the calibrated segment's orientation in the
world (x east, y north, z up), so the "IMU" is aligned with its body. OpenSense's usual
``sensor_to_opensim_rotations`` of (−90°, 0, 0) turns that z-up world into OpenSim's
y-up ground.
"""

from __future__ import annotations

from typing import TextIO

import numpy as np
from armtrack.estimator.sampling import sample_interval_s

from .content import SessionData

#: coordinate stem → (angle, sign)
MOT_COORDINATES = (
    ("arm_flex", "shoulder_flexion", 1.0),
    ("arm_add", "shoulder_abduction", -1.0),
    ("arm_rot", "shoulder_rotation", 1.0),
    ("elbow_flex", "elbow_flexion", 1.0),
    ("pro_sup", "forearm_pronation", 1.0),
    ("wrist_flex", "wrist_flexion", 1.0),
    ("wrist_dev", "wrist_deviation", 1.0),
)
#: segment → (sensor, Rajagopal body stem; ``_r``/``_l`` added where the body is sided)
STO_BODIES = (
    ("thorax", "trunk", "torso", False),
    ("upper_arm", "upper_arm", "humerus", True),
    ("forearm", "forearm", "radius", True),
    ("hand", "hand", "hand", True),
)


def _suffix(side: str) -> str:
    return "r" if side == "right" else "l"


#: Rows formatted by one string format (``_rows``): ~0.3 MB of text a block.
BLOCK_ROWS = 4096


def _rows(out: TextIO, values: np.ndarray, row: str) -> None:
    """Write ``values`` (N, k) to ``out`` with ``row`` (k ``%.6f`` and their separators,
    ending in a newline), ``BLOCK_ROWS`` rows at a time: one ``%`` a block formats in C
    what an f-string a number did in Python (3× faster; the same digits: both round the
    float exactly to 6 decimals)."""
    for start in range(0, len(values), BLOCK_ROWS):
        block = values[start:start + BLOCK_ROWS]
        out.write((row * len(block)) % tuple(block.ravel().tolist()))


def write_mot(out: TextIO, data: SessionData, name: str) -> None:
    """The joint angles as an OpenSim motion file (text), written to ``out`` in blocks
    of rows."""
    s = _suffix(data.session.side)
    columns = ["time", *(f"{stem}_{s}" for stem, _, _ in MOT_COORDINATES)]
    # a kit that measures some angles only (docs/extensions/measured-angles.md): the
    # others keep the spec's 0, as in the angles CSV
    zero = np.zeros_like(data.t)
    values = np.column_stack([data.t, *(sign * data.angles.get(angle, zero)
                                        for _, angle, sign in MOT_COORDINATES)])
    values = values[np.all(np.isfinite(values), axis=1)]
    out.write(f"{name}\nversion=1\nnRows={len(values)}\nnColumns={len(columns)}\n"
              "inDegrees=yes\nendheader\n")
    out.write("\t".join(columns) + "\n")
    _rows(out, values, "\t".join(["%.6f"] * len(columns)) + "\n")


def write_sto(out: TextIO, data: SessionData) -> None:
    """The segments' orientations as an OpenSense quaternion ``.sto`` file (text), written
    to ``out`` in blocks of rows."""
    s = _suffix(data.session.side)
    chosen = [(segment, f"{body}_{s}_imu" if sided else f"{body}_imu")
              for segment, sensor, body, sided in STO_BODIES
              if sensor in data.session.sensors and segment in data.quats]
    quats = [data.quats[segment] for segment, _ in chosen]
    ok = np.isfinite(data.t)
    for q in quats:
        ok &= np.all(np.isfinite(q), axis=1)
    t = data.t[ok]
    step = sample_interval_s(t)
    rate = 1.0 / step if step > 0 else 0.0
    out.write(f"DataRate={rate:.6f}\nDataType=Quaternion\nversion=3\nOpenSimVersion=4.4\n"
              "endheader\n")
    out.write("\t".join(["time", *(column for _, column in chosen)]) + "\n")
    # each row: the time, then one w,x,y,z cell a segment
    _rows(out, np.column_stack([t, *(q[ok] for q in quats)]),
          "%.6f" + "\t%.6f,%.6f,%.6f,%.6f" * len(quats) + "\n")
