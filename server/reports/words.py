"""Names the therapist reads: angles, exercises and the kit's marks in words
(``elbow_flexion`` → "Elbow flexion", ``end:exercise:elbow_flexion`` → "Elbow flexion
ends", ``tpose`` → "T-pose"), never the codes the stream carries. Plain functions, no
heavy import: the live page, the 3D view's replay and the PDF use them alike."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
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


def set_words(names: Sequence[str]) -> list[str]:
    """A session's exercises' names in words, in their order; where the kit marked the
    same exercise more than once, each says its set ("Elbow flexion — set 1", "Elbow
    flexion — set 2"), as the pages do (``exerciseNames`` in web/pages/static/app.js).
    The report's names (its JSON and CSV) stay the kit's."""
    total = Counter(names)
    seen: Counter[str] = Counter()
    out = []
    for name in names:
        text = exercise_words(name)
        if total[name] > 1:
            seen[name] += 1
            text += f" — set {seen[name]}"
        out.append(text)
    return out


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


def calibration_words(method: str | None, poses: list[tuple[str, float, float]],
                      carries_on: int | None = None, brief: bool = False) -> str:
    """Which calibration a session's estimates used, in a sentence for the therapist:
    ``method`` (the estimator's: two-pose, n-pose, default), the ``poses`` held
    ``(name, start_s, end_s)`` and the session it carries on (carried-on/1), if any;
    ``brief``: in a line (the PDF's header)."""
    held = ", ".join(f"{POSE_WORDS.get(n, n)} {a:.1f}–{b:.1f} s" for n, a, b in poses)
    if method == "two-pose":
        return f"From the calibration poses held in this session ({held})."
    if method == "n-pose":
        return f"From the N-pose held in this session ({held}); no T-pose."
    default = ("the default sensor mounting is used (each sensor as the strapping guide "
               "places it) and the first second is taken as the arm hanging")
    if method == "default" and carries_on is not None:
        if brief:
            return (f"No pose here: carries on session {carries_on}, where they were held; "
                    f"default sensor mounting used.")
        return (f"No calibration pose in this session: it carries on session {carries_on}, "
                f"where the patient held the poses, but each session is calibrated on its "
                f"own, so {default}.")
    if method == "default":
        return ("No calibration pose: default sensor mounting used." if brief
                else f"No calibration pose in this session: {default}.")
    return "Not estimated yet." if method is None else f"{method}."
