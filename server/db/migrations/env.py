"""Alembic environment: runs on the engine handed over in ``config.attributes``.

On SQLite, foreign keys are off while migrations run: a migration that rebuilds a table
(copy, drop, rename) must not have the drop cascade into the rows that refer to it. They
are checked once the migrations are through (``PRAGMA foreign_key_check``)."""

from alembic import context
from armtrack.server.db.models import Base

config = context.config
engine = config.attributes["engine"]

with engine.connect() as connection:
    sqlite = connection.dialect.name == "sqlite"
    if sqlite:  # outside a transaction: SQLite ignores this pragma inside one
        connection.exec_driver_sql("PRAGMA foreign_keys=OFF")
        connection.commit()
    try:
        context.configure(connection=connection, target_metadata=Base.metadata,
                          render_as_batch=sqlite)
        with context.begin_transaction():
            context.run_migrations()
        connection.commit()
        if sqlite:
            broken = connection.exec_driver_sql("PRAGMA foreign_key_check").fetchall()
            if broken:
                raise RuntimeError(f"the migration left rows whose references are gone: "
                                   f"{broken[:10]}")
    finally:
        if sqlite:
            connection.rollback()
            connection.exec_driver_sql("PRAGMA foreign_keys=ON")
            connection.commit()
