"""Who may still watch: every open live feed (``/ws/live``) and 3D view, with the right it
was opened with — a therapist's sign-in (its token's hash), a patient, and for a replay a
session. A right can be taken away while the feed is open: the patient or session erased,
the patient reassigned, the account disabled, the sign-in ended by a password change or
reset, or expired. ``AccessWatch.recheck`` checks every open feed against the database the
same way it was checked when it opened, and closes those that lost their right at once:
``4401`` when the sign-in no longer holds, ``4404`` when the patient (or session) is no
longer the therapist's. The routes that take a right away call it before they answer; a
periodic check (``ARMTRACK_ACCESS_CHECK_S``) catches the changes made elsewhere (the
command line, another server instance)."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from ..auth import DEMO_USER
from ..db import models
from ..periodic import every

log = logging.getLogger("armtrack.access")

#: Close codes: the sign-in no longer holds; the patient or session is not (any more) theirs.
CLOSE_SIGNED_OUT = 4401
CLOSE_NOT_FOUND = 4404


def no_patient(patient_id: int) -> str:
    """A therapist's words for a patient not among theirs: the same whether it never was,
    was erased or is another therapist's (no oracle), saying what may have happened and
    whom to ask; the pages' 404 and the live sockets' close reason (at most 123 bytes)."""
    return (f"no patient {patient_id} among yours: erased, or reassigned to another "
            "therapist (ask your clinic admin), or a wrong link")


@dataclass(eq=False)
class Watch:
    """One open feed and its right. ``close(code, reason)`` is called once, on the event
    loop, when the right is gone; it must not block."""

    token_hash: str
    therapist_id: int
    patient_id: int
    session_id: int | None
    close: Callable[[int, str], Any] = field(repr=False)


def holds(therapist: models.Therapist, patient: models.Patient | None) -> bool:
    """Whether ``patient`` is ``therapist``'s: theirs, and they are not a clinic admin
    (an admin holds no patients, docs/security.md)."""
    return patient is not None and patient.therapist_id == therapist.id \
        and not therapist.is_admin


def refusals(db: DbSession, watches: Iterable[Watch], demo_mode: bool = False
             ) -> dict[Watch, tuple[int, str]]:
    """The watches whose right no longer holds, each with its close code and reason (a
    few queries for all of them, whatever their number)."""
    watches = list(watches)
    if not watches:
        return {}
    now = datetime.now(UTC)
    # columns, not objects: a session that holds the rows already (a request checking its
    # own right again, ``api.deps.right_held``) would give its stale objects back
    tokens = {row.token_hash: row for row in db.execute(select(
        models.AccessToken.token_hash, models.AccessToken.therapist_id,
        models.AccessToken.expires_at).where(
        models.AccessToken.token_hash.in_({w.token_hash for w in watches})))}
    therapists = {t.id: t for t in db.execute(select(
        models.Therapist.id, models.Therapist.disabled_at, models.Therapist.username,
        models.Therapist.is_admin).where(
        models.Therapist.id.in_({w.therapist_id for w in watches})))}
    owners = dict(db.execute(select(models.Patient.id, models.Patient.therapist_id).where(
        models.Patient.id.in_({w.patient_id for w in watches}))).all())
    session_ids = {w.session_id for w in watches if w.session_id is not None}
    sessions = dict(db.execute(select(models.Session.id, models.Session.patient_id).where(
        models.Session.id.in_(session_ids))).all()) if session_ids else {}
    refused: dict[Watch, tuple[int, str]] = {}
    for watch in watches:
        token = tokens.get(watch.token_hash)
        therapist = therapists.get(watch.therapist_id)
        if token is None or token.therapist_id != watch.therapist_id \
                or _aware(token.expires_at) <= now or therapist is None \
                or therapist.disabled_at is not None \
                or (therapist.username == DEMO_USER and not demo_mode):
            refused[watch] = (CLOSE_SIGNED_OUT, "the sign-in has ended: sign in again")
        elif owners.get(watch.patient_id) != watch.therapist_id or therapist.is_admin:
            refused[watch] = (CLOSE_NOT_FOUND, no_patient(watch.patient_id))
        elif watch.session_id is not None \
                and sessions.get(watch.session_id) != watch.patient_id:
            refused[watch] = (CLOSE_NOT_FOUND, f"no session {watch.session_id}")
    return refused


def _aware(moment: datetime) -> datetime:
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


class AccessWatch:
    """The open feeds of one server process. ``run_db(fn, *args)``: the services'
    database runner (``fn(db, *args)`` off the event loop)."""

    def __init__(self, run_db: Callable[..., Any], demo_mode: bool = False):
        self.run_db = run_db
        self.demo_mode = demo_mode
        self._watches: set[Watch] = set()
        #: rechecks begun so far: a feed opened across one is checked again (``added``)
        self.generation = 0

    def __len__(self) -> int:
        return len(self._watches)

    async def added(self, watch: Watch, checked_at: int) -> None:
        """Register an open feed whose right was checked at generation ``checked_at``;
        if a recheck began since (a right may have gone in between), check it now."""
        self._watches.add(watch)
        if self.generation != checked_at:
            await self._close(await self.run_db(refusals, [watch], self.demo_mode))

    def remove(self, watch: Watch) -> None:
        self._watches.discard(watch)

    async def recheck(self) -> int:
        """Check every open feed; close those that lost their right. Their number."""
        self.generation += 1
        if not self._watches:
            return 0
        refused = await self.run_db(refusals, tuple(self._watches), self.demo_mode)
        await self._close(refused)
        return len(refused)

    async def _close(self, refused: dict[Watch, tuple[int, str]]) -> None:
        for watch, (code, reason) in refused.items():
            if watch in self._watches:
                self._watches.discard(watch)
                log.info("closing a feed of patient %s (%s): %s", watch.patient_id, code,
                         reason)
                watch.close(code, reason)

    async def run(self, every_s: float) -> None:
        """Recheck every ``every_s`` seconds until cancelled."""
        await every(every_s, self.recheck, log=log, failed="access check failed")
