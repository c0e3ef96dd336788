"""Records the server keeps under a session's metadata (``stopped.py``, ``silence.py``):
a dict of known fields and types. A recording header's values are text, so an upload
cannot forge one; whatever does not match is no record."""

from __future__ import annotations

from typing import Any

from ..db import models


def typed_record(session: models.Session, key: str,
                 fields: dict[str, type]) -> dict[str, Any] | None:
    """The ``fields`` of the record under ``key`` of ``session``'s metadata (a float field
    takes an int too); None when there is none or it does not have them all, typed."""
    record = (session.meta or {}).get(key)
    if not isinstance(record, dict) or any(
            not isinstance(record.get(k), kind if kind is not float else int | float)
            for k, kind in fields.items()):
        return None
    return {k: record[k] for k in fields}
