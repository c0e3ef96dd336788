"""Signing in: the OAuth2 password flow gives a therapist an opaque bearer token."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, status
from fastapi.security import OAuth2PasswordRequestForm
from sqlalchemy import delete, select

from ..auth import new_token, verify_password
from ..db import models
from ..services import Services
from .deps import Db, services
from .schemas import TokenOut

router = APIRouter(prefix="/api/auth", tags=["auth"])


@router.post("/token", response_model=TokenOut)
def sign_in(db: Db, form: Annotated[OAuth2PasswordRequestForm, Depends()],
            svc: Annotated[Services, Depends(services)]) -> TokenOut:
    """A bearer token for a therapist's user name and password."""
    therapist = db.scalar(select(models.Therapist)
                          .where(models.Therapist.username == form.username))
    if not verify_password(form.password, therapist.password_hash if therapist else None):
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "wrong user name or password",
                            headers={"WWW-Authenticate": "Bearer"})
    assert therapist is not None
    now = datetime.now(UTC)
    lifetime = timedelta(hours=svc.settings.access_token_hours)
    token, digest = new_token("at_")
    db.execute(delete(models.AccessToken).where(models.AccessToken.therapist_id == therapist.id,
                                                models.AccessToken.expires_at < now))
    db.add(models.AccessToken(therapist_id=therapist.id, token_hash=digest,
                              expires_at=now + lifetime))
    db.commit()
    return TokenOut(access_token=token, expires_in=int(lifetime.total_seconds()))
