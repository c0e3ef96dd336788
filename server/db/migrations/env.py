"""Alembic environment: runs on the engine handed over in ``config.attributes``.

An upgrade is one transaction: all of it or nothing (a disk full or a kill half-way leaves
the database as it was, and the next start migrates it from there). PostgreSQL's DDL is
transactional as alembic runs it; on SQLite, whose DDL is transactional too, the driver
opens a transaction only before DML, so the upgrade opens it itself (``BEGIN IMMEDIATE``,
holding the write lock from the start, so a server writing meanwhile is waited for); without,
each table made or rebuilt was committed at once, and a migration cut short left tables
that the next start failed to make again ("table programs already exists").

On SQLite, foreign keys are off while migrations run: a migration that rebuilds a table
(copy, drop, rename) must not have the drop cascade into the rows that refer to it. They
are checked once the migrations are through, before the commit (``PRAGMA
foreign_key_check``)."""

from alembic import context
from armtrack.server.db.models import Base

config = context.config
engine = config.attributes["engine"]

with engine.connect() as connection:
    sqlite = connection.dialect.name == "sqlite"
    if sqlite:  # outside a transaction: SQLite ignores this pragma inside one
        connection.exec_driver_sql("PRAGMA foreign_keys=OFF")
        connection.commit()
        # alembic sees a transaction of ours and runs in it. IMMEDIATE: the write lock is
        # taken first, so another program's writes are waited for (busy timeout); a plain
        # BEGIN read the schema first and, had another committed since, SQLite refused the
        # first write at once ("database is locked": WAL cannot move a read forward)
        connection.exec_driver_sql("BEGIN IMMEDIATE")
    try:
        context.configure(connection=connection, target_metadata=Base.metadata,
                          render_as_batch=sqlite)
        with context.begin_transaction():
            context.run_migrations()
        if sqlite:
            broken = connection.exec_driver_sql("PRAGMA foreign_key_check").fetchall()
            if broken:
                raise RuntimeError(f"the migration left rows whose references are gone: "
                                   f"{broken[:10]}")
        connection.commit()
    finally:
        if sqlite:
            connection.rollback()
            connection.exec_driver_sql("PRAGMA foreign_keys=ON")
            connection.commit()
