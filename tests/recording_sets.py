"""The simulated recordings with ground truth the tests read, and what is known of each.

Two sets of the same ten sessions (names of ``shared/data/recordings``):

* ``shared``: the independent simulator's files in ``../shared/data/recordings`` (CI has
  them, a user's clone does not); what is known of them is their README (counts,
  amplitudes, extremes), written here by hand: the independent check.
* ``stand-in``: the same sessions made by the project's simulator (:data:`STAND_INS`);
  what is known of them comes from the simulation's own truth (the excursions it planned:
  their amplitudes, peak times and speeds, and the truth angles at their peaks), never
  from an estimate.

Tests that take ``recording_set`` run on every set there is (both where ``../shared``
exists, the stand-ins alone on a clone); ``recordings_dir`` is one set, the shared one
where it exists.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: ``../shared`` beside the repository; ``ARMTRACK_TEST_SHARED_DIR`` points elsewhere (a
#: folder that does not exist runs the tests as on a user's clone).
SHARED_DIR = Path(os.environ.get("ARMTRACK_TEST_SHARED_DIR")
                  or Path(__file__).resolve().parents[1].parent / "shared")
SHARED_RECORDINGS = SHARED_DIR / "data" / "recordings"
ELEVATION = "shoulder_elevation"
#: Angles whose exercise goes to both sides of rest (``docs/programs.md``, One repetition).
BOTH_WAYS_ANGLES = ("forearm_pronation", "wrist_flexion", "wrist_deviation",
                    "shoulder_rotation")
#: Angles whose repetitions ``shoulder_elevation`` repeats (it is the upper arm's angle
#: from hanging, whichever way it rises).
ELEVATING = ("shoulder_flexion", "shoulder_abduction")


@dataclass(frozen=True)
class SessionFacts:
    """What is known of one recording without estimating anything.

    repetitions: angle → signed amplitudes [deg] of its repetitions, in time order (every
    angle not listed has none; an elbow held at 90° while the wrist works is not one).
    extremes: angle → (min, max) [deg] over the exercise, for every angle that moves.
    excursions: angle → the simulator's planned excursions (stand-ins only: times and
    speeds in closed form, ``estimator.simulation.Excursion``); ``None`` for shared files.
    duration_s, jitter_std_s: the recording's length and its timestamps' jitter [s].
    """

    side: str
    height_m: float
    rate_hz: float
    nine_axis: bool
    sensors: tuple[str, ...]
    duration_s: float
    scenario: str
    repetitions: dict[str, tuple[float, ...]]
    extremes: dict[str, tuple[float, float]]
    lost_fraction: float = 0.0
    jitter_std_s: float = 0.0
    excursions: dict[str, tuple] | None = None

    def counts(self, angles=None) -> dict[str, int]:
        """Repetitions per angle as a therapist counts them (``docs/programs.md``, One
        repetition: on a both-ways angle a turn to each side is one, the count the turns
        to the side turned to more often; the README counts each turn, "pronation to 75°
        ×3, then supination to −75° ×3": 6 turns, 3 repetitions) (``angles``: those, 0
        where none; default: every angle that has some but ``shoulder_elevation``)."""
        if angles is None:
            angles = [k for k in self.repetitions if k != ELEVATION]
        return {k: self._count(k) for k in angles}

    def turns(self, angles=None) -> dict[str, int]:
        """Excursions from rest and back per angle (each turn of a both-ways angle one),
        as the README's table counts them."""
        if angles is None:
            angles = [k for k in self.repetitions if k != ELEVATION]
        return {k: len(self.repetitions.get(k, ())) for k in angles}

    def _count(self, angle: str) -> int:
        signed = self.repetitions.get(angle, ())
        if angle not in BOTH_WAYS_ANGLES:
            return len(signed)
        return max(sum(1 for a in signed if a > 0), sum(1 for a in signed if a < 0))


_ARM = ("upper_arm", "forearm", "hand")


def _readme(side, height, rate, nine_axis, duration, repetitions, extremes, sensors=_ARM,
            **more) -> SessionFacts:
    return SessionFacts(side, height, rate, nine_axis, sensors, duration, "", repetitions,
                        extremes, **more)


#: ``shared/data/recordings/README.md``, as numbers: body, sampling, the repetitions as
#: signed amplitudes [deg] and the moved angles' exact extremes [deg] (the elbow *held* at
#: 90° moved to get there but made no repetition).
SHARED_FACTS: dict[str, SessionFacts] = {
    "elbow_flexion": _readme("right", 1.80, 100, True, 40, {
        "elbow_flexion": (120,) * 5}, {"elbow_flexion": (0, 120)}),
    "shoulder_abduction": _readme("right", 1.74, 100, True, 40, {
        "shoulder_abduction": (80,) * 5, ELEVATION: (80,) * 5},
        {"shoulder_abduction": (0, 80), ELEVATION: (0, 80)}),
    "shoulder_flexion": _readme("right", 1.66, 100, True, 40, {
        "shoulder_flexion": (150,) * 5, ELEVATION: (150,) * 5},
        {"shoulder_flexion": (0, 150), ELEVATION: (0, 150)}),
    "wrist_flexion": _readme("right", 1.83, 100, True, 40, {
        "wrist_flexion": (60,) * 3 + (-50,) * 3},
        {"elbow_flexion": (0, 90), "wrist_flexion": (-50, 60)}),
    "pronation": _readme("right", 1.78, 100, True, 40, {
        "forearm_pronation": (75,) * 3 + (-75,) * 3},
        {"elbow_flexion": (0, 90), "forearm_pronation": (-75, 75)}),
    "left_reach_50hz": _readme("left", 1.70, 50, True, 40, {
        "shoulder_flexion": (80,) * 5, "elbow_flexion": (70,) * 5, ELEVATION: (80,) * 5},
        {"shoulder_flexion": (0, 80), "elbow_flexion": (0, 70), ELEVATION: (0, 80)}),
    "elbow_6axis": _readme("right", 1.80, 100, False, 45, {
        "elbow_flexion": (110,) * 7, "wrist_flexion": (40,) * 6},
        {"elbow_flexion": (0, 110), "wrist_flexion": (0, 40)}),
    "elbow_6axis_long": _readme("right", 1.76, 100, False, 300, {
        "elbow_flexion": (100,) * 40, "forearm_pronation": (50,) * 36,
        "wrist_flexion": (30,) * 36},
        {"elbow_flexion": (0, 100), "forearm_pronation": (0, 50), "wrist_flexion": (0, 30)}),
    "trunk_reach": _readme("right", 1.69, 100, True, 40, {
        "shoulder_flexion": (70,) * 5, "elbow_flexion": (50,) * 5, ELEVATION: (70,) * 5},
        {"shoulder_flexion": (0, 70), "elbow_flexion": (0, 50), ELEVATION: (0, 70)},
        sensors=("trunk", *_ARM)),
    "abduction_120": _readme("right", 1.72, 100, True, 40, {
        "shoulder_abduction": (120,) * 4, ELEVATION: (120,) * 4},
        {"shoulder_abduction": (0, 120), ELEVATION: (0, 120)},
        lost_fraction=0.02, jitter_std_s=0.001),
}
SHARED_FACTS = {name: dataclasses.replace(f, scenario=name) for name, f in SHARED_FACTS.items()}

#: The shared recordings' sessions as the project's simulator makes them: name →
#: SimulationConfig's arguments. Same side, height, rate, axes, sensors, exercise
#: (amplitudes and repetition counts), losses and jitter; another simulator, other
#: mountings, biases and noise draws (:func:`stand_in_config`: also their lengths).
STAND_INS: dict[str, dict] = {
    "elbow_flexion": {"exercise": "elbow_flexion", "height_m": 1.80},
    "shoulder_abduction": {"exercise": "shoulder_abduction", "height_m": 1.74},
    "shoulder_flexion": {"exercise": "shoulder_flexion", "height_m": 1.66},
    "wrist_flexion": {"exercise": "wrist_flexion", "height_m": 1.83},
    "pronation": {"exercise": "pronation", "height_m": 1.78},
    "left_reach_50hz": {"exercise": "reach", "side": "left", "height_m": 1.70,
                        "rate_hz": 50.0},
    "elbow_6axis": {"exercise": "elbow_wrist", "height_m": 1.80, "nine_axis": False},
    # the shared file's three exercises overlap, none held (its README's 40 + 36 + 36)
    "elbow_6axis_long": {"exercise": "long_concurrent", "height_m": 1.76,
                         "nine_axis": False, "gyro_bias_walk": 2e-4},
    # the shared file's trunk sways from t = 0, through the poses, ±4° forward at 0.125 Hz
    # (its trunk gyroscope's spectrum): trunk_sway gives that, and ±2° sideways
    "trunk_reach": {"exercise": "trunk_reach", "height_m": 1.69,
                    "sensors": ("trunk", *_ARM), "trunk_sway": (4.0, 0.125)},
    "abduction_120": {"exercise": "abduction_120", "height_m": 1.72, "lost_fraction": 0.02,
                      "jitter_s": 0.001},
}


#: (stand-in, check) → where the estimator misses its accuracy bar on it (measured
#: figures): the check asserts that it still misses it, so the day it meets it the entry
#: must go, and checks everything else as on the others. Checks: "report-rom" (test_reports'
#: range-of-motion bar). The stand-in trunk_reach met the pipeline's bar at 2.01° and
#: 2.18 cm before issue 19's filter changes, 0.92° and 0.99 cm after; its report's range of
#: motion missed the 1.5° bar (elbow range 1.53° off) until qcf weighed the field-turning
#: bias estimate of its never-resting trunk by its noise (793bc41): worst 0.45° since.
STAND_IN_GAPS: dict[tuple[str, str], str] = {}


def stand_in_config(name: str):
    """The ``SimulationConfig`` of ``name``'s stand-in (seed: its place in the names), as
    long as the shared file (at rest after the exercise), or 2 s after the exercise where
    that is later (elbow_6axis's exercises follow each other; the shared file's overlap)."""
    from armtrack.estimator.simulation import SimulationConfig, exercise_motion

    given = dict(STAND_INS[name])
    walk = given.pop("gyro_bias_walk", 0.0)
    end = exercise_motion(given["exercise"]).end_time()
    # the last sample at exactly the shared file's length (n = ⌊duration · rate⌋ + 1)
    given["tail_s"] = max(SHARED_FACTS[name].duration_s - end, 2.0) + 1e-9
    config = SimulationConfig(seed=sorted(STAND_INS).index(name) + 1, **given)
    if walk:
        config = dataclasses.replace(
            config, errors=dataclasses.replace(config.errors, gyro_bias_walk=walk))
    return config


def stand_in_facts(config, simulation) -> SessionFacts:
    """What the simulation knows of the session it made: its planned repetitions (signed
    peak values from rest, ``Excursion.peak_value``), and ``shoulder_elevation``'s as the
    truth's elevation at the peaks of the shoulder's; the extremes of every joint that
    made an excursion (rest is 0°)."""
    truth = simulation.truth
    recording = simulation.recording
    deg = 180.0 / np.pi
    repetitions = {k: tuple(e.peak_value * deg for e in truth.repetitions(k))
                   for k in truth.excursions if truth.repetitions(k)}
    extremes = {}
    for angle, excursions in truth.excursions.items():
        amplitudes = [e.peak_value * deg for e in excursions]
        extremes[angle] = (min(0.0, *amplitudes), max(0.0, *amplitudes))
    rising = sorted((e for k in ELEVATING for e in truth.repetitions(k)),
                    key=lambda e: e.up_s)
    if rising:
        at_peaks = np.searchsorted(truth.t, [e.peak_s for e in rising])
        elevation = tuple(float(v) for v in truth.angles[ELEVATION][at_peaks] * deg)
        repetitions[ELEVATION] = elevation
        extremes[ELEVATION] = (0.0, max(elevation))
    return SessionFacts(
        side=config.side, height_m=config.height_m, rate_hz=config.rate_hz,
        nine_axis=config.nine_axis, sensors=tuple(recording.sensors),
        duration_s=float(truth.t[-1]), scenario=config.exercise, repetitions=repetitions,
        extremes=extremes, lost_fraction=config.lost_fraction,
        jitter_std_s=config.jitter_s / np.sqrt(3.0),  # uniform in ±jitter_s
        excursions={k: truth.repetitions(k) for k in truth.excursions
                    if truth.repetitions(k)})


def make_stand_ins(folder: Path) -> dict[str, SessionFacts]:
    """``NAME.csv`` and ``NAME.truth.csv`` for every name of :data:`STAND_INS` in
    ``folder``, by the project's simulator (about 10 s); their facts by name."""
    from armtrack.estimator.recording import write_recording
    from armtrack.estimator.simulation import simulate, write_truth

    facts = {}
    for name in sorted(STAND_INS):
        config = stand_in_config(name)
        result = simulate(config)
        write_recording(result.recording, folder / f"{name}.csv")
        write_truth(result.truth, folder / f"{name}.truth.csv")
        facts[name] = stand_in_facts(config, result)
    return facts


@dataclass
class RecordingSet:
    """A folder of ``NAME.csv`` recordings with ``NAME.truth.csv``, and their facts."""

    source: str  # "shared" or "stand-in"
    folder: Path
    facts: dict[str, SessionFacts]
    _truth: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def names(self) -> list[str]:
        return sorted(self.facts)

    def gap(self, name: str, check: str) -> str | None:
        """Why the estimator misses the bar of ``check`` on ``name`` of this set (None: it
        meets it; :data:`STAND_IN_GAPS`)."""
        return STAND_IN_GAPS.get((name, check)) if self.source == "stand-in" else None

    def path(self, name: str) -> Path:
        return self.folder / f"{name}.csv"

    def truth(self, name: str) -> np.ndarray:
        """The truth table (structured array: ``t``, angles [deg], positions [m])."""
        if name not in self._truth:
            self._truth[name] = np.genfromtxt(self.folder / f"{name}.truth.csv",
                                              delimiter=",", names=True)
        return self._truth[name]


def available_sources() -> list[str]:
    """The sets this machine has: the stand-ins always, the shared files where present."""
    return ["stand-in", *(["shared"] if SHARED_RECORDINGS.is_dir() else [])]
