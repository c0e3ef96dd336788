"""``armtrack reprocess SESSION_ID``: recompute a stored session's estimates with the
current estimator (the session keeps the version and settings they came from)."""

from __future__ import annotations

import argparse
import sys

from .serve import add_database_arguments, settings_from

HELP = "recompute stored sessions' estimates with this estimator"
DESCRIPTION = ("Re-estimates sessions from their stored raw data and records the estimator "
               "version and settings used.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session_ids", type=int, nargs="+", metavar="SESSION_ID")
    parser.add_argument("--filter", default="qcf", help="orientation filter (default qcf)")
    add_database_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from armtrack.estimator.orientation import FILTERS, GYRO_DELAY_FILTERS
    from armtrack.server.db import models
    from armtrack.server.db.migrate import ensure_current, migrated_words
    from armtrack.server.services import Services
    from armtrack.server.store.processing import process_session

    if args.filter not in FILTERS:  # before any session is touched: its estimates stay
        print(f"armtrack reprocess: unknown --filter {args.filter!r}; one of "
              f"{', '.join(sorted(FILTERS))}", file=sys.stderr)
        return 2
    services = Services(settings_from(args))
    failed = 0
    try:
        # the schema only: marking live sessions interrupted is the server's start-up
        # step, and the server may be running with kits streaming
        migrated = ensure_current(services.engine)
        if migrated and (words := migrated_words(*migrated)):
            print(words, flush=True)  # as serve and create-user say it
        for session_id in args.session_ids:
            with services.db() as db:
                session = db.get(models.Session, session_id)
                if session is None:
                    print(f"armtrack reprocess: no session {session_id}", file=sys.stderr)
                    failed += 1
                    continue
                if session.gyro_delay_s and args.filter not in GYRO_DELAY_FILTERS:
                    # the kit's declaration, not the data: the session keeps its estimates
                    print(f"session {session_id}: its kit declared a gyroscope delay "
                          f"(gyro_delay_s {session.gyro_delay_s} s) that --filter "
                          f"{args.filter} cannot take ({', '.join(sorted(GYRO_DELAY_FILTERS))}"
                          " can); its estimates are kept", file=sys.stderr)
                    failed += 1
                    continue
                before = (session.estimator or {}).get("version", "none")
                process_session(db, session_id, args.filter)
                db.refresh(session)
                if session.processing_error:
                    print(f"session {session_id}: {session.processing_error}", file=sys.stderr)
                    failed += 1
                    continue
                print(f"session {session_id}: estimates from {before} → "
                      f"{session.estimator['version']} ({args.filter})")
    finally:
        services.engine.dispose()
    return 2 if failed else 0
