"""Range of motion in the scene: per active joint angle, the arc its limb has swept so far,
coloured against the AAOS normal range, and a label with the current angle.

An arc is the path of one point of the angle's distal segment when that angle alone runs
through its range (the others held at their current values), by the chain of
``docs/spec/kinematics.md``. Arcs live in the thorax frame [m]; angles are in degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from armtrack.estimator.arm.forward import forward_kinematics
from armtrack.estimator.arm.joints import NORMAL_RANGE_DEG
from armtrack.estimator.body import SegmentLengths
from armtrack.server.reports.words import exercise_words

from .pose import Pose, chain_angles_rad

#: An angle whose range so far is at least this is active and gets its arc [deg].
ACTIVE_RANGE_DEG = 10.0
#: Beyond the normal range by up to this, an arc is amber; further, red [deg].
AMBER_BEYOND_DEG = 10.0
#: Pieces per arc.
ARC_PIECES = 48
#: Width of an arc's line [screen pixels]: the same however far the camera is.
ARC_LINE_PX = 5.0
#: Opacity of the fan between an arc and its joint.
FAN_OPACITY = 0.35

GREEN = (30, 160, 60)
AMBER = (245, 150, 0)
RED = (214, 40, 40)
BANDS = (GREEN, AMBER, RED)
#: The in-scene labels' size (viser's screen scale: 1 is its default text size): 0.8 was
#: too small to read in the embedded view.
LABEL_SCALE = 1.2
#: viser 1.1's label text at screen scale 1 [CSS px of the view].
VISER_LABEL_PX = 12.0
#: An in-scene label reads at least this large on the page [CSS px]: the page's smallest
#: print (its table headers). A phone shows the 600 px view scaled down (viewer_fit.js).
LABEL_MIN_PX = 12.0
#: The smallest display scale a page may report (a 120 px wide view).
MIN_DISPLAY_SCALE = 0.2


def label_scale(scale: float, display_scale: float = 1.0) -> float:
    """viser's ``font_screen_scale`` for a label of screen scale ``scale`` in a view the
    page shows scaled by ``display_scale`` (0.2–1): on the page it reads as large as in a
    view shown whole, or ``LABEL_MIN_PX`` if that is less; a view shown whole keeps
    ``scale``."""
    display_scale = min(max(display_scale, MIN_DISPLAY_SCALE), 1.0)
    on_page = min(scale * VISER_LABEL_PX, LABEL_MIN_PX)  # [CSS px]
    return max(scale, on_page / (VISER_LABEL_PX * display_scale))
#: How far outside the arc's point a label starts [m] (away from the body).
LABEL_OUTSIDE_M = 0.04

_DOWN = np.array([0.0, -1.0, 0.0])  # a segment's distal axis
_FRONT = np.array([1.0, 0.0, 0.0])  # its anterior axis (for axial rotations)


@dataclass(frozen=True)
class ArcSpec:
    """Which point sweeps: ``radius · R_thorax_<segment> · axis`` about the joint point
    ``centre``; ``radius`` as a fraction of the ``scale`` segment's length."""

    segment: str
    axis: np.ndarray
    centre: str
    radius: float
    scale: str


ARCS: dict[str, ArcSpec] = {
    "shoulder_flexion": ArcSpec("upper_arm", _DOWN, "shoulder", 0.60, "upper_arm"),
    "shoulder_abduction": ArcSpec("upper_arm", _DOWN, "shoulder", 0.45, "upper_arm"),
    "shoulder_rotation": ArcSpec("upper_arm", _FRONT, "elbow", 0.45, "forearm"),
    "elbow_flexion": ArcSpec("forearm", _DOWN, "elbow", 0.55, "forearm"),
    "forearm_pronation": ArcSpec("hand", _FRONT, "wrist", 0.55, "hand"),
    "wrist_flexion": ArcSpec("hand", _DOWN, "wrist", 0.75, "hand"),
    "wrist_deviation": ArcSpec("hand", _DOWN, "wrist", 0.60, "hand"),
}


def band_colour(angle_deg: np.ndarray, name: str) -> np.ndarray:
    """RGB (..., 3) uint8: green inside ``NORMAL_RANGE_DEG[name]``, amber up to
    ``AMBER_BEYOND_DEG`` beyond it, red further."""
    return np.asarray(BANDS, dtype=np.uint8)[band_index(angle_deg, name)]


def band_index(angle_deg: np.ndarray, name: str) -> np.ndarray:
    """Per angle the index into ``BANDS``: 0 (green) inside ``NORMAL_RANGE_DEG[name]``, 1
    (amber) up to ``AMBER_BEYOND_DEG`` beyond it, 2 (red) further."""
    lo, hi = NORMAL_RANGE_DEG[name]
    beyond = np.maximum(lo - np.asarray(angle_deg), np.asarray(angle_deg) - hi)
    return (beyond > 0).astype(np.intp) + (beyond > AMBER_BEYOND_DEG)


def arc_points(name: str, pose: Pose, lengths: SegmentLengths, lo_deg: float, hi_deg: float,
               pieces: int = ARC_PIECES) -> tuple[np.ndarray, np.ndarray]:
    """The arc of ``name`` from ``lo_deg`` to ``hi_deg``: points (pieces + 1, 3) [m, thorax
    frame] and their angles (pieces + 1,) [deg]."""
    spec = ARCS[name]
    theta = np.linspace(lo_deg, hi_deg, pieces + 1)
    angles: dict[str, Any] = chain_angles_rad(pose.angles_deg)
    angles[name] = np.radians(theta)
    side = "right" if pose.side_sign > 0 else "left"
    arm = forward_kinematics(angles, side, lengths)  # type: ignore[arg-type]
    radius = spec.radius * getattr(lengths, spec.scale)
    directions = np.asarray(arm.R_thorax[spec.segment]) @ spec.axis
    return pose.p_thorax[spec.centre] + radius * directions, theta


def current_point(name: str, pose: Pose, lengths: SegmentLengths) -> np.ndarray:
    """Where the arc's point is now (3,) [m, thorax frame], from the measured segment."""
    spec = ARCS[name]
    radius = spec.radius * getattr(lengths, spec.scale)
    return pose.p_thorax[spec.centre] + radius * (pose.R_thorax[spec.segment] @ spec.axis)


def active(pose: Pose) -> list[str]:
    """The angles with an arc: a range so far of at least ``ACTIVE_RANGE_DEG``."""
    return [k for k in ARCS if k in pose.rom_deg
            and pose.rom_deg[k][1] - pose.rom_deg[k][0] >= ACTIVE_RANGE_DEG]


def pretty(name: str) -> str:
    return name.replace("_", " ")


def degrees(value: float) -> str:
    """An angle [deg] for people: whole degrees, no "-0"."""
    return f"{round(value) + 0}°" if math.isfinite(value) else "–"


class RomArcs:
    """The arcs and labels of one viewer's scene, under ``<root>/rom``; nodes made once.

    Each active angle shows a line along its arc (``ARC_LINE_PX`` wide on screen, coloured
    piece by piece) and a translucent fan from its joint to the arc, one fan per colour
    band so a range beyond normal stands out in amber or red. ``display_scale``: how much
    the page shows the view scaled down (``label_scale``)."""

    def __init__(self, scene, root: str, side_sign: float = 1.0, display_scale: float = 1.0):
        self._arcs = {}
        self._side_sign = side_sign
        self._fans: dict[str, list[Any]] = {}
        self._labels = {}
        blank = np.zeros((ARC_PIECES, 2, 3), dtype=np.float32)
        fan_vertices = np.zeros((ARC_PIECES + 2, 3), dtype=np.float32)
        fan_faces = np.array([[0, 1, 2]], dtype=np.uint32)
        for name in ARCS:
            self._arcs[name] = scene.add_line_segments(
                f"{root}/rom/{name}", blank, np.zeros((ARC_PIECES, 2, 3), dtype=np.uint8),
                thickness=ARC_LINE_PX, thickness_units="screen", visible=False)
            self._fans[name] = [
                scene.add_mesh_simple(f"{root}/rom/{name}/fan{i}", fan_vertices, fan_faces,
                                      color=colour, opacity=FAN_OPACITY, side="double",
                                      flat_shading=True, cast_shadow=False,
                                      receive_shadow=False, visible=False)
                for i, colour in enumerate(BANDS)]
            # legible, and written away from the body: the camera looks from the measured
            # arm's side, where the subject's outside is on the screen's left for a right
            # arm (right for a left arm), so the text ends at its point and runs outward;
            # in a view shown scaled down (a phone) the larger text would leave the view
            # there ("lbow flexion" at the arm's rest): it hangs centred below its point
            anchor = ("top-center" if display_scale < 1
                      else "center-right" if side_sign > 0 else "center-left")
            self._labels[name] = scene.add_label(
                f"{root}/rom/{name}/label", exercise_words(name), visible=False,
                font_screen_scale=label_scale(LABEL_SCALE, display_scale), anchor=anchor)
        self.enabled = True

    def update(self, pose: Pose, lengths: SegmentLengths) -> None:
        """Show the active angles' arcs for ``pose``; hide the others."""
        # an unknown angle (its sensor stopped sending) has no arc: its joint is not drawn
        shown = {k for k in active(pose) if math.isfinite(pose.angles_deg.get(k, math.nan))
                 and np.isfinite(pose.p_thorax[ARCS[k].centre]).all()} if self.enabled \
            else set()
        for name, arc in self._arcs.items():
            label = self._labels[name]
            if name not in shown:
                arc.visible = False
                label.visible = False
                for fan in self._fans[name]:
                    fan.visible = False
                continue
            lo, hi = pose.rom_deg[name]
            points, theta = arc_points(name, pose, lengths, lo, hi)
            middle = (theta[:-1] + theta[1:]) / 2
            bands = band_index(middle, name)
            colours = np.asarray(BANDS, dtype=np.uint8)[bands]
            arc.points = np.stack([points[:-1], points[1:]], axis=1).astype(np.float32)
            arc.colors = np.repeat(colours[:, None, :], 2, axis=1)
            arc.visible = True
            self._show_fans(name, pose.p_thorax[ARCS[name].centre], points, bands)
            value = pose.angles_deg.get(name, math.nan)
            outward = np.array([0.0, 0.0, LABEL_OUTSIDE_M * self._side_sign])  # thorax Z: right
            label.position = current_point(name, pose, lengths) + outward
            label.text = (f"{exercise_words(name)} {degrees(value)} "
                          f"({degrees(lo)} to {degrees(hi)})"
                          if math.isfinite(value) else exercise_words(name))
            label.visible = True

    def _show_fans(self, name: str, centre: np.ndarray, points: np.ndarray,
                   bands: np.ndarray) -> None:
        """The fans of ``name``: triangles from the joint ``centre`` to each piece of the
        arc ``points`` (pieces + 1, 3), in the fan of the piece's colour band."""
        vertices = np.vstack([centre[None, :], points]).astype(np.float32)
        pieces = np.arange(len(points) - 1, dtype=np.uint32)
        triangles = np.stack([np.zeros_like(pieces), pieces + 1, pieces + 2], axis=1)
        for i, fan in enumerate(self._fans[name]):
            mine = triangles[bands == i]
            if len(mine) == 0:
                fan.visible = False
                continue
            fan.vertices = vertices
            fan.faces = mine
            fan.visible = True
