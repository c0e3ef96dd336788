"""Two sessions of one kit estimated at once (two server instances' processing, or
``armtrack reprocess`` beside the server) both remember the biases their stillness taught
(``store.gyro_bias.remember_session``): neither commit may fail — a failure would throw
away a good session's estimates — and the kit keeps the later-begun session's biases
whichever commits last. Real SQLite file, migrations, two database sessions interleaved."""
from __future__ import annotations

import contextlib
import threading
from datetime import UTC, datetime, timedelta

from armtrack.estimator.orientation import LearntGyroBias
from armtrack.server.db import models
from armtrack.server.db.engine import make_engine, make_sessionmaker
from armtrack.server.db.migrate import upgrade
from armtrack.server.store.gyro_bias import kit_memory, remember_session
from server_support import add_patient


def learnt(bx: float) -> dict[str, LearntGyroBias]:
    return {"forearm": LearntGyroBias((bx, 0.002, -0.001), "rest", 5.0, 30.0, False)}


def test_two_sessions_of_a_kit_remembered_at_once(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'k.db'}")
    upgrade(engine)
    factory = make_sessionmaker(engine)
    start = datetime(2026, 12, 1, 9, 0, tzinfo=UTC)
    with factory() as db:
        patient = add_patient(db, "p", None)
        device = models.Device(patient_id=patient.id, name="kit", token_hash="h")
        db.add(device)
        db.flush()
        ids = []
        for k in range(2):  # the earlier-begun first
            session = models.Session(patient_id=patient.id, device_id=device.id,
                                     source="stream", status="closed", side="right",
                                     height_m=1.7, rate_hz=100, sensors={}, meta={},
                                     started_at=start + timedelta(hours=k))
            db.add(session)
            db.flush()
            ids.append(session.id)
        device_id = device.id
        db.commit()
    earlier, later = ids
    # each reads the kit's memory (empty) and waits (up to 3 s) for the other to have done
    # so before it commits: the later-begun session first, the earlier one after it
    met = threading.Barrier(2)
    first_done = threading.Event()
    errors: list[BaseException] = []

    def remember(session_id: int, bx: float, after: threading.Event | None) -> None:
        try:
            if after is not None:
                after.wait(10)
            with factory() as db:
                remember_session(db, db.get(models.Session, session_id), learnt(bx))
                if after is None:
                    first_done.set()
                with contextlib.suppress(threading.BrokenBarrierError):
                    met.wait(3)
                db.commit()  # the second raised IntegrityError (UNIQUE device_id, sensor)
        except BaseException as exc:
            errors.append(exc)
            first_done.set()

    threads = [threading.Thread(target=remember, args=(later, 0.003, None)),
               threading.Thread(target=remember, args=(earlier, 0.001, first_done))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    assert not errors, errors
    with factory() as db:
        memory = kit_memory(db, device_id)
    print(f"kit memory after both: forearm {memory['forearm'].bias}")
    assert memory["forearm"].bias[0] == 0.003  # the later-begun session's, not the last commit's
