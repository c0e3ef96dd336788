"""Live status of a patient's kit, for the dashboard (read-only, polled about twice a
second): the newest live or interrupted session, each sensor's connection (connected,
samples per second, lost-sample rate, last seen, battery and signal from the protocol's
``status`` messages) and the calibration in progress (which pose to hold, whether the
kit is still enough, the verdict on each finished pose with the estimator's own words).

A sensor is ``connected`` while its stream's socket is open and a sample arrived in the
last ``STALE_S`` seconds; a closed socket shows at the next poll, a silent one after
``STALE_S``."""

from __future__ import annotations

import time
from collections import deque
from typing import Annotated, Any
from weakref import WeakKeyDictionary

import numpy as np
from armtrack.estimator.arm.joints import NORMAL_RANGE_DEG
from armtrack.estimator.calibration import pose_stillness_warnings
from armtrack.estimator.calibration.quality import (
    GUIDED_HOLD_MAX_S,
    STILL_ACC_STD,
    STILL_GYR_RMS,
    trunk_hold_guide,
)
from armtrack.estimator.pipeline.calibrate import held_side_lean_sd_deg
from fastapi import APIRouter, Depends
from sqlalchemy import func, select
from sqlalchemy.orm import Session as DbSession

from ..db import models
from ..ingest.writer import SEEN_PREFIX
from ..live.motion import MotionWatch, current_exercise, watch, watching
from ..live.streams import STALE_S
from ..services import Services
from ..store.blocks import SAMPLE_COLUMNS, unpack_many
from ..store.recordings import session_lengths
from ..store.stopped import stopped_by_server
from ..text_direction import shown
from .deps import Therapist, aware_utc, own_patient
from .deps import services as get_services
from .schemas import Id, StoppedByServer

router = APIRouter(prefix="/api", tags=["live"])

#: Window of arrivals for samples per second [s].
RATE_WINDOW_S = 3.0
#: The newest stretch of samples judged for stillness while a pose is held [s].
STILL_WINDOW_S = 1.0
#: Poses the kit marks, and what the person does in each (``docs/spec/kinematics.md``).
POSES = {
    "npose": "Stand tall, arm hanging by your side, elbow straight, palm facing your thigh "
             "(thumb forward). Hold still.",
    "tpose": "Lift the arm straight out to the side to shoulder height, elbow straight, "
             "palm down. Hold still.",
}

# arrival counts per open connection and sensor: (monotonic time, samples so far)
_arrivals: WeakKeyDictionary[Any, dict[str, deque[tuple[float, int]]]] = WeakKeyDictionary()
# finished poses' verdicts: (session id, pose start) → verdict (a finished pose never changes)
_verdicts: dict[tuple[int, float], dict[str, Any]] = {}
# the last arrival seen per (session id, sensor) [wall-clock s], for after a stream ends
_last_seen: dict[tuple[int, str], float] = {}


def _rate(connection: Any, sensor: str, stats: dict[str, Any], now: float) -> float | None:
    history = _arrivals.setdefault(connection, {}).setdefault(sensor, deque())
    history.append((now, int(stats["samples"])))
    while len(history) > 2 and history[0][0] < now - RATE_WINDOW_S:
        history.popleft()
    then, count = history[0]
    if now - then < 0.3:  # first poll: the average since the stream began
        span = stats.get("last", now) - stats.get("first", now)
        return stats["samples"] / span if span > 0.5 else None
    return (stats["samples"] - count) / (now - then)


def block_totals(db: DbSession, session_id: int) -> dict[str, dict[str, float]]:
    """Per sensor: stored rows and the first and last sample time [s]."""
    rows = db.execute(
        select(models.SampleBlock.sensor, func.sum(models.SampleBlock.n_rows),
               func.min(models.SampleBlock.t_first), func.max(models.SampleBlock.t_last))
        .where(models.SampleBlock.session_id == session_id)
        .group_by(models.SampleBlock.sensor)).all()
    return {s: {"samples": int(n), "t_first": float(a), "t_last": float(b)}
            for s, n, a, b in rows}


def lost_fraction(totals: dict[str, float], rate_hz: float | None) -> float | None:
    """Share of samples missing at the nominal rate between the first and last one."""
    if not rate_hz or totals["samples"] < 2:
        return None
    expected = round((totals["t_last"] - totals["t_first"]) * rate_hz) + 1
    return max(0.0, 1.0 - totals["samples"] / expected) if expected > 0 else None


def _samples(db: DbSession, session_id: int, start: float, end: float,
             sensor: str | None = None) -> dict[str, np.ndarray]:
    """Stored rows of each sensor (or ``sensor`` alone) with ``start <= t <= end``."""
    query = (select(models.SampleBlock.sensor, models.SampleBlock.data)
             .where(models.SampleBlock.session_id == session_id,
                    models.SampleBlock.t_last >= start, models.SampleBlock.t_first <= end))
    if sensor is not None:
        query = query.where(models.SampleBlock.sensor == sensor)
    blocks = db.execute(query.order_by(models.SampleBlock.sensor,
                                       models.SampleBlock.ordinal)).all()
    by_sensor: dict[str, list[bytes]] = {}
    for sensor, data in blocks:
        by_sensor.setdefault(sensor, []).append(data)
    out = {}
    for sensor, blobs in by_sensor.items():
        rows = unpack_many(blobs, len(SAMPLE_COLUMNS))
        out[sensor] = rows[(rows[:, 0] >= start) & (rows[:, 0] <= end)]
    return out


def _stillness(rows: dict[str, np.ndarray]) -> dict[str, Any]:
    """How still each sensor is: rotation rms [rad/s] and acceleration spread [m/s²]."""
    sensors = {}
    for sensor, r in rows.items():
        if len(r) < 2:
            continue
        gyr, acc = r[:, 4:7], r[:, 1:4]
        gyr_rms = float(np.sqrt(np.mean(np.sum((gyr - gyr.mean(0)) ** 2, axis=1))))
        acc_std = float(np.sqrt(np.mean(np.sum((acc - acc.mean(0)) ** 2, axis=1))))
        sensors[sensor] = {"rotation_rms": gyr_rms, "acceleration_std": acc_std,
                           "still": gyr_rms <= STILL_GYR_RMS and acc_std <= STILL_ACC_STD}
    return {"still": bool(sensors) and all(s["still"] for s in sensors.values()),
            "sensors": sensors}


def trunk_guide(rows: np.ndarray, start: float, now_t: float) -> dict[str, Any]:
    """The live guide on the trunk through an N-pose held from ``start`` to ``now_t``
    [s]: ``quality.trunk_hold_guide`` of how well the trunk sensor's stored rows
    (``SAMPLE_COLUMNS``) since ``start`` pin its side lean through a sway."""
    rows = rows[(rows[:, 0] >= start) & (rows[:, 0] <= now_t)]
    sd = held_side_lean_sd_deg(rows[:, 0], rows[:, 1:4]) if len(rows) else None
    return trunk_hold_guide(sd, now_t - start)


def _verdict(db: DbSession, session_id: int, name: str, start: float, end: float
             ) -> dict[str, Any]:
    key = (session_id, start)
    if key not in _verdicts:
        rows = _samples(db, session_id, start, end)
        warnings = [w.message for w in pose_stillness_warnings(
            name, {sensor: (r[:, 4:7], r[:, 1:4]) for sensor, r in rows.items()})]
        if not rows:
            warnings.append(f"no samples arrived during the {name}")
        _verdicts[key] = {"still": not warnings, "warnings": warnings}
        if len(_verdicts) > 10000:
            _verdicts.clear()
    return _verdicts[key]


def calibration_progress(db: DbSession, session_id: int, now_t: float | None,
                         streaming: bool = True) -> dict[str, Any]:
    """The session's calibration poses so far: each with its verdict, and the one held
    now (``holding``) with how long and how still, and, an N-pose on a kit with a trunk
    sensor, whether the hold has pinned the trunk's lean yet (``trunk``: ``trunk_guide``).
    ``streaming``: the session is live. When it is not (its stream lost, or stopped by
    the server), a pose whose end mark never came was cut off, not held: ``cut_off`` of
    each pose and ``holding_now`` (null then) say so (``pose-cut-off/1``); ``holding``
    keeps naming the pose whose end has not come, as clients read it before."""
    marks = db.execute(select(models.Mark.t, models.Mark.label)
                       .where(models.Mark.session_id == session_id)
                       .order_by(models.Mark.t, models.Mark.id)).all()
    poses: list[dict[str, Any]] = []
    open_: dict[str, dict[str, Any]] = {}
    exercise = None
    exercise_t = None
    for t, label in marks:
        if label in POSES:
            pose = {"name": label, "start": t, "end": None, "cut_off": False}
            poses.append(pose)
            open_[label] = pose
        elif label.startswith("end:") and label[4:] in open_:
            open_.pop(label[4:])["end"] = t
        elif label.startswith("exercise:"):
            exercise, exercise_t = label.split(":", 1)[1], t
        elif label.startswith("end:exercise:"):
            exercise = exercise_t = None
    holding = None
    for pose in poses:
        if pose["end"] is not None:
            pose.update(_verdict(db, session_id, pose["name"], pose["start"], pose["end"]))
        else:
            pose["held_s"] = max(0.0, (now_t or pose["start"]) - pose["start"])
            if now_t is not None:
                window = _samples(db, session_id, max(pose["start"], now_t - STILL_WINDOW_S),
                                  now_t)
                pose.update(_stillness(window))
                if pose["name"] == "npose":
                    # how well the hold so far pins the trunk's lean through a sway: the
                    # guide asks for a longer hold until it does (GUIDED_HOLD_MAX_S at most)
                    trunk = _samples(db, session_id, max(pose["start"], now_t - 3 *
                                                         GUIDED_HOLD_MAX_S), now_t, "trunk")
                    if "trunk" in trunk:
                        pose["trunk"] = trunk_guide(trunk["trunk"], pose["start"], now_t)
            pose["cut_off"] = not streaming
            holding = pose
    return {"poses": poses, "holding": holding,
            "holding_now": holding if streaming else None,
            "instructions": POSES, "exercise": exercise,
            "exercise_since_s": exercise_t, "stream_time_s": now_t}


def _snapshot(svc: Services, patient_id: int) -> dict[int, dict[str, Any]]:
    """On the event loop: the patient's open streams by session id, each sensor's arrival
    figures (monotonic clock turned into wall-clock time)."""
    now_mono, now_wall = time.monotonic(), time.time()
    out: dict[int, dict[str, Any]] = {}
    for connection in list(svc.connections.values()):
        if connection.patient_id != patient_id or connection.state is None:
            continue
        sensors = {}
        for name, stats in list(connection.sensor_stats.items()):
            receiving = now_mono - stats["last"] <= STALE_S
            sensors[name] = {
                "last_seen": now_wall - (now_mono - stats["last"]),
                "receiving": receiving,
                "samples_per_s": _rate(connection, name, stats, now_mono) if receiving else 0.0,
            }
        out[connection.state.session_id] = sensors
        for name, figures in sensors.items():
            _last_seen[(connection.state.session_id, name)] = figures["last_seen"]
    if len(_last_seen) > 10000:
        _last_seen.clear()
    return out


def stored_seen(db: DbSession, session_id: int) -> dict[str, float]:
    """Per sensor, when its last rows were stored [s, Unix time], as the session's streams
    keep it with their position (``writer.SEEN_PREFIX``; none for rows stored before)."""
    seen: dict[str, float] = {}
    for (last_t,) in db.execute(select(models.Stream.last_t)
                                .where(models.Stream.session_id == session_id)):
        for key, at in (last_t or {}).items():
            if key.startswith(SEEN_PREFIX):
                name = key[len(SEEN_PREFIX):]
                seen[name] = max(seen.get(name, at), at)
    return seen


def _stored_last_seen(session: models.Session, totals: dict[str, dict[str, float]],
                      name: str, now_wall: float, seen: dict[str, float]) -> float:
    """When sensor ``name`` was last seen [s, Unix time], from the store alone, for a
    stream no page polled while it was open, or a server restarted since (arrival times
    are kept in memory only: "never" was wrong): when its last rows were stored
    (``seen``), the truth also for a backlog sent later and faster than it was recorded;
    for rows stored before that was kept, the session's start (the kit's hello) plus the
    stream's own time from its first sample to that one. Never after ``now_wall``."""
    if name in seen:
        return min(now_wall, seen[name])
    first = min(t["t_first"] for t in totals.values())
    start = aware_utc(session.started_at).timestamp()  # SQLite's naive UTC: not local time
    return min(now_wall, start + (totals[name]["t_last"] - first))


def live_status(svc: Services, db: DbSession, patient_id: int,
                streams: dict[int, dict[str, Any]],
                motion: MotionWatch | None = None) -> dict[str, Any]:
    session = db.scalar(select(models.Session)
                        .where(models.Session.patient_id == patient_id)
                        .order_by(models.Session.started_at.desc(), models.Session.id.desc())
                        .limit(1))
    if session is None or session.status == "closed":
        return {"patient_id": patient_id, "session": None, "sensors": [], "connected": False,
                "calibration": None, "estimating": False, "server_time": time.time()}
    now_wall = time.time()
    open_stream = streams.get(session.id)
    totals = block_totals(db, session.id)
    status = svc.sensor_status.get(patient_id, {})
    sensors = []
    now_t = None
    seen: dict[str, float] | None = None  # read once, when a sensor needs it
    for name in session.sensors:
        arrivals = (open_stream or {}).get(name)
        last_seen = arrivals["last_seen"] if arrivals else _last_seen.get((session.id, name))
        if last_seen is None and name in totals:
            if seen is None:
                seen = stored_seen(db, session.id)
            last_seen = _stored_last_seen(session, totals, name, now_wall, seen)
        sensor_status = status.get(name, {})
        sensors.append({
            "sensor": name,
            "connected": bool(arrivals and arrivals["receiving"]),
            "socket_open": open_stream is not None,
            "samples_per_s": (arrivals["samples_per_s"] if arrivals
                              else 0.0 if open_stream is not None else None),
            "lost_fraction": (lost_fraction(totals[name], session.rate_hz)
                              if name in totals else None),
            "samples": totals.get(name, {}).get("samples", 0),
            "last_seen": last_seen,
            "seconds_since": None if last_seen is None else max(0.0, now_wall - last_seen),
            "battery": sensor_status.get("battery"),
            "rssi_dbm": sensor_status.get("rssi_dbm"),
        })
        if name in totals:
            now_t = max(now_t or -np.inf, totals[name]["t_last"])
    latest = svc.hub.latest.get(patient_id)
    calibration = calibration_progress(db, session.id, now_t, session.status == "live")
    mark = ({"name": calibration["exercise"], "t": calibration["exercise_since_s"]}
            if calibration["exercise"] else None)
    return {
        "patient_id": patient_id,
        "session": {"id": session.id, "status": session.status,
                    "started_at": session.started_at.isoformat(),
                    "device": shown((session.meta or {}).get("device")), "rate_hz": session.rate_hz,
                    "stopped_by_server": None if (stop := stopped_by_server(session)) is None
                    else StoppedByServer(**stop).model_dump(mode="json")},
        "connected": open_stream is not None,
        "sensors": sensors,
        "calibration": calibration,
        "exercise": (current_exercise(motion, session.id, mark, session_lengths(session))
                     if motion is not None else None),
        "estimating": bool(latest and latest.get("session_id") == session.id),
        "normal_ranges": NORMAL_RANGE_DEG,
        "storage_failing": svc.writer.failing,
        "server_time": now_wall,
    }


@router.get("/patients/{patient_id}/live")
async def get_live_status(patient_id: Id, therapist: Therapist,
                          svc: Annotated[Services, Depends(get_services)]) -> dict[str, Any]:
    """The patient's newest live (or interrupted) session: per-sensor connection, samples
    per second, lost-sample rate, last seen, battery and signal; the calibration poses so
    far and the one being held (``holding_now``, null once the stream stopped: a pose it
    cut off is ``cut_off``, docs/extensions/pose-cut-off.md); the exercise going on
    (``exercise``: its name, in words, and its repetitions so far,
    ``server/live/motion.py``). ``session`` is null when nothing is streaming."""
    streams = _snapshot(svc, patient_id)

    motion = watching(svc.hub, patient_id)  # started once the patient is known as theirs

    def read(db: DbSession) -> dict[str, Any]:
        own_patient(db, therapist, patient_id)
        return live_status(svc, db, patient_id, streams, motion)
    answer = await svc.run_db(read)
    if motion is None:
        watch(svc.hub, patient_id)
    return answer
