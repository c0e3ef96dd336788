"""The exercise catalogue: every exercise the guided home session (``/kit``) and the
programs know, with the joint angle that measures it (``docs/spec/kinematics.md``'s names and
signs), its default target band [deg], the sensor that must be worn to measure it, a
sentence for the patient and a picture (the name of a drawing the kit page has).

Programs (``docs/programs.md``) count an exercise's repetitions and take its range on its
``angle`` only (the report's rule, ``estimator.metrics.count_repetitions``: a full cycle out
and back, counted once — for ``both_ways`` exercises, a turn to each side).
A multi-joint exercise names the angle it is counted on: *reach* moves the shoulder and the
elbow together and is counted on ``shoulder_flexion``, its largest-amplitude angle (the rule
the report uses to name detected exercises, ``reports/content.py``'s ``detected_groups``).

What a kit can measure (``estimator/arm/coverage.py``): an exercise is measured by a kit
whose sensors measure its ``angle`` — a phone on the forearm measures elbow flexion and
pronation, on the upper arm the shoulder's angles (rotation included); nothing worn on
the forearm alone measures the shoulder's rotation, and only a hand sensor the wrist's.
``measurable`` and ``why_not`` say so, in words for the kit and the program editor.

An exercise's ``name`` is what its stream marks carry (``exercise:<name>``, ``ingest.md``)
and what reports group by; the names match the simulator's scenarios where both exist.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

from armtrack.estimator.arm.coverage import ANGLES_OF_SENSOR, measured_angles
from armtrack.estimator.metrics import BOTH_WAYS


@dataclass(frozen=True)
class Exercise:
    """One exercise of the catalogue.

    ``angle``: the joint angle that measures it. ``rest_deg``..``target_deg``: the default
    target band [deg] — from where the movement starts to where it should reach (a
    therapist's target for ``angle`` replaces it). ``sensor``: the segment whose sensor
    measures ``angle`` (``coverage.ANGLES_OF_SENSOR``; the single-sensor kits wear one).
    ``repetitions``: the default count. ``both_ways`` (from ``angle``): one repetition is a
    turn to each side of the rest (palm down, then up), not one excursion from rest.
    ``instruction``: one sentence for the patient. ``picture``: a drawing's name.
    """

    name: str
    title: str
    angle: str
    rest_deg: float
    target_deg: float
    sensor: str
    repetitions: int
    instruction: str
    picture: str

    @property
    def both_ways(self) -> bool:
        return self.angle in BOTH_WAYS

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "both_ways": self.both_ways}


CATALOGUE: dict[str, Exercise] = {e.name: e for e in (
    Exercise("elbow_flexion", "Bend the elbow", "elbow_flexion", 0.0, 120.0, "forearm", 10,
             "Arm along your side, thumb forward: bend the elbow to bring the hand up "
             "toward the shoulder, then straighten it fully.", "elbow_flexion"),
    Exercise("pronation", "Turn the palm", "forearm_pronation", -70.0, 70.0, "forearm", 10,
             "Elbow bent at a right angle by your side: turn the palm down, then up, as far "
             "as is comfortable.", "pronation"),
    Exercise("shoulder_flexion", "Raise the arm forward", "shoulder_elevation", 0.0, 150.0,
             "upper_arm", 10,
             "Arm straight, thumb up: raise it forward and up as high as is comfortable, "
             "then lower it slowly.", "shoulder_flexion"),
    Exercise("shoulder_abduction", "Raise the arm to the side", "shoulder_elevation", 0.0,
             90.0, "upper_arm", 10,
             "Arm straight, palm down: raise it out to the side up to shoulder height, then "
             "lower it slowly.", "shoulder_abduction"),
    Exercise("wrist_flexion", "Bend the wrist", "wrist_flexion", -50.0, 60.0, "hand", 10,
             "Forearm resting on a table, palm down: bend the wrist down, then up, as far as "
             "is comfortable.", "wrist_flexion"),
    Exercise("shoulder_rotation", "Turn the arm out and in", "shoulder_rotation", -50.0,
             60.0, "upper_arm", 10,
             "Elbow bent at a right angle by your side: swing the hand out, then in across "
             "your belly, keeping the elbow at your side.", "shoulder_rotation"),
    Exercise("reach", "Reach forward", "shoulder_flexion", 0.0, 80.0, "upper_arm", 8,
             "Sitting tall: reach forward as if to take a cup from a shelf, then bring the "
             "hand back. Counted on the arm's forward raise, its largest movement.", "reach"),
)}

#: What a phone on each segment guides by default, in this order, when the therapist
#: has set no program.
DEFAULT_SESSION: dict[str, tuple[str, ...]] = {
    "forearm": ("elbow_flexion", "pronation"),
    "upper_arm": ("shoulder_flexion", "shoulder_abduction"),
}


def exercise(name: str) -> Exercise | None:
    """The catalogue's exercise ``name`` (None when unknown)."""
    return CATALOGUE.get(name)


#: The segments a phone kit is worn on (``docs/phone-kit.md``).
PHONE_SEGMENTS: tuple[str, ...] = ("forearm", "upper_arm")

#: Words for the segments and angles in the sentences below.
SEGMENT_WORDS = {"trunk": "trunk", "clavicle": "collarbone", "upper_arm": "upper arm",
                 "forearm": "forearm", "hand": "hand"}
ANGLE_WORDS = {"elbow_flexion": "the elbow's bend", "forearm_pronation": "the forearm's turn",
               "shoulder_elevation": "the arm's elevation",
               "shoulder_flexion": "the shoulder's forward raise",
               "shoulder_abduction": "the shoulder's side raise",
               "shoulder_rotation": "the shoulder's rotation", "wrist_flexion": "the wrist's bend",
               "wrist_deviation": "the wrist's side bend"}


def measurable(entry: Exercise, sensors: Iterable[str]) -> bool:
    """Whether a kit wearing ``sensors`` measures ``entry`` (its ``angle``)."""
    return entry.angle in measured_angles(sensors)


def phone_segments(entry: Exercise) -> list[str]:
    """The segments a single phone may be worn on to measure ``entry``."""
    return [s for s in PHONE_SEGMENTS if measurable(entry, (s,))]


def why_not(entry: Exercise, sensors: Iterable[str]) -> str:
    """Why a kit wearing ``sensors`` (or kits wearing them between them) does not measure
    ``entry``, in a sentence."""
    worn = [SEGMENT_WORDS.get(s, s) for s in sensors]
    needed = [SEGMENT_WORDS.get(s, s) for s, angles in ANGLES_OF_SENSOR.items()
              if entry.angle in angles]
    kit = ("no sensor is worn" if not worn else
           f"a sensor on the {worn[0]} alone does not measure it" if len(worn) == 1 else
           f"sensors on the {', '.join(worn[:-1])} and {worn[-1]} do not measure it")
    return (f"{entry.title}: counted on {ANGLE_WORDS.get(entry.angle, entry.angle)}, which "
            f"needs a sensor on the {' or '.join(needed) or 'arm'}; {kit}.")


def phone_fields(entry: Exercise) -> dict[str, Any]:
    """What the device-today read adds to an exercise for a phone kit: ``measured_by``
    (the segments a phone measures it on) and ``not_measured`` (segment → why not)."""
    on = phone_segments(entry)
    return {"measured_by": on,
            "not_measured": {s: why_not(entry, (s,)) for s in PHONE_SEGMENTS if s not in on}}
