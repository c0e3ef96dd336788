"""Names the therapist reads: angles, exercises and the kit's marks in words
(``elbow_flexion`` → "Elbow flexion", ``end:exercise:elbow_flexion`` → "Elbow flexion
ends", ``tpose`` → "T-pose"), never the codes the stream carries. Plain functions, no
heavy import: the live page, the 3D view's replay and the PDF use them alike."""

from __future__ import annotations

import math
from datetime import date

#: Angles (``REPORTED_ANGLES``) in words.
ANGLE_WORDS = {
    "clavicle_protraction": "Clavicle protraction", "clavicle_elevation": "Clavicle elevation",
    "shoulder_flexion": "Shoulder flexion", "shoulder_abduction": "Shoulder abduction",
    "shoulder_rotation": "Shoulder internal rotation", "elbow_flexion": "Elbow flexion",
    "forearm_pronation": "Forearm pronation", "wrist_flexion": "Wrist flexion",
    "wrist_deviation": "Wrist ulnar deviation", "shoulder_elevation": "Shoulder elevation",
}
#: The calibration poses' marks in words.
POSE_WORDS = {"npose": "N-pose", "tpose": "T-pose"}


def exercise_words(name: str) -> str:
    """An exercise's or angle's name in words; a combined one keeps its parts
    (``elbow_flexion + forearm_pronation`` → "Elbow flexion + Forearm pronation")."""
    parts = [p.strip() for p in name.split("+")]
    text = " + ".join(ANGLE_WORDS.get(p, p.replace("_", " ")) for p in parts)
    return text[:1].upper() + text[1:]


def mark_words(label: str) -> str:
    """A mark's label in words: a calibration pose or an exercise, its start or its end
    ("… ends"); any other label (a kit's own words) as it is."""
    end = label.startswith("end:")
    name = label[4:] if end else label
    if name in POSE_WORDS:
        text = POSE_WORDS[name]
    elif name.startswith("exercise:") and name[9:].strip():
        text = exercise_words(name[9:])
    else:
        return label
    return f"{text} ends" if end else text


def duration_words(seconds: float) -> str:
    """A duration [s] as the pages say it (``fmtDuration`` in web/pages/static/app.js):
    "35 s", "2 min 05 s" — not "0.6 min", which a reader must convert — and from an hour
    on "1 h 05 min", to the minute (not "65 min 17 s"). A half rounds up (``Math.round``),
    not to even as Python's ``round``."""
    whole = math.floor(seconds + 0.5)
    if whole >= 3600:
        return f"{whole // 3600} h {whole % 3600 // 60:02d} min"
    return f"{whole // 60} min {whole % 60:02d} s" if whole >= 60 else f"{whole} s"


def day_words(day: date, weekday: bool = False) -> str:
    """A calendar day as the reports write it: "3 Dec 2026" ("Thu 3 Dec 2026" with
    ``weekday``) — not "2026-12-03" nor an ISO week code ("2026-W49")."""
    return (f"{day:%a} " if weekday else "") + f"{day.day} {day:%b %Y}"
