"""Whether a patient's kit is sending now, as the dashboard's sensor table judges it: the
rule shared by ``GET /api/patients/{id}/live`` and the 3D view's connection chip, so the
view never says "Connected" while the table says the connection is lost."""

from __future__ import annotations

import time
from typing import Any

#: A sensor with an open socket but no sample for this long [s] shows as not receiving.
STALE_S = 1.0


def stream_receiving(svc: Any, patient_id: int) -> bool | None:
    """Whether the patient's kit is sending now, by the rule of the sensor table (any
    thread; the 3D view's chip asks): True while a sample arrived in the last
    ``STALE_S`` on one of their open streams, False when a stream is open but silent,
    None when no stream of theirs is open on this server."""
    now = time.monotonic()
    try:
        connections = [c for c in list(svc.connections.values())
                       if c.patient_id == patient_id and c.state is not None]
        lasts = [stats["last"] for c in connections
                 for stats in list(c.sensor_stats.values())]
    except RuntimeError:  # changed while read from another thread: ask again later
        return None
    if not connections:
        return None
    return any(now - last <= STALE_S for last in lasts)
