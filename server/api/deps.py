"""What routes depend on: a database session, the signed-in therapist, and ownership
checks (another therapist's patient is 404, as if it did not exist).

A clinic admin manages accounts and holds no patients (docs/security.md): no patient is
ever theirs, whatever the database says, so every patient, session and kit is 404 to them
as to another therapist; they cannot add patients, nor be given one."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import AsyncIterator, Callable, Iterable, Iterator
from datetime import UTC, datetime
from typing import Annotated, Any, TypeVar

from fastapi import Depends, HTTPException, Query, Request, status
from fastapi.security import OAuth2PasswordBearer
from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from .. import audit
from ..auth import DEMO_USER, hash_token
from ..db import models
from ..live.access import CLOSE_SIGNED_OUT, Watch, holds, no_patient, refusals
from ..services import ExportUnwanted, Services
from .spool import SpooledResponse

T = TypeVar("T")

oauth2 = OAuth2PasswordBearer(tokenUrl="/api/auth/token", auto_error=False)


def services(request: Request) -> Services:
    return request.app.state.services


def database(request: Request) -> Iterator[DbSession]:
    with request.app.state.services.db() as db:
        yield db


Db = Annotated[DbSession, Depends(database)]


def unauthorized(detail: str = "sign in first: a valid bearer token is required"
                 ) -> HTTPException:
    return HTTPException(status.HTTP_401_UNAUTHORIZED, detail,
                         headers={"WWW-Authenticate": "Bearer"})


def therapist_of_token(db: DbSession, token: str | None, demo_mode: bool
                       ) -> models.Therapist | None:
    """The therapist of a valid access token: known, unexpired, the account enabled (and
    the demo account only in demo mode); else None."""
    if not token:
        return None
    row = db.scalar(select(models.AccessToken).where(
        models.AccessToken.token_hash == hash_token(token)))
    if row is None or aware_utc(row.expires_at) <= datetime.now(UTC):
        return None
    therapist = db.get(models.Therapist, row.therapist_id)
    if therapist is None or therapist.disabled_at is not None \
            or (therapist.username == DEMO_USER and not demo_mode):
        return None
    return therapist


def current_therapist(db: Db, token: Annotated[str | None, Depends(oauth2)],
                      request: Request) -> models.Therapist:
    if not token:
        raise unauthorized()
    therapist = therapist_of_token(db, token, request.app.state.services.settings.demo_mode)
    if therapist is None:
        raise unauthorized("the token is unknown or has expired: sign in again")
    audit.note(therapist_id=therapist.id)
    return therapist


async def in_export_turn(request: Request, asker: models.Therapist,
                         fn: Callable[..., T], *args: Any) -> T:
    """``fn(db, therapist, *args)``, an export, in its turn (``Services.run_export``),
    with the therapist of the request's token as it is then: a sign-in that ended or an
    account disabled while the export waited is 401, and the ownership ``fn`` checks is
    read then too. A request whose client goes away while it waits is not built. Turns
    are shared fairly among the therapists asking (``asker``: as read when it came).
    A built export is sent for as long as that right holds (``live.access``, as a live
    feed): the patient erased or reassigned, the session erased, the account disabled
    or the sign-in ended while its client reads, the rest is not sent."""
    token = await oauth2(request)
    services = request.app.state.services
    held = services.exports_held
    if held.get(asker.id, 0) >= EXPORTS_HELD:
        raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS,
                            f"this account has {EXPORTS_HELD} exports being made or "
                            "downloaded at once, the most it may: ask again once one has "
                            "finished downloading", headers={"Retry-After": "5"})
    held[asker.id] = held.get(asker.id, 0) + 1

    def release() -> None:
        if (left := held.get(asker.id, 0) - 1) > 0:
            held[asker.id] = left
        else:
            held.pop(asker.id, None)

    checked_at = [services.access.generation]

    def work(db: DbSession) -> T:
        checked_at[0] = services.access.generation  # the rights are read after this
        therapist = current_therapist(db, token, request)
        answer = fn(db, therapist, *args)
        if not isinstance(answer, SpooledResponse):  # sent whole: its right read again now
            right_held(db, token, therapist, services.settings.demo_mode)
        return answer
    try:
        answer = await services.run_export(work, owner=asker.id, gone=_disconnected(request))
    except ExportUnwanted:  # nobody is there to answer
        release()
        raise HTTPException(CLIENT_GONE, "the client went away before its turn") from None
    except BaseException:
        release()
        raise
    if isinstance(answer, SpooledResponse):
        answer.on_end = release  # its file waits on disk until the download ends
        reached = audit.noted()  # the patient (and session) fn read, as own_* noted them
        if reached.get("patient_id") is not None:
            answer.guard = _right_held(services, hash_token(token or ""), asker.id,
                                       reached["patient_id"], reached.get("session_id"),
                                       checked_at[0])
    else:
        release()
    return answer


def _right_held(services: Services, token_hash: str, therapist_id: int, patient_id: int,
                session_id: int | None, checked_at: int):
    """A download's guard (``SpooledResponse.guard``): its right (read at access
    generation ``checked_at``) watched as a live feed's is, ``cut`` called once it is
    gone."""
    @contextlib.asynccontextmanager
    async def guard(cut: Callable[[int, str], None]) -> AsyncIterator[None]:
        watch = Watch(token_hash, therapist_id, patient_id, session_id, cut)
        try:
            await services.access.added(watch, checked_at)
            yield
        finally:
            services.access.remove(watch)
    return guard


def right_held(db: DbSession, token: str | None, therapist: models.Therapist,
               demo_mode: bool) -> None:
    """Read the request's right again, as it answers: the sign-in (``token``) and the
    patient and session its route reached (as ``own_*`` noted them for the audit) checked
    as an open feed's are (``live.access.refusals``). Gone (the sign-in ended, the account
    disabled, the patient erased or reassigned, the session erased while the answer was
    made, which can take seconds): the 401 or 404 a request made now would get. For an
    answer sent whole once made; a download's right is watched while it is sent
    (``_right_held``)."""
    reached = audit.noted()
    if reached.get("patient_id") is None:
        return  # no patient's data reached
    session_id = reached.get("session_id")
    watch = Watch(hash_token(token or ""), therapist.id, reached["patient_id"], session_id,
                  close=lambda code, reason: None)
    refused = refusals(db, [watch], demo_mode).get(watch)
    if refused is None:
        return
    code, reason = refused
    if code == CLOSE_SIGNED_OUT:
        raise unauthorized(reason)
    raise HTTPException(status.HTTP_404_NOT_FOUND,
                        reason if session_id is None else f"no session {session_id}")


class Right:
    """A route's answer made while its right may go (a report, a summary: a build that can
    wait for a place and take seconds): ``right.held(answer)`` gives the answer once the
    right is read again (``right_held``), or raises the 401 or 404."""

    def __init__(self, db: Db, token: Annotated[str | None, Depends(oauth2)],
                 therapist: Annotated[models.Therapist, Depends(current_therapist)],
                 request: Request):
        self.db, self.token, self.therapist = db, token, therapist
        self.demo_mode = request.app.state.services.settings.demo_mode

    def held(self, answer: T) -> T:
        right_held(self.db, self.token, self.therapist, self.demo_mode)
        return answer

    def theirs(self, patient_ids: Iterable[int]) -> set[int]:
        """Of ``patient_ids`` (an answer about several patients, as ``/flags``), those
        still the therapist's now; the sign-in ended meanwhile: its 401."""
        watches = {p: Watch(hash_token(self.token or ""), self.therapist.id, p, None,
                            close=lambda code, reason: None) for p in patient_ids}
        refused = refusals(self.db, watches.values(), self.demo_mode)
        if any(code == CLOSE_SIGNED_OUT for code, _ in refused.values()):
            raise unauthorized("the sign-in has ended: sign in again")
        return {p for p, watch in watches.items() if watch not in refused}


Held = Annotated[Right, Depends()]


#: Exports one account may have being made or downloaded at once (a built one waits for
#: its download in a file of the data folder, for as long as its client holds the
#: connection without reading: twelve angles.csv of a 540k-row session so held were 398 MB,
#: and any number could be asked for: the disk the database lives on filled).
EXPORTS_HELD = 8


#: Status logged for an export nobody waited for (nginx's "client closed request").
CLIENT_GONE = 499


async def _disconnected(request: Request) -> None:
    """Returns once the client of ``request`` (a GET: no body to read) has gone."""
    while (await request.receive())["type"] != "http.disconnect":
        pass


def aware_utc(moment: datetime) -> datetime:
    """SQLite gives naive datetimes back; they were stored in UTC."""
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


Therapist = Annotated[models.Therapist, Depends(current_therapist)]


def current_admin(therapist: Therapist) -> models.Therapist:
    if not therapist.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "only a clinic admin may do this")
    return therapist


Admin = Annotated[models.Therapist, Depends(current_admin)]


class AtOnce:
    """At most ``most`` requests of one account (its id, all its sign-ins together) at
    once in this server process; the next is refused at once (429, ``busy``) rather than
    served too."""

    def __init__(self, most: int):
        self.most = most
        self._held: dict[int, int] = {}
        self._lock = threading.Lock()

    @contextlib.contextmanager
    def turn(self, account: int, busy: str, retry_after_s: int | None = None
             ) -> Iterator[None]:
        """Hold one of ``account``'s places while the block runs, or raise the 429 with
        ``busy`` (and ``Retry-After``: ``retry_after_s`` [s]) when all are held."""
        with self._lock:
            held = self._held.get(account, 0)
            if held >= self.most:
                raise HTTPException(
                    status.HTTP_429_TOO_MANY_REQUESTS, busy,
                    headers=None if retry_after_s is None else {"Retry-After": str(retry_after_s)})
            self._held[account] = held + 1
        try:
            yield
        finally:
            with self._lock:
                if (left := self._held[account] - 1) > 0:
                    self._held[account] = left
                else:
                    del self._held[account]


#: A list asked for with a ``limit`` over this is long (``long_list``).
LONG_LIST = 100
#: One account's long lists of sessions or summaries being made at once, all its sign-ins
#: together, in one server process.
LONG_LISTS_AT_ONCE = 2
_long_lists = AtOnce(LONG_LISTS_AT_ONCE)
LONG_LISTS_BUSY = (f"this account has {LONG_LISTS_AT_ONCE} lists of more than {LONG_LIST} "
                   "rows being made at once, the most it may: ask again in 2 s, or ask for "
                   f"at most {LONG_LIST} rows at a time (limit, offset)")


@contextlib.contextmanager
def long_list(therapist: models.Therapist, limit: int) -> Iterator[None]:
    """Make a list of ``limit`` rows: past ``LONG_LIST`` rows, at most
    ``LONG_LISTS_AT_ONCE`` of one account's at once, the next ``429`` at once. A patient's
    sessions list carries each session's metadata (up to 16,000 characters): 1,000 of
    them are 16.9 MB of JSON, +27-40 MB of the server while made; one account's 30 at once
    took it +892 MB and another therapist's request 8.8 s (att18,
    tests/test_security_long_lists.py)."""
    if limit <= LONG_LIST:
        yield
        return
    with _long_lists.turn(therapist.id, LONG_LISTS_BUSY, retry_after_s=2):
        yield


class Page:
    """``?limit=&offset=`` of a list."""

    def __init__(self, limit: Annotated[int, Query(ge=1, le=1000)] = 100,
                 offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0):
        self.limit = limit
        self.offset = offset


def own_patient(db: DbSession, therapist: models.Therapist, patient_id: int) -> models.Patient:
    patient = db.get(models.Patient, patient_id)
    if not holds(therapist, patient):
        raise HTTPException(status.HTTP_404_NOT_FOUND, no_patient(patient_id))
    audit.note(patient_id=patient.id)
    return patient


def own_session(db: DbSession, therapist: models.Therapist, session_id: int) -> models.Session:
    session = db.get(models.Session, session_id)
    if session is not None:
        patient = db.get(models.Patient, session.patient_id)
        if holds(therapist, patient):
            audit.note(patient_id=patient.id, session_id=session.id)
            return session
    raise HTTPException(status.HTTP_404_NOT_FOUND, f"no session {session_id}")


def own_device(db: DbSession, therapist: models.Therapist, device_id: int) -> models.Device:
    device = db.get(models.Device, device_id)
    if device is not None:
        patient = db.get(models.Patient, device.patient_id)
        if holds(therapist, patient):
            audit.note(patient_id=patient.id)
            return device
    raise HTTPException(status.HTTP_404_NOT_FOUND, f"no device {device_id}")
