"""Whether a 9-axis kit's magnetometers agree on one field, so they may share a heading.

In the earth's field every sensor of a kit sees the same norm and the same dip (the angle
of the field below the horizontal), whatever its orientation. Near metal or electronics
(a steel table, a laptop, a radiator) the field changes from place to place: sensors a
few decimetres apart see different ones, and their "north" differs by tens of degrees
(on the RING chain by up to 60°). Each filter learns its own reference field (norm and
dip, see ``QcfParams``); at calibration the kit's references are compared, and each with the
field the sensor saw in the calibration poses (whose headings set the thorax's). Where
they disagree the magnetometers are left out and the headings come from the calibration and
the joints, as on a 6-axis kit: the magnetometer is evidence, never the arbiter.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..calibration import CalibrationWarning
from ..calibration.quality import place
from .tracks import SensorTrack

#: A sensor's reference norm further than this from the kit's median disagrees (relative;
#: the filter's own tolerance for a disturbed sample, ``QcfParams.mag_norm_tolerance``).
NORM_SPREAD = 0.05
#: A sensor's reference dip further than this from the kit's median disagrees [deg]
#: (``QcfParams.mag_dip_tolerance``).
DIP_SPREAD_DEG = 3.0



def disagreeing_sensors(tracks: Mapping[str, SensorTrack], until: float,
                        poses: Sequence[tuple[float, float]]) -> list[str]:
    """The 9-axis sensors whose reference field (learnt from their samples up to
    ``until`` [s], calibration's final time) departs from the kit's median, or whose
    field during a calibration pose (``poses``: (start, end) [s]) departs from their own
    reference (a kit calibrated beside a laptop: the headings the poses give are off);
    [] when all agree or fewer than two sensors have a reference field."""
    references = {name: track.reference_field(until) for name, track in tracks.items()}
    references = {name: r for name, r in references.items() if r is not None}
    if len(references) < 2:
        return []
    dip_spread = np.deg2rad(DIP_SPREAD_DEG)
    norms = np.array([r[0] for r in references.values()])
    dips = np.array([r[1] for r in references.values()])
    norm_median, dip_median = float(np.median(norms)), float(np.median(dips))
    out = [name for name, (norm, dip, _) in references.items()
           if abs(norm - norm_median) > NORM_SPREAD * norm_median
           or abs(dip - dip_median) > dip_spread]
    if len(references) == 2 and out:  # two that disagree: neither is the odd one out
        out = list(references)
    for name, (norm, dip, _) in references.items():
        for start, end in poses:
            pose = tracks[name].pose_field(start, end)
            if name not in out and pose is not None and (
                    abs(pose[0] - norm) > NORM_SPREAD * norm or abs(pose[1] - dip) > dip_spread):
                out.append(name)
    return out


def disagreement_warning(sensors: list[str], all_sensors: list[str]) -> CalibrationWarning:
    """The warning a therapist can act on when the kit's magnetometers were left out."""
    if len(sensors) == 1:
        where = f"near the {place(sensors[0])} differs from the other sensors'"
    else:
        where = "differs from sensor to sensor"
    return CalibrationWarning(
        "magnetic-field-disturbed", sensors[0] if len(sensors) == 1 else None,
        f"the magnetic field {where} (metal or electronics nearby?); angles use the joints "
        f"and the calibration instead of the magnetometers. Moving away from tables, "
        f"laptops and radiators lets the magnetometers help again next session")
