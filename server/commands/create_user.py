"""``armtrack create-user NAME``: a therapist account (password from ``--password``, asked
twice at a terminal, or a line of standard input), in the database the settings point at
(migrated first). ``--admin`` makes a clinic admin; ``--disable`` disables an existing
account (its tokens stop working)."""

from __future__ import annotations

import argparse
import getpass
import sys

from .serve import add_database_arguments, settings_from

MIN_PASSWORD = 8

HELP = "make a therapist account"
DESCRIPTION = ("Creates a therapist who can sign in; the password comes from --password, "
               "else is asked twice at a terminal, else is a line of standard input.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", help="the therapist's user name")
    parser.add_argument("--password", help="the password (default: asked twice at a "
                        "terminal, else read from standard input)")
    parser.add_argument("--full-name", help="the name reports print (\"Dr Jane Doe\")")
    parser.add_argument("--admin", action="store_true",
                        help="a clinic admin (manages therapists, reassigns patients)")
    parser.add_argument("--disable", action="store_true",
                        help="disable the existing account NAME instead (no password asked)")
    add_database_arguments(parser)


def _database(args: argparse.Namespace):
    """A session factory on the settings' database, migrated to the newest schema first
    (only when it is behind), and its engine. Just the database: not the server's
    services (viewer, live estimation), which `create-user` does not need and which would
    cost seconds to import."""
    from armtrack.server.db.engine import make_engine, make_sessionmaker
    from armtrack.server.db.migrate import ensure_current, migrated_words

    settings = settings_from(args)
    settings.data_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
    engine = make_engine(settings.resolved_database_url())
    migrated = ensure_current(engine)
    if migrated and (words := migrated_words(*migrated)):
        print(words, flush=True)  # an upgrade is said wherever it happens, as serve says it
    return make_sessionmaker(engine), engine


def run(args: argparse.Namespace) -> int:
    from armtrack.server.auth import hash_password
    from armtrack.server.db import models
    from sqlalchemy import select

    if args.disable:
        return _disable(args)
    password = args.password
    if password is None and sys.stdin.isatty():
        # typed unseen: asked twice, so a slip of the finger makes no account whose
        # password nobody knows; Ctrl-D (or Ctrl-C) at the prompt creates nothing
        try:
            password = getpass.getpass("password: ")
            again = getpass.getpass("the same password again: ")
        except (EOFError, KeyboardInterrupt):
            print("\narmtrack create-user: no password given: no account was created",
                  file=sys.stderr)
            return 2
        if password != again:
            print("armtrack create-user: the two passwords differ: no account was created; "
                  "run it again", file=sys.stderr)
            return 2
    elif password is None:
        password = sys.stdin.readline().rstrip("\r\n")
    if len(password) < MIN_PASSWORD:
        print(f"armtrack create-user: the password needs at least {MIN_PASSWORD} characters",
              file=sys.stderr)
        return 2
    sessions, engine = _database(args)
    try:
        with sessions() as db:
            existing = db.scalar(select(models.Therapist)
                                 .where(models.Therapist.username == args.name))
            if existing is not None:
                way = ("It is disabled: a clinic admin enables it again on the Clinic "
                       "accounts page (/admin)" if existing.disabled_at is not None
                       else _new_password_words(existing.is_admin))
                print(f"armtrack create-user: user {args.name!r} exists already; nothing was "
                      f"changed. {way}", file=sys.stderr)
                return 2
            therapist = models.Therapist(username=args.name,
                                         password_hash=hash_password(password),
                                         is_admin=args.admin, full_name=args.full_name or None)
            db.add(therapist)
            db.flush()
            _logged(db, "created_account",
                    f"{args.name}{' --admin' if args.admin else ''}", therapist.id)
            db.commit()
    finally:
        engine.dispose()
    print(f"created {'clinic admin' if args.admin else 'therapist'} {args.name!r}")
    return 0


def _logged(db, action: str, arguments: str, account: int) -> None:
    """An account made or disabled here, in the audit log (not committed), as an admin's
    change on the Clinic accounts page is: the command, the account, and who ran it (the
    operating-system user, in the address's place; no account acted). Before, none was
    written (att19)."""
    import getpass

    from armtrack.server import audit
    try:
        user = getpass.getuser()
    except (KeyError, OSError):  # no name for the process's uid (a bare container)
        user = "unknown"
    audit.record(db, action=action,
                 route=f"{audit.CREATE_USER} {arguments} (account {account})",
                 client=f"{user} (operating-system user)", commit=False)


def _new_password_words(is_admin: bool) -> str:
    """How an existing account gets a new password (create-user sets none): found by an
    IT person rotating a therapist's password, whom "exists already" left without a way."""
    own = "its holder changes it signed in, on their account page (/account)"
    if is_admin:
        return (f"A new password: {own}; a clinic admin who forgot theirs is given a new "
                "admin account (armtrack create-user NEW_NAME --admin) and this one is "
                "disabled (--disable) (docs/security.md)")
    return (f"A new password: {own}, or a clinic admin makes a one-time reset code on the "
            "Clinic accounts page (/admin), which the therapist enters under \"I have a "
            "reset code\" on the sign-in page (docs/operator.md, Accounts)")


def _disable(args: argparse.Namespace) -> int:
    from datetime import UTC, datetime

    from armtrack.server.db import models
    from sqlalchemy import delete, select

    sessions, engine = _database(args)
    try:
        with sessions() as db:
            therapist = db.scalar(select(models.Therapist)
                                  .where(models.Therapist.username == args.name))
            if therapist is None:
                print(f"armtrack create-user: no user {args.name!r}", file=sys.stderr)
                return 2
            therapist.disabled_at = therapist.disabled_at or datetime.now(UTC)
            db.execute(delete(models.AccessToken)
                       .where(models.AccessToken.therapist_id == therapist.id))
            db.execute(delete(models.PasswordReset).where(  # unused reset codes end too
                models.PasswordReset.therapist_id == therapist.id,
                models.PasswordReset.used_at.is_(None)))
            _logged(db, "disabled_account", f"{args.name} --disable", therapist.id)
            db.commit()
    finally:
        engine.dispose()
    print(f"disabled {args.name!r}")
    return 0
