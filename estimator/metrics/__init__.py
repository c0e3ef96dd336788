"""Clinical metrics of joint-angle series: trajectory errors, range of motion,
repetitions, smoothness and consistency.

Angles in [rad] and times in [s] go in; the range of motion comes out in degrees (a
clinical figure compared with normal values in degrees, ``_deg`` names), repetitions in
radians with ``_deg`` helpers for reports. Modules:

* ``trajectory``  — MAE, maximum error, RMSE (seed paper eq. 17), NaN-aware;
* ``rom``         — range of motion against AAOS and the seed paper's Table 2;
* ``rest``        — the rest level a repetition leaves from and returns to;
* ``repetitions`` — counting with hysteresis; start, peak, end, amplitude, velocity;
* ``smoothness``  — SPARC and LDLJ (Balasubramanian et al.);
* ``consistency`` — coefficients of variation across repetitions;
* ``timebase``, ``velocity`` — windows, even grids, low-pass and angular velocity.
"""

from .consistency import Consistency, coefficient_of_variation, consistency
from .repetitions import (
    BOTH_WAYS,
    Repetition,
    RepetitionParams,
    count_repetitions,
    detect_repetitions,
    repetitions_by_angle,
)
from .rom import (
    CALIBRATION_TAIL_S,
    RangeOfMotion,
    RomParams,
    calibration_exclusion,
    percent_of,
    range_of_motion,
    range_of_motion_table,
    rom_report,
)
from .smoothness import (
    Phase,
    Smoothness,
    SmoothnessParams,
    angle_smoothness,
    angular_speed_profile,
    ldlj,
    repetition_smoothness,
    sparc,
)
from .timebase import Windows
from .trajectory import TrajectoryErrors, position_errors, series_errors

__all__ = [
    "BOTH_WAYS", "CALIBRATION_TAIL_S", "Consistency", "Phase", "RangeOfMotion", "Repetition",
    "RepetitionParams", "RomParams", "Smoothness", "SmoothnessParams", "TrajectoryErrors",
    "Windows", "angle_smoothness", "angular_speed_profile", "calibration_exclusion",
    "coefficient_of_variation", "consistency", "count_repetitions", "detect_repetitions",
    "ldlj", "percent_of", "position_errors", "range_of_motion", "range_of_motion_table",
    "repetition_smoothness", "repetitions_by_angle", "rom_report", "series_errors", "sparc",
]
