"""A discharged patient's kits (docs/extensions/discharge.md): they start no new session,
streamed or uploaded, until the therapist readmits the patient. What was recorded stays,
and a stream already under way goes on (its session was started in care)."""

from __future__ import annotations

from ..db import models

#: Why a discharged patient's kit starts no session: for the patient, on their phone.
DISCHARGED = ("this patient was discharged by the therapist: this kit starts no new "
              "session. What it recorded is kept; ask your therapist to readmit you to "
              "record again")


def refusal(patient: models.Patient) -> str | None:
    """Why ``patient``'s kit may not start a new session now, or None (in care)."""
    return DISCHARGED if patient.discharged_at is not None else None
