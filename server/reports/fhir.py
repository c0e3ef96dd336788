"""The report's ranges of motion as FHIR R4: a ``Bundle`` (type ``collection``) holding a
``DiagnosticReport`` that groups one ``Observation`` per angle that moved, and the
``Patient`` they are about.

Each Observation: code SNOMED CT 364564000 "Range of joint movement"; ``valueQuantity``
the arc of motion (range) in UCUM ``deg``; components for the minimum and maximum angle and
the percentage of normal; ``bodySite`` the joint with laterality as a SNOMED CT
post-coordinated expression (``<joint>:272741003=<24028007 right | 7771000 left>``, with
the same in ``text``); ``referenceRange`` the AAOS normal arc (``type`` normal; the
components carry the normal minimum and maximum) and, when the therapist set one, the
patient's target (``type`` treatment). Ids are stable UUIDs derived from the session, so
the same export twice gives the same resources. Times are the session's start and end.
"""

from __future__ import annotations

import uuid
from datetime import UTC, datetime
from typing import Any

from .content import RomEntry, SessionReport

SNOMED = "http://snomed.info/sct"
UCUM = "http://unitsofmeasure.org"
RANGE_MEANING = "http://terminology.hl7.org/CodeSystem/referencerange-meaning"
ROM_CODE = {"system": SNOMED, "code": "364564000", "display": "Range of joint movement"}
LATERALITY = {"right": ("24028007", "Right"), "left": ("7771000", "Left")}
#: angle → (SNOMED CT body structure, its display, the joint's plain name)
JOINT_SITES = {
    "clavicle_protraction": ("7844006", "Sternoclavicular joint structure",
                             "sternoclavicular joint"),
    "clavicle_elevation": ("7844006", "Sternoclavicular joint structure",
                           "sternoclavicular joint"),
    "shoulder_flexion": ("16982005", "Shoulder joint structure", "shoulder joint"),
    "shoulder_abduction": ("16982005", "Shoulder joint structure", "shoulder joint"),
    "shoulder_rotation": ("16982005", "Shoulder joint structure", "shoulder joint"),
    "shoulder_elevation": ("16982005", "Shoulder joint structure", "shoulder joint"),
    "elbow_flexion": ("16953009", "Elbow joint structure", "elbow joint"),
    "forearm_pronation": ("14975008", "Forearm structure", "forearm"),
    "wrist_flexion": ("74670003", "Wrist joint structure", "wrist joint"),
    "wrist_deviation": ("74670003", "Wrist joint structure", "wrist joint"),
}
#: angle → the movement measured, in words
MOVEMENTS = {
    "clavicle_protraction": "clavicle protraction–retraction",
    "clavicle_elevation": "clavicle elevation–depression",
    "shoulder_flexion": "shoulder flexion–extension",
    "shoulder_abduction": "shoulder abduction–adduction",
    "shoulder_rotation": "shoulder internal–external rotation",
    "shoulder_elevation": "shoulder elevation (humerothoracic)",
    "elbow_flexion": "elbow flexion–extension",
    "forearm_pronation": "forearm pronation–supination",
    "wrist_flexion": "wrist flexion–extension",
    "wrist_deviation": "wrist ulnar–radial deviation",
}


def _deg(value: float) -> dict[str, Any]:
    return {"value": value, "unit": "deg", "system": UCUM, "code": "deg"}


def _percent(value: float) -> dict[str, Any]:
    return {"value": value, "unit": "%", "system": UCUM, "code": "%"}


def _uuid(*parts: object) -> str:
    return str(uuid.uuid5(uuid.NAMESPACE_URL, "armtrack:" + ":".join(map(str, parts))))


def _iso(moment: datetime | None) -> str | None:
    if moment is None:
        return None
    return (moment if moment.tzinfo else moment.replace(tzinfo=UTC)).isoformat()


def body_site(angle: str, side: str) -> dict[str, Any]:
    code, display, plain = JOINT_SITES[angle]
    lat_code, lat = LATERALITY[side]
    return {"coding": [{"system": SNOMED, "code": f"{code}:272741003={lat_code}",
                        "display": f"{display} ({lat.lower()})"}],
            "text": f"{side} {plain}"}


def observation(report: SessionReport, angle: str, rom: RomEntry, obs_id: str,
                patient_ref: str, issued: str) -> dict[str, Any]:
    movement = MOVEMENTS[angle]
    components = [
        {"code": {"text": f"{movement}: minimum angle"}, "valueQuantity": _deg(rom.min)},
        {"code": {"text": f"{movement}: maximum angle"}, "valueQuantity": _deg(rom.max)},
    ]
    ranges: list[dict[str, Any]] = []
    if rom.normal_min is not None and rom.normal_max is not None:
        components[0]["referenceRange"] = [{"low": _deg(rom.normal_min),
                                            "text": "AAOS normal limit"}]
        components[1]["referenceRange"] = [{"high": _deg(rom.normal_max),
                                            "text": "AAOS normal limit"}]
        ranges.append({
            "high": _deg(rom.normal_max - rom.normal_min),
            "type": {"coding": [{"system": RANGE_MEANING, "code": "normal",
                                 "display": "Normal Range"}]},
            "text": f"AAOS normal {rom.normal_min:g}° to {rom.normal_max:g}° "
                    f"(arc {rom.normal_max - rom.normal_min:g}°)"})
    if rom.percent_of_normal is not None:
        components.append({"code": {"text": "reach on the side moved most as a percentage of "
                                            "the AAOS normal limit on that side"},
                           "valueQuantity": _percent(rom.percent_of_normal)})
    if rom.target_min is not None and rom.target_max is not None:
        ranges.append({
            "low": _deg(rom.target_max - rom.target_min),
            "type": {"coding": [{"system": RANGE_MEANING, "code": "treatment",
                                 "display": "Treatment Range"}]},
            "text": f"therapist's target {rom.target_min:g}° to {rom.target_max:g}°"
                    + (" (reached)" if rom.target_reached else " (not reached)")})
    s = report.session
    resource: dict[str, Any] = {
        "resourceType": "Observation", "id": obs_id, "status": "final",
        "category": [{"coding": [{
            "system": "http://terminology.hl7.org/CodeSystem/observation-category",
            "code": "exam", "display": "Exam"}]}],
        "code": {"coding": [ROM_CODE], "text": f"Range of motion: {movement}"},
        "subject": {"reference": patient_ref, "display": s.patient_name},
        "effectivePeriod": {k: v for k, v in (("start", _iso(s.started_at)),
                                              ("end", _iso(s.ended_at))) if v},
        "issued": issued,
        "bodySite": body_site(angle, s.side),
        "method": {"text": "wearable inertial sensors (armtrack); robust extremes with "
                           "calibration poses excluded"},
        "valueQuantity": _deg(rom.range),
        "component": components,
        "note": [{"text": f"armtrack angle {angle}, docs/spec/kinematics.md signs; "
                          f"{rom.samples} samples"}],
    }
    if ranges:
        resource["referenceRange"] = ranges
    return resource


def fhir_bundle(report: SessionReport, issued: datetime | None = None) -> dict[str, Any]:
    """The report's ROM as a FHIR R4 collection Bundle (a JSON-ready dict)."""
    s = report.session
    issued_iso = _iso(issued or datetime.now(UTC))
    patient_id = _uuid("patient", s.patient_id)
    patient_ref = f"urn:uuid:{patient_id}"
    observations = []
    for angle, rom in report.rom.items():
        obs_id = _uuid("session", s.session_id, "rom", angle)
        observations.append(observation(report, angle, rom, obs_id, patient_ref, issued_iso))
    report_id = _uuid("session", s.session_id, "report")
    diagnostic = {
        "resourceType": "DiagnosticReport", "id": report_id, "status": "final",
        "category": [{"coding": [{"system": "http://terminology.hl7.org/CodeSystem/v2-0074",
                                  "code": "PHY", "display": "Physician"}],
                      "text": "rehabilitation assessment"}],
        "code": {"coding": [ROM_CODE],
                 "text": f"Range of motion of the {s.side} arm, session {s.session_id}"},
        "subject": {"reference": patient_ref, "display": s.patient_name},
        "effectivePeriod": {k: v for k, v in (("start", _iso(s.started_at)),
                                              ("end", _iso(s.ended_at))) if v},
        "issued": issued_iso,
        "result": [{"reference": f"urn:uuid:{o['id']}"} for o in observations],
        "conclusion": "; ".join(
            f"{MOVEMENTS[a]} {r.min:.0f}° to {r.max:.0f}° (arc {r.range:.0f}°"
            + (f", {r.percent_of_normal:.0f}% of normal" if r.percent_of_normal is not None
               else "") + ")" for a, r in report.rom.items()) or "no joint moved",
    }
    patient = {"resourceType": "Patient", "id": patient_id,
               "identifier": [{"system": "urn:armtrack:patient", "value": str(s.patient_id)}],
               "name": [{"text": s.patient_name}]}
    entries = [diagnostic, *observations, patient]
    return {
        "resourceType": "Bundle", "id": _uuid("session", s.session_id, "bundle"),
        "type": "collection", "timestamp": issued_iso,
        "entry": [{"fullUrl": f"urn:uuid:{r['id']}", "resource": r} for r in entries],
    }
