"""``armtrack demo``: everything on one machine in one command. Starts the server under
uvicorn on the embedded defaults (SQLite in ``./armtrack-demo``), makes a demo therapist
(``demo``, a fresh password printed each run), a demo patient and a sensor kit, then
streams a simulated patient through the real ingest protocol (``KitEmulator``, real
time): calibration poses, then one exercise, one session per exercise, in a loop.
Ctrl-C stops it cleanly."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import secrets
import sys
import time
from pathlib import Path

#: The exercises streamed, one session each, in this order (then again).
DEMO_EXERCISES = ("elbow_flexion", "shoulder_abduction", "shoulder_flexion", "pronation",
                  "wrist_flexion", "reach")
DEMO_USER = "demo"
DEMO_PATIENT = "Demo Patient"
HELP = "run the server with a simulated patient streaming exercises"
DESCRIPTION = ("Starts the server (SQLite in ./armtrack-demo), makes a demo therapist (user "
               "demo, a password printed each run), a patient and a kit, and streams a "
               "simulated patient (calibration poses, then exercises in a loop) through the "
               "real protocol in real time. Prints the address and the sign-in; Ctrl-C stops.")
#: Pause between two sessions [s].
PAUSE_S = 5.0
#: Most sessions the demo keeps, the one streaming included (two rounds of the default
#: exercises, ~12 minutes, some 15 MB): before each new session the oldest closed ones are
#: erased to make room, so a demo left running for days never holds more than this.
KEEP_SESSIONS = 12
#: How often the demo kit reports battery and signal [s].
STATUS_EVERY_S = 5.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default=None,
                        help="address to listen on (ARMTRACK_HOST, default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=None,
                        help="port (ARMTRACK_PORT, default 8000)")
    parser.add_argument("--data-dir", type=Path, default=None,
                        help="folder for the demo database (default ./armtrack-demo)")
    parser.add_argument("--exercises", default=",".join(DEMO_EXERCISES), metavar="A,B,…",
                        help="exercises to stream in a loop (default %(default)s)")
    parser.add_argument("--speed", type=float, default=1.0,
                        help="playback speed of the simulated patient (default 1: real time)")
    parser.add_argument("--once", action="store_true",
                        help="stream each exercise once, then keep serving")
    parser.add_argument("--keep", type=int, default=KEEP_SESSIONS, metavar="N",
                        help="sessions kept; older ones are erased (default %(default)s)")


def _settings(args: argparse.Namespace):
    import os

    from armtrack.server.settings import Settings

    given: dict = {"data_dir": args.data_dir or Path(os.environ.get("ARMTRACK_DATA_DIR",
                                                                    "armtrack-demo")),
                   "demo_mode": True}  # the demo account signs in only in demo mode
    if args.host:
        given["host"] = args.host
    if args.port is not None:
        given["port"] = args.port
    return Settings(**given)


def _setup(services) -> tuple[str, int, str]:
    """The demo therapist (a new password), patient and kit (a new token; older demo kits
    revoked). Returns (password, patient id, device token)."""
    from datetime import UTC, datetime

    from armtrack.server.auth import hash_password, new_token
    from armtrack.server.db import models
    from armtrack.server.store.gyro_bias import forget_kit
    from sqlalchemy import select

    password = secrets.token_urlsafe(9)
    with services.db() as db, db.begin():
        therapist = db.scalar(select(models.Therapist)
                              .where(models.Therapist.username == DEMO_USER))
        if therapist is None:
            therapist = models.Therapist(username=DEMO_USER, password_hash="")
            db.add(therapist)
            db.flush()
        therapist.password_hash = hash_password(password)
        patient = db.scalar(select(models.Patient).where(
            models.Patient.therapist_id == therapist.id, models.Patient.name == DEMO_PATIENT))
        if patient is None:
            patient = models.Patient(therapist_id=therapist.id, name=DEMO_PATIENT,
                                     side="right", height_m=1.72)
            db.add(patient)
            db.flush()
        for old in db.scalars(select(models.Device).where(
                models.Device.patient_id == patient.id, models.Device.revoked_at.is_(None))):
            old.revoked_at = datetime.now(UTC)
            forget_kit(db, old.id)
        token, digest = new_token("dev_")
        db.add(models.Device(patient_id=patient.id, name="demo kit", token_hash=digest))
        return password, patient.id, token


def _recording(exercise: str, seed: int, side: str, height_m: float):
    """A simulated session of ``exercise`` with its calibration poses and the exercise
    marked (``exercise:<name>`` … ``end:exercise:<name>``)."""
    from armtrack.estimator.recording import Mark
    from armtrack.estimator.simulation import SimulationConfig, simulate
    from armtrack.estimator.simulation.scenarios import EXERCISE_START_S

    config = SimulationConfig(exercise=exercise, side=side, height_m=height_m, seed=seed)
    recording = simulate(config).recording
    end = min(float(s.t[-1]) for s in recording.sensors.values()) - config.tail_s / 2
    marks = (Mark(EXERCISE_START_S - 0.5, f"exercise:{exercise}"),
             Mark(end, f"end:exercise:{exercise}"))
    return dataclasses.replace(recording, marks=marks,
                               metadata={**recording.metadata, "demo": "simulated patient"})


def _demo_kit_class():
    from armtrack.server.emulator import KitEmulator

    class DemoKit(KitEmulator):
        """The emulator, also reporting battery and signal now and then (``status``)."""

        battery = 0.93
        _last_status = 0.0

        async def _send_text(self, ws, text: str) -> None:
            now = time.monotonic()
            hello = text.startswith('{"type":"hello"')  # status may follow ready only
            if not hello and now - self._last_status >= STATUS_EVERY_S:
                self._last_status = now
                DemoKit.battery = max(0.05, DemoKit.battery - 0.002)
                for i, sensor in enumerate(self.hello["sensors"]):
                    await ws.send(f'{{"type":"status","sensor":"{sensor}",'
                                  f'"battery":{DemoKit.battery - 0.04 * i:.3f},'
                                  f'"rssi_dbm":{-52 - 4 * i}}}')
            await super()._send_text(ws, text)

    return DemoKit


def _prune(services, patient_id: int, keep: int) -> list[int]:
    """Erase the demo patient's closed sessions beyond the newest ``keep``; their ids."""
    from armtrack.server.api.erase import erase_session
    from armtrack.server.db import models
    from sqlalchemy import select

    with services.db() as db:
        old = db.scalars(select(models.Session.id)
                         .where(models.Session.patient_id == patient_id)
                         .order_by(models.Session.id.desc()).offset(keep)).all()
        closed = [i for i in old if db.get(models.Session, i).status == "closed"]
        for session_id in closed:
            erase_session(db, session_id)
    return closed


async def _patient_loop(url: str, token: str, exercises: list[str], speed: float,
                        once: bool, side: str, height_m: float,
                        services=None, patient_id: int | None = None,
                        keep: int = KEEP_SESSIONS) -> None:
    import asyncio

    from armtrack.server.emulator import KitError

    kit_class = _demo_kit_class()
    seed = 0
    next_recording = asyncio.create_task(asyncio.to_thread(
        _recording, exercises[0], seed, side, height_m))
    while True:
        for i, exercise in enumerate(exercises):
            recording = await next_recording
            seed += 1
            following = exercises[(i + 1) % len(exercises)]
            next_recording = asyncio.create_task(asyncio.to_thread(
                _recording, following, seed, side, height_m))
            print(f"demo: the simulated patient calibrates (N-pose, T-pose), then does "
                  f"{exercise.replace('_', ' ')} "
                  f"({recording.sensors['forearm'].t[-1] / speed:.0f} s)", flush=True)
            if services is not None:  # room for the session about to stream
                erased = await asyncio.to_thread(_prune, services, patient_id, keep - 1)
                if erased:
                    print(f"demo: erased the oldest session(s) {', '.join(map(str, erased))}"
                          f" (the demo keeps the newest {keep})", flush=True)
            kit = kit_class(recording, url, token, device="demo kit", speed=speed)
            try:
                await kit.run()
            except KitError as exc:
                print(f"demo: the kit stopped: {exc}", file=sys.stderr, flush=True)
                await asyncio.sleep(PAUSE_S)
            await asyncio.sleep(PAUSE_S)
        if once:
            next_recording.cancel()
            print("demo: every exercise streamed once; still serving (Ctrl-C stops)",
                  flush=True)
            return


async def _main(args: argparse.Namespace) -> int:
    import asyncio

    import uvicorn
    from armtrack.server.app import create_app

    settings = _settings(args)
    exercises = [e.strip() for e in args.exercises.split(",") if e.strip()]
    from armtrack.estimator.simulation import EXERCISES
    unknown = [e for e in exercises if e not in EXERCISES]
    if unknown or not exercises:
        print(f"armtrack demo: unknown exercise(s) {', '.join(unknown) or '(none given)'}; "
              f"choose from {', '.join(sorted(EXERCISES))}", file=sys.stderr)
        return 2
    from armtrack.server.listen import CannotListen, bind_socket

    if args.keep < 1:
        print(f"armtrack demo: --keep must be at least 1, got {args.keep}", file=sys.stderr)
        return 2
    try:
        sock = bind_socket(settings.host, settings.port, "demo")
    except CannotListen as exc:
        print(f"armtrack demo: {exc}", file=sys.stderr)
        return 2
    app = create_app(settings)
    server = uvicorn.Server(uvicorn.Config(app, host=settings.host, port=settings.port,
                                           ws_max_size=settings.max_message_bytes,
                                           log_level="warning", proxy_headers=False))
    serving = asyncio.create_task(server.serve(sockets=[sock]))
    while not server.started:
        if serving.done():
            serving.result()
            print("armtrack demo: the server stopped while starting (see the messages "
                  "above)", file=sys.stderr)
            return 3
        await asyncio.sleep(0.05)
    services = app.state.services
    password, patient_id, token = await services.run_db(lambda _db: _setup(services))
    host = "127.0.0.1" if settings.host in ("0.0.0.0", "::") else settings.host
    port = server.servers[0].sockets[0].getsockname()[1] if server.servers else settings.port
    base = f"http://{host}:{port}"
    print(f"""
armtrack demo is running: open {base}/ in a browser
  sign in as   {DEMO_USER}
  password     {password}
  live view    {base}/patients/{patient_id} (then "Open the live view")
  data         {settings.data_dir.resolve()}
A simulated patient ({DEMO_PATIENT}, right arm) streams through the real protocol:
calibration poses first, then {', '.join(e.replace('_', ' ') for e in exercises)}.
Ctrl-C stops.
""", flush=True)
    patient = asyncio.create_task(_patient_loop(
        f"ws://{host}:{port}/ws/ingest", token, exercises, args.speed, args.once,
        "right", 1.72, services, patient_id, args.keep))
    try:
        await serving  # until Ctrl-C (uvicorn handles the signal)
    finally:
        patient.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await patient
    return 0


def run(args: argparse.Namespace) -> int:
    import asyncio

    from armtrack.server.cpu_threads import one_blas_thread

    one_blas_thread()  # a server too: before numpy's first import (as `serve`)

    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(message)s")
    try:
        code = asyncio.run(_main(args))
    except KeyboardInterrupt:
        code = 0
    if code != 2:
        print("armtrack demo: stopped", flush=True)
    return code
