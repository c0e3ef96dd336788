"""A kit's memory of its sensors' gyroscope biases on the server (docs/gyro-bias-memory.md).

A kit's session starts from the biases the kit remembers (``session_prior``, a copy kept
with the session, so its live estimates, its estimation after it closes and any later
reprocessing all start from the same); once the session is estimated the biases its
stillness taught replace the kit's older ones (``remember_session``); a removed kit's
memory is forgotten (``forget_kit``)."""

from __future__ import annotations

from typing import Any

from armtrack.estimator.errors import InvalidArgument
from armtrack.estimator.orientation import LearntGyroBias
from armtrack.estimator.pipeline.bias_memory import (
    RememberedBias,
    memory_from_json,
    memory_to_json,
    priors,
)
from sqlalchemy import delete, select, update
from sqlalchemy.orm import Session as DbSession

from .. import clock
from ..db import models


def kit_memory(db: DbSession, device_id: int) -> dict[str, RememberedBias]:
    """The kit's remembered biases by sensor name."""
    rows = db.scalars(select(models.KitGyroBias)
                      .where(models.KitGyroBias.device_id == device_id))
    return {row.sensor: RememberedBias((row.bias_x, row.bias_y, row.bias_z), row.learnt,
                                       row.still_s, row.age_s) for row in rows}


def session_prior(db: DbSession, device_id: int | None) -> dict[str, Any] | None:
    """What a new session of the kit keeps as its ``gyro_bias_prior``: the kit's memory
    as docs/gyro-bias-memory.md's JSON, or None (no kit, or nothing remembered)."""
    if device_id is None:
        return None
    memory = kit_memory(db, device_id)
    return memory_to_json(memory) if memory else None


def session_priors(session: models.Session) -> dict[str, tuple[float, float, float]] | None:
    """The biases the session's filters start from (``Pipeline``'s ``gyr_bias_priors``),
    or None. A stored prior the reader refuses (it was written by this code) is ignored
    rather than failing the session."""
    if not session.gyro_bias_prior:
        return None
    try:
        return priors(memory_from_json(session.gyro_bias_prior)) or None
    except InvalidArgument:
        return None


def session_priors_by_id(db: DbSession, session_id: int
                         ) -> dict[str, tuple[float, float, float]] | None:
    session = db.get(models.Session, session_id)
    return None if session is None else session_priors(session)


def remember_session(db: DbSession, session: models.Session,
                     learnt: dict[str, LearntGyroBias]) -> None:
    """The biases the session's stillness taught replace the kit's memory of those sensors,
    unless a later session of the kit taught one already (not committed). Sessions without
    a kit (uploads), a removed kit and untaught biases change nothing. Safe beside another
    session of the kit remembered at once (another instance, ``armtrack reprocess``): each
    sensor's row is created if missing (nothing if it exists) and then replaced in one
    statement only where it was begun no later, so no commit fails and the later-begun
    session's bias stays whichever commits last."""
    if session.device_id is None or not learnt:
        return
    device = db.get(models.Device, session.device_id)
    if device is None or device.revoked_at is not None:
        return
    table = models.KitGyroBias.__table__
    insert = _insert_ignoring_existing(db)
    for sensor, value in learnt.items():
        if not value.remembered:
            continue
        values = dict(bias_x=value.bias[0], bias_y=value.bias[1], bias_z=value.bias[2],
                      learnt=value.learnt, still_s=value.still_s, age_s=value.age_s,
                      session_id=session.id, session_started_at=session.started_at,
                      updated_at=clock.now())
        db.execute(insert(table).values(device_id=device.id, sensor=sensor, **values)
                   .on_conflict_do_nothing(index_elements=["device_id", "sensor"]))
        db.execute(update(table).where(
            table.c.device_id == device.id, table.c.sensor == sensor,
            table.c.session_started_at <= session.started_at).values(**values))


def _insert_ignoring_existing(db: DbSession):
    """The dialect's ``insert`` (with ``on_conflict_do_nothing``): SQLite or PostgreSQL."""
    if db.get_bind().dialect.name == "postgresql":
        from sqlalchemy.dialects.postgresql import insert
    else:
        from sqlalchemy.dialects.sqlite import insert
    return insert


def forget_kit(db: DbSession, device_id: int) -> None:
    """Forget a kit's remembered biases (not committed)."""
    db.execute(delete(models.KitGyroBias).where(models.KitGyroBias.device_id == device_id))
