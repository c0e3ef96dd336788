"""Which joint angles a kit measures, and what it assumes for the rest
(``docs/extensions/measured-angles.md``).

An angle is measured when the segment it moves (the joint's distal segment) carries a
sensor. Its proximal segment either carries one too, or is *assumed* where the chain
keeps unsensored segments (``docs/spec/recording.md``: their joints stay at 0): a phone on the
forearm alone measures the elbow's angles assuming the upper arm hangs still beside the
trunk; a phone on the upper arm alone measures the shoulder's assuming an upright, still
trunk. Every kit without a trunk sensor assumes the trunk upright and still.
"""

from __future__ import annotations

from collections.abc import Iterable

from .joints import ELEVATION

#: Angles by the sensor that must be worn to measure them.
ANGLES_OF_SENSOR: dict[str, tuple[str, ...]] = {
    "clavicle": ("clavicle_protraction", "clavicle_elevation"),
    "upper_arm": ("shoulder_flexion", "shoulder_abduction", "shoulder_rotation", ELEVATION),
    "forearm": ("elbow_flexion", "forearm_pronation"),
    "hand": ("wrist_flexion", "wrist_deviation"),
}

#: Assumption name → (the sensor whose absence makes it, the sensors it matters to,
#: the sentence a report prints).
ASSUMPTIONS: dict[str, tuple[str, tuple[str, ...], str]] = {
    "trunk_still": ("trunk", ("clavicle", "upper_arm", "forearm", "hand"),
                    "the trunk is upright and still (no trunk sensor)"),
    "upper_arm_still": ("upper_arm", ("forearm",),
                        "the upper arm hangs still beside the trunk (no upper-arm sensor): "
                        "elbow angles are the forearm's against the vertical trunk"),
    "forearm_still": ("forearm", ("hand",),
                      "the forearm is still (no forearm sensor): wrist angles are the "
                      "hand's against the assumed forearm"),
}


def measured_angles(sensors: Iterable[str]) -> tuple[str, ...]:
    """The reported angles a kit of ``sensors`` measures, in chain order."""
    worn = set(sensors)
    return tuple(a for sensor, angles in ANGLES_OF_SENSOR.items() if sensor in worn
                 for a in angles)


def assumptions(sensors: Iterable[str]) -> dict[str, str]:
    """The assumptions the kit's measured angles rest on: name → sentence."""
    worn = set(sensors)
    return {name: sentence for name, (missing, matters, sentence) in ASSUMPTIONS.items()
            if missing not in worn and worn & set(matters)}


def coverage(sensors: Iterable[str]) -> dict[str, object]:
    """What a session records about its kit: ``measured_angles`` and ``assumptions``."""
    worn = tuple(sensors)
    return {"measured_angles": list(measured_angles(worn)),
            "assumptions": assumptions(worn)}
