"""Signing in: the OAuth2 password flow gives a therapist an opaque bearer token. Failed
sign-ins slow the user name and the client address down (429 with ``Retry-After``,
``security.LoginLimiter``; the client's address comes from ``X-Forwarded-For`` only behind
a proxy in ``ARMTRACK_TRUSTED_PROXIES``); a disabled account and, outside demo mode, the
demo account cannot sign in; signing out ends the sign-in on the server. A therapist
changes their password (old and new); an admin-issued one-time reset token sets a new one."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from datetime import UTC, datetime, timedelta
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Request, status
from fastapi.security import OAuth2PasswordRequestForm
from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy import delete, select, update
from sqlalchemy.orm import Session as DbSession

from .. import audit
from ..auth import hash_password, hash_token, new_token, verify_password
from ..db import models
from ..plain_text import Secret
from ..security import LoginLimiter, login_keys
from ..services import PasswordsBusy, Services
from .deps import DEMO_USER, Db, Therapist, aware_utc, oauth2, services, unauthorized
from .schemas import TokenOut

router = APIRouter(prefix="/api/auth", tags=["auth"])

MIN_PASSWORD = 8
WRONG = "wrong user name or password"


class PasswordChange(BaseModel):
    model_config = ConfigDict(extra="forbid")
    old_password: Secret = Field(max_length=1000)
    new_password: Secret = Field(min_length=MIN_PASSWORD, max_length=1000)


#: Why no reset code is made for an admin (``POST /api/admin/therapists/{id}/reset``), nor
#: used on one (a code made before that rule), and what to do instead.
ADMIN_RESET_REFUSED = (
    "account {} is a clinic admin: no admin makes a reset code for an admin (its holder "
    "would act in their name). An admin changes their password on their account page; "
    "one who forgot it is given a new admin account on the server (armtrack create-user "
    "NAME --admin), and this one is disabled")


class PasswordReset(BaseModel):
    model_config = ConfigDict(extra="forbid")
    new_password: Secret = Field(min_length=MIN_PASSWORD, max_length=1000)


def limiter(request: Request) -> LoginLimiter:
    state = request.app.state
    if not hasattr(state, "login_limiter"):
        settings = state.services.settings
        state.login_limiter = LoginLimiter(settings.login_max_failures, settings.login_window_s,
                                           settings.login_max_delay_s)
    return state.login_limiter


def _too_many(wait: int) -> HTTPException:
    return HTTPException(status.HTTP_429_TOO_MANY_REQUESTS,
                         f"too many failed sign-ins: try again in {wait} s",
                         headers={"Retry-After": str(wait)})


#: Seconds a caller answered ``_busy`` waits before trying again (Retry-After) [s].
BUSY_RETRY_S = 5


def _busy() -> HTTPException:
    return HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE,
                         "the server is busy with many sign-ins at once: try again in "
                         f"{BUSY_RETRY_S} s", headers={"Retry-After": str(BUSY_RETRY_S)})


async def _new_hash(svc: Services, password: str) -> str:
    """``password``'s argon2id hash, on the password pool (503 when it is full)."""
    try:
        return await svc.run_password(hash_password, password)
    except PasswordsBusy:
        raise _busy() from None


def _client(request: Request) -> str | None:
    return request.client.host if request.client else None


async def _guess(request: Request, svc: Services, keys: list[str], password: str,
                 stored_hash: Callable[[], Awaitable[str | None]]) -> bool:
    """Whether ``password`` matches the hash ``stored_hash()`` gives (None: no such
    account), as a guess the sign-in limiter counts (``keys``): 429 while they must wait,
    the attempt counted as a failure until checked; 503 when the password pool is full
    (nothing counted). argon2id (64 MiB, ~0.1 s) runs on the password pool: two at once,
    however many are sent."""
    limits = limiter(request)
    if (wait := limits.reserve(keys)) is not None:
        raise _too_many(wait)
    right: bool | None = False
    try:
        found = await stored_hash()
        try:
            right = await svc.run_password(verify_password, password, found)
        except PasswordsBusy:
            right = None  # no password checked: no failure counted
            raise _busy() from None
    finally:
        limits.settle(keys, right)
    return bool(right)


@router.post("/token", response_model=TokenOut, responses={
    401: {"description": WRONG}, 403: {"description": "the account is disabled"},
    429: {"description": "too many failed sign-ins (see Retry-After)"},
    503: {"description": "too many password checks under way (see Retry-After)"}})
async def sign_in(form: Annotated[OAuth2PasswordRequestForm, Depends()],
                  svc: Annotated[Services, Depends(services)], request: Request) -> TokenOut:
    """A bearer token for a therapist's user name and password."""
    account: models.Therapist | None = None

    async def stored_hash() -> str | None:
        nonlocal account
        account = await svc.run_db(_account, form.username, svc.settings.demo_mode)
        return account.password_hash if account else None
    if not await _guess(request, svc, login_keys(form.username, _client(request)),
                        form.password, stored_hash):
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, WRONG,
                            headers={"WWW-Authenticate": "Bearer"})
    therapist = account
    assert therapist is not None
    if therapist.disabled_at is not None:
        raise HTTPException(status.HTTP_403_FORBIDDEN,
                            "this account is disabled: ask your clinic's admin")
    lifetime = timedelta(hours=svc.settings.access_token_hours)
    token, digest = new_token("at_")

    def store(db: DbSession) -> None:
        now = datetime.now(UTC)
        db.execute(delete(models.AccessToken).where(
            models.AccessToken.therapist_id == therapist.id, models.AccessToken.expires_at < now))
        db.add(models.AccessToken(therapist_id=therapist.id, token_hash=digest,
                                  expires_at=now + lifetime))
        db.commit()

    await svc.run_db(store)
    return TokenOut(access_token=token, expires_in=int(lifetime.total_seconds()))


@router.post("/signout", status_code=status.HTTP_204_NO_CONTENT, responses={
    401: {"description": "the token is unknown or has already ended"}})
async def sign_out(therapist: Therapist, token: Annotated[str | None, Depends(oauth2)],
                   svc: Annotated[Services, Depends(services)]) -> None:
    """End this sign-in (the bearer token given): it stops working at once, and the live
    feeds and 3D views opened with it close (4401). The account's other sign-ins stay."""
    def work(db: DbSession) -> None:
        db.execute(delete(models.AccessToken).where(
            models.AccessToken.therapist_id == therapist.id,
            models.AccessToken.token_hash == hash_token(token or "")))
        db.commit()

    await svc.run_db(work)
    await svc.access.recheck()


def _account(db: DbSession, username: str, demo_mode: bool) -> models.Therapist | None:
    """The account of a user name (the demo's only in demo mode: it exists for `armtrack
    demo`), detached from ``db``."""
    therapist = db.scalar(select(models.Therapist).where(models.Therapist.username == username))
    if therapist is None or (therapist.username == DEMO_USER and not demo_mode):
        return None
    db.expunge(therapist)
    return therapist


@router.post("/password", status_code=status.HTTP_204_NO_CONTENT, responses={
    400: {"description": "the old password is wrong"},
    429: {"description": "too many wrong old passwords"},
    503: {"description": "too many password checks under way (see Retry-After)"}})
async def change_password(body: PasswordChange, therapist: Therapist, request: Request,
                          token: Annotated[str | None, Depends(oauth2)],
                          svc: Annotated[Services, Depends(services)]) -> None:
    """Change your password (the old one, then the new one, at least 8 characters). Your
    other sign-ins end, with their live feeds and 3D views, and so does a reset code not
    used yet; this sign-in stays."""
    async def stored_hash() -> str:
        return therapist.password_hash
    right = await _guess(request, svc, login_keys(therapist.username, _client(request)),
                         body.old_password, stored_hash)
    if not right:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, "the old password is wrong")
    password_hash = await _new_hash(svc, body.new_password)

    def work(db: DbSession) -> None:
        db.execute(update(models.Therapist).where(models.Therapist.id == therapist.id)
                   .values(password_hash=password_hash))
        db.execute(delete(models.AccessToken).where(
            models.AccessToken.therapist_id == therapist.id,
            models.AccessToken.token_hash != hash_token(token or "")))
        # an unused reset code ends too: its holder would set the password after them
        db.execute(delete(models.PasswordReset).where(
            models.PasswordReset.therapist_id == therapist.id,
            models.PasswordReset.used_at.is_(None)))
        audit.record(db, action="changed_password", route="POST /api/auth/password",
                     therapist_id=therapist.id, client=_client(request), commit=False)
        db.commit()

    await svc.run_db(work)
    await svc.access.recheck()


def reset_grant(db: Db, token: Annotated[str | None, Depends(oauth2)]
                ) -> models.PasswordReset:
    """The valid, unused reset of the bearer reset token."""
    row = db.scalar(select(models.PasswordReset).where(
        models.PasswordReset.token_hash == hash_token(token))) if token else None
    if row is None or row.used_at is not None \
            or aware_utc(row.expires_at) <= datetime.now(UTC):
        raise unauthorized("the reset token is unknown, used or expired: ask your admin")
    return row


@router.post("/reset", status_code=status.HTTP_204_NO_CONTENT, responses={
    401: {"description": "the reset token is missing, unknown, used or expired"},
    403: {"description": "the account is disabled, or a clinic admin's (a code made before "
                        "no admin could make one for an admin sets nothing)"},
    503: {"description": "too many password checks under way (see Retry-After)"}})
async def reset_password(body: PasswordReset,
                         row: Annotated[models.PasswordReset, Depends(reset_grant)],
                         svc: Annotated[Services, Depends(services)],
                         request: Request) -> None:
    """Set a new password with the one-time reset token a clinic admin issued, given as
    the bearer token (``Authorization: Bearer rt_…``). Every sign-in of the account ends,
    with its live feeds and 3D views."""
    password_hash = await _new_hash(svc, body.new_password)  # before the take

    def work(db: DbSession) -> None:
        account = db.get(models.Therapist, row.therapist_id)
        if account is None or account.disabled_at is not None:
            raise HTTPException(status.HTTP_403_FORBIDDEN,
                                "this account is disabled: ask your clinic's admin")
        if account.is_admin:  # a code made before no admin could make one for an admin
            raise HTTPException(status.HTTP_403_FORBIDDEN,
                                ADMIN_RESET_REFUSED.format(account.id))
        # taken by one request only: the row is marked used where it still is unused, so
        # of requests sent at once (or to two servers) one sets the password
        taken = db.execute(update(models.PasswordReset).where(
            models.PasswordReset.id == row.id, models.PasswordReset.used_at.is_(None))
            .values(used_at=datetime.now(UTC)))
        if taken.rowcount != 1:  # used meanwhile
            db.rollback()
            raise unauthorized("the reset token is unknown, used or expired: ask your admin")
        db.execute(update(models.Therapist).where(models.Therapist.id == row.therapist_id)
                   .values(password_hash=password_hash))
        db.execute(delete(models.AccessToken).where(
            models.AccessToken.therapist_id == row.therapist_id))
        # logged with its address: the account's views from now on are whoever chose it
        audit.record(db, action="reset_password", route="POST /api/auth/reset",
                     therapist_id=row.therapist_id, client=_client(request), commit=False)
        db.commit()

    await svc.run_db(work)
    await svc.access.recheck()
