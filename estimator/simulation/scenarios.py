"""Named exercises and the calibration sequence every simulated recording starts with.

Timeline (as in ``shared/data/recordings``): N-pose still from 0 to 3.0 s (header window
0.5–3.0 s), up to the T-pose by 5.0 s, held to 8.5 s (header window 5.5–8.0 s), back to
the N-pose by 10.0 s; the exercise starts at ``EXERCISE_START_S`` = 11 s. A longer N-pose
(``npose_s``, the seconds it is held from the start: 3.0 here) moves everything after it
later by the difference (``pose_windows``, ``calibration_offset``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import InvalidArgument
from .profiles import Motion, Profile, Ramp, Sine, hold_and_return, repetitions

DEG = np.pi / 180.0
NPOSE_WINDOW_S = (0.5, 3.0)
TPOSE_WINDOW_S = (5.5, 8.0)
EXERCISE_START_S = 11.0
#: Exercise accuracy is scored from here on (after the return from the T-pose).
SCORED_FROM_S = 10.5


#: How long the N-pose is held from the start [s], as in ``shared/data/recordings``.
NPOSE_S = 3.0


def calibration_offset(npose_s: float = NPOSE_S) -> float:
    """How much later than the shared timeline everything after an N-pose held
    ``npose_s`` [s] from the start happens [s]."""
    if not 1.0 <= npose_s <= 600.0:
        raise InvalidArgument(f"npose_s must be within 1–600 s, got {npose_s}")
    return npose_s - NPOSE_S


def pose_windows(npose_s: float = NPOSE_S) -> tuple[tuple[float, float], tuple[float, float]]:
    """The header's N- and T-pose windows [s] of an N-pose held ``npose_s`` [s]."""
    offset = calibration_offset(npose_s)
    return ((NPOSE_WINDOW_S[0], NPOSE_WINDOW_S[1] + offset),
            (TPOSE_WINDOW_S[0] + offset, TPOSE_WINDOW_S[1] + offset))


def calibration_sequence(npose_s: float = NPOSE_S) -> dict[str, Profile]:
    """N-pose (held ``npose_s`` [s]), then T-pose (90° abduction) and back: ramps on
    ``shoulder_abduction``."""
    offset = calibration_offset(npose_s)
    return {"shoulder_abduction": Profile(ramps=(Ramp(4.0 + offset, 90 * DEG, 0.25),
                                                 Ramp(9.25 + offset, -90 * DEG, 0.1875)))}


def _merge(*parts: dict[str, Profile]) -> dict[str, Profile]:
    merged: dict[str, Profile] = {}
    for part in parts:
        for name, profile in part.items():
            merged[name] = merged.get(name, Profile()) + profile
    return merged


def _single(name: str, default_amplitude_deg: float, default_reps: int):
    def build(reps: int | None, amplitude_deg: float | None, start: float):
        count = default_reps if reps is None else reps
        amplitude = (default_amplitude_deg if amplitude_deg is None else amplitude_deg) * DEG
        return {name: repetitions(start, count, amplitude)}, {}
    return build


def _elbow_held(name: str, first_deg: float, second_deg: float, default_reps: int):
    """Elbow to 90° and held; ``name`` to ``first_deg`` and back, then to ``second_deg`` and
    back, ×reps: one repetition of a both-ways exercise is a turn to each side
    (``docs/programs.md``: palm down, then up), as the catalogue's instruction says."""
    def build(reps: int | None, amplitude_deg: float | None, start: float):
        count = default_reps if reps is None else reps
        scale = 1.0 if amplitude_deg is None else amplitude_deg / first_deg
        # repetitions(): 1.5-s ramps, 0.5 s held, 1 s still: a turn every 4.5 s
        first = repetitions(start + 2.0, count, first_deg * scale * DEG, rest=5.5)
        second = repetitions(start + 2.0 + 4.5, count, second_deg * scale * DEG, rest=5.5)
        end = start + 2.0 + 2 * count * 4.5
        # up on a ramp centred at start + 0.75 s, down at end + 0.75 s (σ 0.375 s)
        elbow = hold_and_return(start, 90 * DEG, 1.5, end - start - 1.5, sigma=0.375,
                                held=True)
        return {"elbow_flexion": elbow, name: first + second}, {}
    return build


def _reach(flexion_deg: float, elbow_deg: float, default_reps: int, sway_deg: float = 0.0):
    def build(reps: int | None, amplitude_deg: float | None, start: float):
        count = default_reps if reps is None else reps
        scale = 1.0 if amplitude_deg is None else amplitude_deg / flexion_deg
        joints = {"shoulder_flexion": repetitions(start, count, flexion_deg * scale * DEG),
                  "elbow_flexion": repetitions(start, count, elbow_deg * scale * DEG)}
        trunk = {}
        if sway_deg:
            trunk = {"trunk_flexion": Profile(sines=(Sine(sway_deg * DEG, 0.23),)),
                     "trunk_lateral": Profile(sines=(Sine(0.5 * sway_deg * DEG, 0.17, 1.0),))}
        return joints, trunk
    return build


def _combined(default_reps: int):
    """Elbow to 110° ×reps, then wrist flexion to 40° ×(reps − 1)."""
    def build(reps: int | None, amplitude_deg: float | None, start: float):
        count = default_reps if reps is None else reps
        scale = 1.0 if amplitude_deg is None else amplitude_deg / 110.0
        elbow = repetitions(start, count, 110 * scale * DEG)
        wrist = repetitions(start + count * 4.5, max(count - 1, 0), 40 * scale * DEG)
        return {"elbow_flexion": elbow, "wrist_flexion": wrist}, {}
    return build


def _drinking(default_reps: int):
    """Hand to mouth: flexion 45°, elbow 130°, pronation −40° together."""
    def build(reps: int | None, amplitude_deg: float | None, start: float):
        count = default_reps if reps is None else reps
        scale = 1.0 if amplitude_deg is None else amplitude_deg / 130.0
        return {"shoulder_flexion": repetitions(start, count, 45 * scale * DEG),
                "elbow_flexion": repetitions(start, count, 130 * scale * DEG),
                "forearm_pronation": repetitions(start, count, -40 * scale * DEG),
                "shoulder_abduction": repetitions(start, count, 15 * scale * DEG)}, {}
    return build


def _sets(default_sets: int):
    """A long session: sets of elbow flexion to 100° ×10, pronation to 50° ×9 (elbow at
    90°), wrist flexion to 30° ×9, with 8 s rests in the N-pose between exercises."""
    def build(reps: int | None, amplitude_deg: float | None, start: float):
        sets = default_sets if reps is None else reps
        scale = 1.0 if amplitude_deg is None else amplitude_deg / 100.0
        joints: dict[str, Profile] = {}
        t = start
        for _ in range(sets):
            joints = _merge(joints, {"elbow_flexion": repetitions(t, 10, 100 * scale * DEG,
                                                                  rise=1.0, hold=0.3, rest=0.5)})
            t += 10 * 2.8 + 8.0
            joints = _merge(joints, {
                "elbow_flexion": hold_and_return(t, 90 * DEG, 1.5, 9 * 2.8 + 1.0,
                                                 held=True),
                "forearm_pronation": repetitions(t + 2.0, 9, 50 * scale * DEG, rise=1.0,
                                                 hold=0.3, rest=0.5)})
            t += 2.0 + 9 * 2.8 + 3.0 + 8.0
            joints = _merge(joints, {"wrist_flexion": repetitions(t, 9, 30 * scale * DEG,
                                                                  rise=1.0, hold=0.3,
                                                                  rest=0.5)})
            t += 9 * 2.8 + 8.0
        return joints, {}
    return build


def _concurrent_sets(default_sets: int):
    """A long session whose exercises overlap, as ``shared/data/recordings``'
    elbow_6axis_long: sets of elbow flexion to 100° ×10, with forearm pronation to 50° ×9
    starting 1 s and wrist flexion to 30° ×9 starting 2 s after it, all at a 5-s period
    (1.5 s up, 1 s held, 1.5 s down, 1 s rest), 15 s rests in the N-pose between sets.
    Nothing is held: every excursion is a repetition."""
    def build(reps: int | None, amplitude_deg: float | None, start: float):
        sets = default_sets if reps is None else reps
        scale = 1.0 if amplitude_deg is None else amplitude_deg / 100.0
        joints: dict[str, Profile] = {}
        t = start
        for _ in range(sets):
            joints = _merge(joints, {
                "elbow_flexion": repetitions(t, 10, 100 * scale * DEG, hold=1.0),
                "forearm_pronation": repetitions(t + 1.0, 9, 50 * scale * DEG, hold=1.0),
                "wrist_flexion": repetitions(t + 2.0, 9, 30 * scale * DEG, hold=1.0)})
            t += 10 * 5.0 + 15.0
        return joints, {}
    return build


def _shoulder_sets(default_rounds: int, rest_s: float = 20.0, pause_s: float = 1.0):
    """A long session of the shoulder: rounds of flexion to 120° ×8, abduction to 75° ×8,
    rotation ±45° ×6 with the elbow at 90°, and elbow flexion to 110° ×8, with 20 s rests
    in the N-pose after each set (3 rounds: 11 minutes); ``rest_s`` 0: set after set;
    ``pause_s`` [s] the stillness between two repetitions (0: none, nothing ever rests)."""
    def build(reps: int | None, amplitude_deg: float | None, start: float):
        rounds = default_rounds if reps is None else reps
        scale = 1.0 if amplitude_deg is None else amplitude_deg / 120.0
        period = 3.5 + pause_s  # repetitions(): 2 × 1.5 s rise, 0.5 s hold, the pause
        joints: dict[str, Profile] = {}
        t = start

        def sets(begin: float, count: int, amplitude: float) -> Profile:
            return repetitions(begin, count, amplitude, rest=pause_s)
        for _ in range(rounds):
            joints = _merge(joints, {"shoulder_flexion": sets(t, 8, 120 * scale * DEG)})
            t += 8 * period + rest_s
            joints = _merge(joints, {"shoulder_abduction": sets(t, 8, 75 * scale * DEG)})
            t += 8 * period + rest_s
            joints = _merge(joints, {
                "elbow_flexion": hold_and_return(t, 90 * DEG, 1.5, 12 * period + 1.0,
                                                 held=True),
                "shoulder_rotation": sets(t + 2.0, 6, 45 * scale * DEG)
                + sets(t + 2.0 + 6 * period, 6, -45 * scale * DEG)})
            t += 2.0 + 12 * period + 2.0 + pause_s + rest_s
            joints = _merge(joints, {"elbow_flexion": sets(t, 8, 110 * scale * DEG)})
            t += 8 * period + rest_s
        return joints, {}
    return build


ExerciseBuilder = Callable[[int | None, float | None, float],
                           tuple[dict[str, Profile], dict[str, Profile]]]

#: Exercise name → builder(repetitions, amplitude [deg], start [s]) → (joints, trunk).
EXERCISES: dict[str, ExerciseBuilder] = {
    "elbow_flexion": _single("elbow_flexion", 120.0, 5),
    "shoulder_abduction": _single("shoulder_abduction", 80.0, 5),
    "shoulder_flexion": _single("shoulder_flexion", 150.0, 5),
    "abduction_120": _single("shoulder_abduction", 120.0, 4),
    "shoulder_rotation": _elbow_held("shoulder_rotation", 60.0, -50.0, 3),
    "wrist_flexion": _elbow_held("wrist_flexion", 60.0, -50.0, 3),
    "pronation": _elbow_held("forearm_pronation", 75.0, -75.0, 3),
    "wrist_deviation": _elbow_held("wrist_deviation", 25.0, -15.0, 3),
    "reach": _reach(80.0, 70.0, 5),
    "trunk_reach": _reach(70.0, 50.0, 5, sway_deg=4.0),
    "elbow_wrist": _combined(7),
    "drinking": _drinking(5),
    "shrug": _single("clavicle_elevation", 25.0, 5),
    "long_session": _sets(4),
    "long_concurrent": _concurrent_sets(4),
    "shoulder_sets": _shoulder_sets(3),
    "shoulder_sets_no_rest": _shoulder_sets(4, rest_s=0.0),
    "shoulder_sets_nonstop": _shoulder_sets(4, rest_s=0.0, pause_s=0.0),
    "still": lambda reps, amplitude, start: ({}, {}),
}


def exercise_motion(name: str, *, repetitions_count: int | None = None,
                    amplitude_deg: float | None = None, calibration: bool = True,
                    start_s: float | None = None, npose_s: float = NPOSE_S) -> Motion:
    """The calibration sequence (optional; its N-pose held ``npose_s`` [s]) followed by the
    named exercise."""
    if name not in EXERCISES:
        raise InvalidArgument(f"unknown exercise {name!r}; one of {', '.join(sorted(EXERCISES))}")
    # without calibration poses the kit still lies still for 3 s before the exercise
    start = ((EXERCISE_START_S + calibration_offset(npose_s)) if calibration else 3.0) \
        if start_s is None else start_s
    joints, trunk = EXERCISES[name](repetitions_count, amplitude_deg, start)
    if calibration:
        joints = _merge(calibration_sequence(npose_s), joints)
    return Motion(joints=joints, trunk=trunk)


__all__ = ["EXERCISES", "NPOSE_S", "SCORED_FROM_S", "calibration_offset",
           "calibration_sequence", "exercise_motion", "hold_and_return", "pose_windows"]
