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
#: The camera: its distance from the target [m], its turn from the subject's front toward
#: the measured arm [deg], how far the target is below the shoulder [m] and how far the
#: camera is above the target [m].
CAMERA_DISTANCE_M = 1.3
CAMERA_TURN_DEG = 60.0
CAMERA_DROP_M = 0.22
CAMERA_RISE_M = 0.25


class ClientView:
    """The view of one viser ``client``: ``heading`` titles the panels; ``height_m`` [m]
    and ``side`` (``"right"`` | ``"left"``) shape the figure until poses come; ``live``:
    a live view (else a replay, whose controls stay in reach)."""

    def __init__(self, client, *, heading: str, height_m: float | None, side: str,
                 live: bool = True):
        lo, hi = HEIGHT_RANGE_M
        height = height_m if height_m is not None and lo <= height_m <= hi else DEFAULT_HEIGHT_M
        self.client = client
        self.lengths = SegmentLengths.from_height(height)
        self.side = side if side in ("right", "left") else "right"
        self._camera_placed = False
        self._last: Pose | None = None
        self._due: dict[str, float] = {}
        with client.atomic():
            self.panels = Panels(client.gui, heading, live=live)
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
        """Frame the measured arm: look at a point below its shoulder (where the arm and
        its arcs are, whether it hangs or is raised) from ``CAMERA_DISTANCE_M`` away,
        ``CAMERA_TURN_DEG`` from the front toward the measured arm's side and a little
        above, so the arm fills the middle of a small embedded view and both sagittal and
        frontal arcs show, clear of the trunk."""
        R = pose.R_world["thorax"]
        forward = heading(R)
        right = np.cross(forward, [0.0, 0.0, 1.0])  # the subject's right on the floor
        turn = np.radians(CAMERA_TURN_DEG)
        toward = np.cos(turn) * forward + pose.side_sign * np.sin(turn) * right
        notch = self.arm.notch_world(pose)
        shoulder = notch + R @ pose.p_thorax["shoulder"]
        target = shoulder - np.array([0.0, 0.0, CAMERA_DROP_M]) + 0.05 * forward
        camera = self.client.camera
        with self.client.atomic():
            camera.up_direction = (0.0, 0.0, 1.0)
            camera.position = target + CAMERA_DISTANCE_M * toward + np.array(
                [0.0, 0.0, CAMERA_RISE_M])
            camera.look_at = target
