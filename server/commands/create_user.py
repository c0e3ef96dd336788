"""``armtrack create-user NAME``: a therapist account (password from ``--password`` or
standard input), in the database the settings point at (migrated first)."""

from __future__ import annotations

import argparse
import getpass
import sys

from .serve import add_arguments as add_server_arguments
from .serve import settings_from

MIN_PASSWORD = 8


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", help="the therapist's user name")
    parser.add_argument("--password", help="the password (default: read from standard input)")
    add_server_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from armtrack.server.auth import hash_password
    from armtrack.server.db import models
    from armtrack.server.services import Services
    from sqlalchemy import select

    password = args.password
    if password is None:
        password = (getpass.getpass("password: ") if sys.stdin.isatty()
                    else sys.stdin.readline().rstrip("\r\n"))
    if len(password) < MIN_PASSWORD:
        print(f"armtrack create-user: the password needs at least {MIN_PASSWORD} characters",
              file=sys.stderr)
        return 2
    services = Services(settings_from(args))
    try:
        services.migrate()
        with services.db() as db:
            if db.scalar(select(models.Therapist).where(models.Therapist.username == args.name)):
                print(f"armtrack create-user: user {args.name!r} exists already",
                      file=sys.stderr)
                return 2
            db.add(models.Therapist(username=args.name, password_hash=hash_password(password)))
            db.commit()
    finally:
        services.engine.dispose()
    print(f"created therapist {args.name!r}")
    return 0
