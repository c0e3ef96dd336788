"""Does a recording's body (side, height, lengths) match a patient's record?

One check for every place a file meets a patient: the upload dialog and the import of
vendor files (which carry no side or height: the patient's are used and nothing differs),
and the therapist's review of uploaded recordings. Messages are for the person uploading.
"""

from __future__ import annotations

import math

#: Heights closer than this [m] are the same (a header rounded to the centimetre).
HEIGHT_TOLERANCE_M = 0.015


def body_mismatch(patient_side: str, patient_height_m: float | None, side: str | None,
                  height_m: float | None = None, has_lengths: bool = False) -> list[str]:
    """Sentences naming each way a file's side and height differ from the patient's record
    (empty when they agree, or when the file says nothing). ``has_lengths``: the file gives
    measured segment lengths, which win over any height."""
    problems = []
    if side and patient_side and side != patient_side:
        problems.append(f"the file records the {side} arm; {patient_side} is the patient's "
                        "treated arm on record")
    if (height_m is not None and patient_height_m is not None and not has_lengths
            and math.isfinite(height_m)
            and abs(height_m - patient_height_m) > HEIGHT_TOLERANCE_M):
        problems.append(f"the file's body height is {height_m:.2f} m; the patient's record "
                        f"says {patient_height_m:.2f} m (segment lengths follow the height)")
    return problems


def recording_mismatch(recording, patient_side: str, patient_height_m: float | None
                       ) -> list[str]:
    """:func:`body_mismatch` of a :class:`~armtrack.estimator.recording.Recording`."""
    return body_mismatch(patient_side, patient_height_m, recording.side, recording.height_m,
                         recording.lengths is not None)
