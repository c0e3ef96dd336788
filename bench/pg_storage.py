"""Benchmark: how the group writer's sample blocks are best written to PostgreSQL. Run
by hand against a throwaway database (``eval "$(.ci/postgres start)"``):
``python bench/pg_storage.py [--url URL] [--blocks 100 400 1600] [--rounds 30]``. Not a
test.

Each round is one group commit as ``server/ingest/writer.py`` makes it: ``--blocks`` sample
blocks (10 rows × 10 float64, zlib-packed as the server packs them: ~0.7 kB of ``bytea``
each; 400 blocks ≈ 130 patients × 3 sensors in one 100 ms batch) in one transaction, with
``synchronous_commit`` on (an acked block is on disk). Ways compared:

* ``executemany``: SQLAlchemy Core ``insert()`` over a list of parameter sets — what the
  writer does on any database (psycopg 3 runs it as a pipeline of prepared statements);
* ``values``: one multi-row ``INSERT … VALUES (…), (…), …`` statement per commit;
* ``copy``: psycopg's ``COPY sample_blocks (…) FROM STDIN`` (binary format).

Prints median and p90 ms per commit and blocks/s for each, on a fresh schema.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np
from armtrack.server.db import models
from armtrack.server.db.engine import make_engine
from armtrack.server.db.migrate import upgrade
from armtrack.server.store.blocks import pack
from sqlalchemy import insert, text

COLUMNS = ("session_id", "sensor", "ordinal", "n_rows", "t_first", "t_last", "data")


def blocks(n: int, start: int, session_id: int) -> list[dict]:
    rng = np.random.default_rng(start)
    out = []
    for i in range(n):
        rows = rng.normal(size=(10, 10))
        rows[:, 0] = (start + i) * 0.1 + np.arange(10) * 0.01
        out.append({"session_id": session_id, "sensor": f"s{i % 3}", "ordinal": start + i,
                    "n_rows": 10, "t_first": float(rows[0, 0]), "t_last": float(rows[-1, 0]),
                    "data": pack(rows)})
    return out


def write_executemany(connection, rows):
    connection.execute(insert(models.SampleBlock.__table__), rows)


def write_values(connection, rows):
    connection.execute(insert(models.SampleBlock.__table__).values(rows))


def write_copy(connection, rows):
    raw = connection.connection.driver_connection  # psycopg.Connection, same transaction
    with raw.cursor() as cursor, cursor.copy(
            f"COPY sample_blocks ({', '.join(COLUMNS)}) FROM STDIN (FORMAT BINARY)") as copy:
        copy.set_types(["int4", "varchar", "int8", "int4", "float8", "float8", "bytea"])
        for r in rows:
            copy.write_row([r[c] for c in COLUMNS])


WAYS = {"executemany": write_executemany, "values": write_values, "copy": write_copy}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--url", default=os.environ.get("ARMTRACK_TEST_POSTGRES_URL"))
    parser.add_argument("--blocks", type=int, nargs="+", default=[100, 400, 1600])
    parser.add_argument("--rounds", type=int, default=30)
    args = parser.parse_args(argv)
    if not args.url:
        parser.error("no --url (or ARMTRACK_TEST_POSTGRES_URL)")
    engine = make_engine(args.url)
    with engine.begin() as connection:
        connection.execute(text("DROP SCHEMA public CASCADE; CREATE SCHEMA public"))
    upgrade(engine)
    with engine.begin() as connection:
        connection.execute(text(
            "INSERT INTO therapists (id, username, password_hash, created_at) "
            "VALUES (1, 'b', 'x', now());"
            "INSERT INTO patients (id, therapist_id, name, side, height_m, created_at) "
            "VALUES (1, 1, 'p', 'right', 1.7, now());"
            "INSERT INTO sessions (id, patient_id, source, status, side, sensors, metadata, "
            "started_at, samples) VALUES (1, 1, 'stream', 'live', 'right', '{}', '{}', "
            "now(), 0)"))
    print(f"{'blocks':>6} {'way':>12} {'median ms':>10} {'p90 ms':>8} {'blocks/s':>9}")
    ordinal = 0
    for n in args.blocks:
        batches = [blocks(n, k * n, 1) for k in range(4)]
        for name, way in WAYS.items():
            times = []
            for r in range(args.rounds):
                rows = [dict(b, ordinal=ordinal + i) for i, b in enumerate(batches[r % 4])]
                ordinal += n
                t0 = time.perf_counter()
                with engine.begin() as connection:
                    way(connection, rows)
                times.append(time.perf_counter() - t0)
            median = statistics.median(times)
            p90 = float(np.percentile(times, 90))
            print(f"{n:>6} {name:>12} {1000 * median:>10.2f} {1000 * p90:>8.2f} "
                  f"{n / median:>9.0f}")
    engine.dispose()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
