"""Secrets: therapists' passwords (argon2id, memory-hard) and bearer tokens (random,
stored only as their SHA-256, so a copy of the database reveals no usable token)."""

from __future__ import annotations

import functools
import hashlib
import secrets

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError

#: The account ``armtrack demo`` makes; it signs in only in demo mode.
DEMO_USER = "demo"

_hasher = PasswordHasher()


@functools.cache
def _dummy_hash() -> str:
    """A hash to verify against when the user does not exist, so both cases take as long
    (made on first use: hashing takes ~0.1 s, which `armtrack create-user` need not pay)."""
    return _hasher.hash("armtrack-no-such-user")


def hash_password(password: str) -> str:
    return _hasher.hash(password)


def verify_password(password: str, password_hash: str | None) -> bool:
    """True when ``password`` matches; a missing user costs the same time as a wrong one."""
    try:
        return (_hasher.verify(password_hash or _dummy_hash(), password)
                and password_hash is not None)
    except (VerificationError, InvalidHashError):
        return False


def new_token(prefix: str) -> tuple[str, str]:
    """A fresh bearer token (``prefix`` + 256 random bits, URL-safe) and its stored hash."""
    token = prefix + secrets.token_urlsafe(32)
    return token, hash_token(token)


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8", "surrogatepass")).hexdigest()
