"""Replay of a stored session in one viewer: play, pause, speed, a timeline to scrub and
jumps to the session's marks. Times are session times [s], angles degrees."""

from __future__ import annotations

import asyncio
import math
import threading
import time
from dataclasses import dataclass

import numpy as np
from armtrack.estimator.metrics import Repetition, repetitions_by_angle
from armtrack.server.db import models
from armtrack.server.live.estimator import CALIBRATION_TAIL_S
from armtrack.server.reports.words import exercise_words, mark_words
from armtrack.server.store.processing import stored_estimates
from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from .panels import PLOT_COLOURS, PLOT_WINDOW_S, ROM_ANGLES, exercise_angle
from .pose import EstimateTable, Rom
from .repetitions import counted_by
from .view import ClientView

#: Replay speeds offered.
SPEEDS = {"0.25×": 0.25, "0.5×": 0.5, "1×": 1.0, "2×": 2.0, "4×": 4.0}
#: Frames per second of the replay.
REPLAY_HZ = 30.0
#: Most points per plotted series.
PLOT_POINTS = 600


@dataclass
class StoredSession:
    """What a replay needs of a stored session."""

    session_id: int
    table: EstimateTable
    marks: list[tuple[float, str]]  # (t [s], label), in time order
    #: the range of motion and repetitions count from here on [s] (after calibration)
    rom_start_s: float


def load_session(db: DbSession, session_id: int) -> StoredSession | None:
    """The stored estimates and marks of a session; None when it has no estimates."""
    session = db.get(models.Session, session_id)
    if session is None:
        return None
    columns, values = stored_estimates(db, session)
    if not columns or len(values) == 0:
        return None
    marks = [(float(m.t), m.label) for m in db.scalars(
        select(models.Mark).where(models.Mark.session_id == session_id)
        .order_by(models.Mark.t, models.Mark.id))]
    table = EstimateTable(columns, values)
    poses = (session.calibration or {}).get("poses") or []
    rom_start = (max(float(p["end"]) for p in poses) + CALIBRATION_TAIL_S if poses
                 else float(table.t[0]))
    return StoredSession(session_id, table, marks, rom_start)


def running_rom(table: EstimateTable, start_s: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per angle, the least and greatest value [deg] up to each row, from ``start_s`` on
    (NaN before any)."""
    out = {}
    for k in ROM_ANGLES:
        v = np.where(table.t >= start_s, table.angles_deg[k], np.nan)
        out[k] = (np.fmin.accumulate(v), np.fmax.accumulate(v))
    return out


def exercise_at(marks: list[tuple[float, str]], t: float) -> str | None:
    """The exercise mark (``exercise:<name>``) open at time ``t`` [s], if any."""
    current = None
    for mt, label in marks:
        if mt > t:
            break
        if label.startswith("exercise:"):
            current = label
        elif current is not None and label == f"end:{current}":
            current = None
    return current


class ReplayDriver:
    """Replays ``data`` in ``view``; the controls go into the view's Replay folder."""

    def __init__(self, view: ClientView, data: StoredSession):
        self.view = view
        self.data = data
        table = data.table
        self.t0, self.t1 = float(table.t[0]), float(table.t[-1])
        self.t = self.t0
        self.playing = True
        self.speed = 1.0
        self._seek: float | None = None
        self._lock = threading.Lock()
        self.rom = running_rom(table, data.rom_start_s)
        angles = {k: np.radians(table.angles_deg[k]) for k in ROM_ANGLES}
        exclude = [(self.t0, data.rom_start_s)] if data.rom_start_s > self.t0 else None
        self.repetitions: dict[str, tuple[Repetition, ...]] = repetitions_by_angle(
            angles, table.t, exclude=exclude)
        #: the whole session's repetitions per angle (``count_repetitions``)
        self.totals = counted_by(self.repetitions, math.inf)
        # in words, as the therapist reads them ("12.5 s · Elbow flexion"), not codes
        self._mark_options = {f"{t:.1f} s · {mark_words(label)}": t for t, label in data.marks}
        self._build_controls()

    def _build_controls(self) -> None:
        gui = self.view.client.gui
        folder = self.view.panels.replay_folder
        with folder:
            self.play = gui.add_button("Play", icon="player-play")
            self.pause = gui.add_button("Pause", icon="player-pause")
            self.speed_input = gui.add_dropdown("Speed", tuple(SPEEDS), initial_value="1×")
            step = 0.01 if self.t1 - self.t0 < 600 else 0.1
            self.timeline = gui.add_slider("Time [s]", min=round(self.t0, 2),
                                           max=round(max(self.t1, self.t0 + step), 2),
                                           step=step, initial_value=round(self.t0, 2))
            options = tuple(self._mark_options) or ("(no marks)",)
            self.marks = gui.add_dropdown("Marks", options, disabled=not self._mark_options)
            self.jump = gui.add_button("Jump to mark", disabled=not self._mark_options)
        folder.visible = True
        self.play.on_click(lambda _: self._set_playing(True))
        self.pause.on_click(lambda _: self._set_playing(False))
        self.speed_input.on_update(lambda _: setattr(self, "speed",
                                                     SPEEDS[self.speed_input.value]))
        self.timeline.on_update(self._scrubbed)
        self.marks.on_update(lambda event: self._jump() if event.client is not None else None)
        self.jump.on_click(lambda _: self._jump())

    def _set_playing(self, playing: bool) -> None:
        with self._lock:
            if playing and self.t >= self.t1:
                self._seek = self.t0
            self.playing = playing

    def _scrubbed(self, event) -> None:
        if event.client is not None:  # a viewer moved it, not the replay
            self.seek(float(self.timeline.value))

    def _jump(self) -> None:
        t = self._mark_options.get(self.marks.value)
        if t is not None:
            self.seek(t)

    def seek(self, t: float) -> None:
        """Go to session time ``t`` [s]."""
        with self._lock:
            self._seek = min(max(t, self.t0), self.t1)

    def index_at(self, t: float) -> int:
        return int(np.clip(np.searchsorted(self.data.table.t, t, side="right") - 1,
                           0, len(self.data.table) - 1))

    def advance(self, dt: float) -> float:
        """The replay time after ``dt`` [s] of wall time."""
        with self._lock:
            if self._seek is not None:
                self.t, self._seek = self._seek, None
            elif self.playing:
                self.t = min(self.t + dt * self.speed, self.t1)
                if self.t >= self.t1:
                    self.playing = False
            return self.t

    async def run(self) -> None:
        """Until cancelled: ``REPLAY_HZ`` frames per second."""
        last = -1
        clock = time.monotonic()
        while True:
            now = time.monotonic()
            t = self.advance(now - clock)
            clock = now
            i = self.index_at(t)
            if i != last:
                last = i
                await asyncio.to_thread(self.show, i)
            await asyncio.sleep(1.0 / REPLAY_HZ)

    def rom_at(self, i: int) -> Rom:
        return {k: (float(lo[i]), float(hi[i])) for k, (lo, hi) in self.rom.items()
                if math.isfinite(lo[i])}

    def show(self, i: int) -> None:
        """Draw row ``i`` and its panels (runs on a worker thread)."""
        table = self.data.table
        pose = table.pose(i, self.rom_at(i))
        self.view.show(pose)
        view, panels = self.view, self.view.panels
        if view.due("slider", 0.2):
            self.timeline.value = round(float(np.clip(pose.t, self.timeline.min,
                                                      self.timeline.max)), 2)
        if view.due("plot", 0.1):
            start = int(np.searchsorted(table.t, pose.t - PLOT_WINDOW_S))
            step = max(1, math.ceil((i + 1 - start) / PLOT_POINTS))
            rows = slice(start, i + 1, step)
            panels.show_plot(table.t[rows], {k: table.angles_deg[k][rows] for k in PLOT_COLOURS})
        if view.due("tables", 0.3):
            panels.show_rom(pose.rom_deg, pose.angles_deg)
            exercise = exercise_at(self.data.marks, pose.t)
            name = exercise_angle(exercise, pose.rom_deg)
            counts = counted_by(self.repetitions, pose.t)
            panels.show_repetitions(name, counts.get(name, 0) if name else 0,
                                    self.totals.get(name) if name else None)
            state = "playing" if self.playing else "paused"
            panels.show_status([
                f"Replay · session {self.data.session_id} · {state} at {self.speed:g}×",
                f"t = {pose.t:.1f} s of {self.t1:.1f} s"
                + (f" · {exercise_words(exercise[9:])}" if exercise else "")])
