"""One viewer's scene and panels: the arm, its range-of-motion arcs and the GUI, made once
when the viewer connects and updated in place by the live or replay driver."""

from __future__ import annotations

import time

import numpy as np
from armtrack.estimator.body import HEIGHT_RANGE_M, SegmentLengths

from .arm import ROOT, ArmView
from .geometry import heading
from .panels import Panels
from .pose import Pose
from .rom import RomArcs

#: Default body height [m] when the patient's is unknown or implausible.
DEFAULT_HEIGHT_M = 1.70


class ClientView:
    """The view of one viser ``client``: ``heading`` titles the panels; ``height_m`` [m]
    and ``side`` (``"right"`` | ``"left"``) shape the figure until poses come."""

    def __init__(self, client, *, heading: str, height_m: float | None, side: str):
        lo, hi = HEIGHT_RANGE_M
        height = height_m if height_m is not None and lo <= height_m <= hi else DEFAULT_HEIGHT_M
        self.client = client
        self.lengths = SegmentLengths.from_height(height)
        self.side = side if side in ("right", "left") else "right"
        self._camera_placed = False
        self._last: Pose | None = None
        self._due: dict[str, float] = {}
        with client.atomic():
            self.panels = Panels(client.gui, heading)
            self.arm = ArmView(client.scene, height, self.lengths,
                               1.0 if self.side == "right" else -1.0)
            self.arcs = RomArcs(client.scene, ROOT)
        self.panels.sensor_frames.on_update(
            lambda _: self.arm.set_sensor_frames(self.panels.sensor_frames.value))
        self.panels.arcs.on_update(lambda _: self._toggle_arcs())
        self.show(Pose.zero(self.lengths, self.side), measured=False)

    def _toggle_arcs(self) -> None:
        self.arcs.enabled = self.panels.arcs.value
        if self._last is not None:
            self.show(self._last, measured=False)

    def due(self, key: str, interval_s: float) -> bool:
        """True at most once per ``interval_s`` [s] per ``key`` (throttles panel updates)."""
        now = time.monotonic()
        if now - self._due.get(key, -np.inf) < interval_s:
            return False
        self._due[key] = now
        return True

    def show(self, pose: Pose, *, measured: bool = True) -> None:
        """Draw ``pose`` (a pose with non-finite parts is skipped). The first measured pose
        also places the camera in front of the subject, on the measured arm's side."""
        if not pose.is_finite():
            return
        lengths = pose.lengths() or self.lengths
        with self.client.atomic():
            self.arm.show(pose)
            self.arcs.update(pose, lengths)
        self._last = pose
        if measured and not self._camera_placed:
            self._camera_placed = True
            self.place_camera(pose)
        elif not measured and not self._camera_placed:
            self.place_camera(pose)

    def place_camera(self, pose: Pose) -> None:
        """Look at the chest from 2.4 m away, 55° from the front toward the measured arm (so
        both sagittal and frontal arcs show)."""
        R = pose.R_world["thorax"]
        forward = heading(R)
        right = np.cross(forward, [0.0, 0.0, 1.0])  # the subject's right on the floor
        turn = np.radians(55.0)
        toward = np.cos(turn) * forward + pose.side_sign * np.sin(turn) * right
        target = self.arm.notch_world(pose) - np.array([0.0, 0.0, 0.25])
        camera = self.client.camera
        with self.client.atomic():
            camera.up_direction = (0.0, 0.0, 1.0)
            camera.position = target + 2.4 * toward + np.array([0.0, 0.0, 0.35])
            camera.look_at = target
