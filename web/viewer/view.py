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
#: The camera: its vertical field of view [deg], its turn from the subject's front toward
#: the measured arm [deg], how far above the shoulder it looks down from [deg], and the
#: margin around the arm's reach sphere [-].
CAMERA_FOV_DEG = 45.0
CAMERA_TURN_DEG = 60.0
CAMERA_ELEVATION_DEG = 12.0
REACH_MARGIN = 1.08
#: The view's aspect (width / height) until the browser says (the embedded view is 4:3).
DEFAULT_ASPECT = 4 / 3


def reach_m(lengths: SegmentLengths) -> float:
    """The arm's reach from the shoulder [m]: upper arm + forearm + hand. Wherever the arm
    goes (150° of flexion, full abduction, behind the back), the hand stays within a
    sphere of this radius about the shoulder."""
    return lengths.upper_arm + lengths.forearm + lengths.hand


def framing_distance(reach: float, fov_rad: float, aspect: float) -> float:
    """The camera's distance [m] from the centre of a sphere of radius ``reach`` [m] that
    fits the whole sphere (with ``REACH_MARGIN``) in a view of vertical field of view
    ``fov_rad`` [rad] and ``aspect`` (width / height): the narrower of the vertical and
    horizontal fields decides."""
    horizontal = 2 * np.arctan(np.tan(fov_rad / 2) * aspect)
    half = min(fov_rad, horizontal) / 2
    return REACH_MARGIN * reach / np.sin(half)


class ClientView:
    """The view of one viser ``client``: ``heading`` titles the panels; ``height_m`` [m]
    and ``side`` (``"right"`` | ``"left"``) shape the figure until poses come; ``live``:
    a live view (else a replay, whose controls stay in reach); ``display_scale``: how much
    the page shows the view scaled down (0.2–1; its labels grow to match)."""

    def __init__(self, client, *, heading: str, height_m: float | None, side: str,
                 live: bool = True, display_scale: float = 1.0):
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
                               1.0 if self.side == "right" else -1.0, display_scale)
            self.arcs = RomArcs(client.scene, ROOT, 1.0 if self.side == "right" else -1.0,
                                display_scale)
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
        """Draw ``pose`` (one without a known trunk and shoulder is skipped; unknown
        segments are left out). The first measured pose
        also places the camera in front of the subject, on the measured arm's side."""
        if not pose.is_drawable():
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
        """Frame the arm's whole reach: look at the measured shoulder (the centre of the
        sphere the hand stays in, ``reach_m``) from ``framing_distance`` away,
        ``CAMERA_TURN_DEG`` from the front toward the measured arm's side and
        ``CAMERA_ELEVATION_DEG`` above, so the hand stays in the picture at 150° of
        flexion and at full abduction, and both sagittal and frontal arcs show."""
        R = pose.R_world["thorax"]
        forward = heading(R)
        right = np.cross(forward, [0.0, 0.0, 1.0])  # the subject's right on the floor
        turn, rise = np.radians(CAMERA_TURN_DEG), np.radians(CAMERA_ELEVATION_DEG)
        level = np.cos(turn) * forward + pose.side_sign * np.sin(turn) * right
        toward = np.cos(rise) * level + np.sin(rise) * np.array([0.0, 0.0, 1.0])
        notch = self.arm.notch_world(pose)
        shoulder = notch + R @ pose.p_thorax["shoulder"]
        lengths = pose.lengths() or self.lengths
        camera = self.client.camera
        try:
            aspect = float(camera.aspect)
        except (AssertionError, AttributeError, ZeroDivisionError):  # no size from the browser yet
            aspect = DEFAULT_ASPECT
        if not np.isfinite(aspect) or aspect <= 0:
            aspect = DEFAULT_ASPECT
        fov = np.radians(CAMERA_FOV_DEG)
        distance = framing_distance(reach_m(lengths), fov, aspect)
        with self.client.atomic():
            camera.fov = fov
            camera.up_direction = (0.0, 0.0, 1.0)
            camera.position = shoulder + distance * toward
            camera.look_at = shoulder
