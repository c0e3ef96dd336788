"""A stored session's measured angles and assumptions (``docs/extensions/
measured-angles.md``): recorded in the session's metadata when it is made (``coverage``
of its sensors); sessions made before that get the same from their sensors."""

from __future__ import annotations

from typing import Any

from armtrack.estimator.arm.coverage import coverage
from armtrack.estimator.recording.model import GYRO_DELAY_KEY

from ..db import models
from ..text_direction import shown

#: The session metadata keys that hold them (not recording header material).
COVERAGE_KEYS = ("measured_angles", "assumptions")


def session_coverage(session: models.Session) -> dict[str, Any]:
    """``{"measured_angles": [...], "assumptions": {name: sentence}}`` of ``session``."""
    meta = session.meta or {}
    if isinstance(meta.get("measured_angles"), list):
        return {"measured_angles": list(meta["measured_angles"]),
                "assumptions": dict(meta.get("assumptions") or {})}
    return coverage(session.sensors)


def plain_metadata(session: models.Session) -> dict[str, str]:
    """The session's metadata as text (a recording header's), without the coverage keys;
    a direction control kept from before they were refused written out (``shown``)."""
    out = {k: shown(v) for k, v in (session.meta or {}).items()
           if k not in COVERAGE_KEYS and isinstance(v, str) and k != GYRO_DELAY_KEY}
    if session.gyro_delay_s is not None:  # docs/extensions/gyro-delay.md: its own column
        out[GYRO_DELAY_KEY] = repr(float(session.gyro_delay_s))
    return out
