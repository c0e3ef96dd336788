"""The exercise catalogue: every exercise the guided home session (``/kit``) and the
programs know, with the joint angle that measures it (``spec/kinematics.md``'s names and
signs), its default target band [deg], the sensor that must be worn to measure it, a
sentence for the patient and a picture (the name of a drawing the kit page has).

Programs (``docs/programs.md``) count an exercise's repetitions and take its range on its
``angle`` only (the report's rule: one excursion from rest and back is one repetition).
A multi-joint exercise names the angle it is counted on: *reach* moves the shoulder and the
elbow together and is counted on ``shoulder_flexion``, its largest-amplitude angle (the rule
the report uses to name detected exercises, ``reports/content.py``'s ``detected_groups``).

An exercise's ``name`` is what its stream marks carry (``exercise:<name>``, ``ingest.md``)
and what reports group by; the names match the simulator's scenarios where both exist.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any


@dataclass(frozen=True)
class Exercise:
    """One exercise of the catalogue.

    ``angle``: the joint angle that measures it. ``rest_deg``..``target_deg``: the default
    target band [deg] — from where the movement starts to where it should reach (a
    therapist's target for ``angle`` replaces it). ``sensor``: the segment whose sensor
    measures it (the single-sensor kits wear one). ``repetitions``: the default count.
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

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


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
             60.0, "forearm", 10,
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
