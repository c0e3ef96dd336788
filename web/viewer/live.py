"""The live driver of one viewer: the patient's updates from the server's ``LiveHub`` drawn
as they come (the hub publishes poses at most ``live_poses_hz``, 30 Hz by default)."""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from .panels import PLOT_COLOURS, PLOT_WINDOW_S, ROM_ANGLES, exercise_angle
from .pose import Pose
from .repetitions import RunningRepetitions
from .view import ClientView

#: The panel's title is checked this often when no update comes [s].
TICK_S = 1.0
#: A pose this recent means the stream is live, when the kit streams to another server
#: instance [s].
POSE_FRESH_S = 2.0


class LiveDriver:
    """Feeds ``view`` with the updates of ``patient_id`` from ``hub``; ``sensor_status``:
    the server's last ``status`` per sensor of that patient."""

    def __init__(self, view: ClientView, hub, patient_id: int,
                 sensor_status: dict[str, dict[str, Any]] | None = None,
                 receiving: Callable[[], bool | None] | None = None):
        self.view = view
        #: whether the kit sends now (``server/live/streams.py``; None: no stream here)
        self.receiving = receiving or (lambda: None)
        self.session_status: str | None = None  # of the newest session heard of
        self._pose_at = -float("inf")  # monotonic time of the last pose
        self.hub = hub
        self.patient_id = patient_id
        self.sensors: dict[str, dict[str, Any]] = dict(sensor_status or {})
        self.session: str = "no live session yet"
        self.repetitions = RunningRepetitions(ROM_ANGLES)
        self._plot_t: deque[float] = deque()
        self._plot: dict[str, deque[float]] = {k: deque() for k in PLOT_COLOURS}
        self._pose: Pose | None = None
        self._update: dict[str, Any] = {}

    async def run(self) -> None:
        """Until cancelled."""
        with self.hub.subscribe(self.patient_id) as subscription:
            latest = self.hub.latest.get(self.patient_id)
            if latest is not None:
                await asyncio.to_thread(self.handle, latest)
            else:
                await asyncio.to_thread(self._status)
            while True:  # the chip is kept up to date even when nothing comes
                try:
                    update = await asyncio.wait_for(subscription.get(), TICK_S)
                except TimeoutError:  # the title only (sent when it changes)
                    await asyncio.to_thread(self._label)
                    continue
                await asyncio.to_thread(self.handle, update)

    def handle(self, update: dict[str, Any]) -> None:
        """One hub update (runs on a worker thread, never on the event loop)."""
        kind = update.get("kind")
        if kind == "pose":
            pose = Pose.from_update(update)
            self._pose, self._update = pose, update
            self._pose_at = time.monotonic()
            self.session = f"session {update.get('session_id')}: live"
            self.view.show(pose)
            self._panels(pose)
        elif kind == "status":
            self.sensors[str(update.get("sensor"))] = update
        elif kind == "session":
            self.session = f"session {update.get('session_id')}: {update.get('status')}"
            self.session_status = update.get("status")
        elif kind == "error":
            self.session = f"session {update.get('session_id')}: {update.get('reason')}"
        if kind != "pose" or self.view.due("status", 0.5):
            self._status()

    def _panels(self, pose: Pose) -> None:
        if pose.rom_deg:  # after calibration: count repetitions
            self.repetitions.add(pose.t, pose.angles_deg)
        self._plot_t.append(pose.t)
        for k, values in self._plot.items():
            values.append(pose.angles_deg.get(k, np.nan))
        while self._plot_t and self._plot_t[0] < pose.t - PLOT_WINDOW_S:
            self._plot_t.popleft()
            for values in self._plot.values():
                values.popleft()
        panels = self.view.panels
        if self.view.due("plot", 0.1):
            panels.show_plot(np.fromiter(self._plot_t, float),
                             {k: np.fromiter(v, float) for k, v in self._plot.items()})
        if self.view.due("tables", 0.5):
            panels.show_rom(pose.rom_deg, pose.angles_deg)
            name = exercise_angle(None, pose.rom_deg)
            panels.show_repetitions(name, self.repetitions.counts.get(name, 0) if name else 0)

    def stream_state(self) -> str:
        """The stream's state in words, for the panel's title: the sensor table's rule
        when the kit streams to this server, else what the hub says."""
        receiving = self.receiving()
        if receiving is True:
            return "Live: receiving"
        if receiving is False:
            return "No data from the kit"
        if self.session_status == "closed":
            return "Session ended"
        if self.session_status == "interrupted":
            return "Connection lost"
        if time.monotonic() - self._pose_at <= POSE_FRESH_S:
            return "Live: receiving"  # the kit streams to another server instance
        return "Waiting for the kit"

    def _label(self) -> None:
        self.view.panels.set_label(self.stream_state())

    def _status(self) -> None:
        self._label()
        lines = [f"Live · {self.session}"]
        if self._pose is not None:
            latency = self._update.get("latency_s")
            lines.append(f"t = {self._pose.t:.1f} s"
                         + (f" · latency {1000 * latency:.0f} ms" if latency is not None else ""))
            if not self._pose.rom_deg:
                lines.append("calibrating: hold the pose still")
        now = time.time()
        for name, s in sorted(self.sensors.items()):
            parts = [name]
            if s.get("battery") is not None:
                parts.append(f"battery {100 * float(s['battery']):.0f} %"
                             if float(s["battery"]) <= 1 else f"battery {s['battery']} %")
            if s.get("received_at") is not None:
                try:
                    parts.append(f"seen {max(0.0, now - float(s['received_at'])):.0f} s ago")
                except (TypeError, ValueError):
                    pass
            lines.append(" · ".join(parts))
        for warning in self._update.get("warnings") or []:
            lines.append(f"⚠ {warning}")
        self.view.panels.show_status(lines)
