"""A program as FHIR R4 (``docs/programs.md``, "FHIR R4"): a collection Bundle with a
``CarePlan`` (one ``activity`` per exercise, referencing its ``ServiceRequest``), a
``Goal`` per exercise (its target range in degrees), a ``ServiceRequest`` per exercise
(the dose: ``occurrenceTiming`` days a week within the version's dates; sets ×
repetitions, hold and rest in ``patientInstruction``), the ``Patient``, and per program
session and exercise a range-of-motion ``Observation`` (and the pain and effort given).
Validated with ``fhir.resources``' R4B models in the tests (a validator checks structure,
not codes). Ids are UUIDs derived from the program, version and session, so the same
export twice gives the same resources.

Codes, and where each was looked up:

* SNOMED CT 364564000 "Range of joint movement": every range-of-motion Observation's and
  Goal's code, as the session reports (``reports/fhir.py``). LOINC has degree-valued
  active-range-of-motion terms for some motions and some sides only; where one fits, it
  codes the component it measures:
* LOINC 41299-9 "Shoulder - left Abduction Active Range of Motion Quantitative": the
  highest angle of a left shoulder's abduction exercise (source:
  https://www.healthassure.in/codes/loinc-41299-9-shoulder-left-abduction-active-range-of-motion-quantitative;
  the right shoulder's term was not found, so the right side keeps SNOMED CT only).
* LOINC 41387-2 "Shoulder External rotation Active Range of Motion Quantitative": the
  external rotation reached in a shoulder rotation exercise, −(lowest
  ``shoulder_rotation``), internal rotation being + (``docs/spec/kinematics.md``) (source:
  https://www.healthassure.in/codes/loinc-41387-2-shoulder-external-rotation-active-range-of-motion-quantitative).
* No LOINC term was found for elbow flexion, forearm pronation/supination, wrist flexion
  or a forward reach's shoulder flexion: SNOMED CT 364564000 with the joint as
  ``bodySite`` only (``reports/fhir.py``'s ``body_site``).
* LOINC 72514-3 "Pain severity - 0-10 verbal numeric rating [Score] - Reported": pain
  (source: https://www.healthassure.in/codes/loinc-72514-3-pain-severity-0-10-verbal-numeric-rating-score-reported).
* LOINC 82289-0 "Rating of perceived exertion [Score]", 0 (sitting) to 10 (the highest
  effort possible): effort on the Borg CR10 scale (source: https://loinc.org/82289-0).
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, date, datetime
from typing import Any

from ..db import models
from ..reports.fhir import MOVEMENTS, ROM_CODE, SNOMED, UCUM, body_site
from . import catalogue, store
from .adherence import ProgramSession

LOINC = "http://loinc.org"
#: (angle, side) → (LOINC code, display, which extreme): see the module's docstring
LOINC_COMPONENTS = {
    ("shoulder_abduction", "left"): ("41299-9", "Shoulder - left Abduction Active Range "
                                     "of Motion Quantitative", "max"),
    ("shoulder_elevation", "left"): ("41299-9", "Shoulder - left Abduction Active Range "
                                     "of Motion Quantitative", "max"),
}
#: catalogue exercise → the LOINC term its extreme is, on either side
LOINC_BY_EXERCISE = {
    "shoulder_rotation": ("41387-2", "Shoulder External rotation Active Range of Motion "
                          "Quantitative", "external"),
}
PAIN_CODE = {"system": LOINC, "code": "72514-3",
             "display": "Pain severity - 0-10 verbal numeric rating [Score] - Reported"}
EFFORT_CODE = {"system": LOINC, "code": "82289-0",
               "display": "Rating of perceived exertion [Score]"}
CATEGORY = "http://terminology.hl7.org/CodeSystem/observation-category"


def _uuid(*parts: object) -> str:
    import uuid

    return str(uuid.uuid5(uuid.NAMESPACE_URL, "armtrack:" + ":".join(map(str, parts))))


def _deg(value: float) -> dict[str, Any]:
    return {"value": value, "unit": "deg", "system": UCUM, "code": "deg"}


def _iso(moment: datetime) -> str:
    return (moment if moment.tzinfo else moment.replace(tzinfo=UTC)).isoformat()


def _ref(resource: dict[str, Any]) -> dict[str, str]:
    return {"reference": f"urn:uuid:{resource['id']}"}


def dose_words(e: models.ProgramExercise) -> str:
    words = f"{e.sets} × {e.repetitions} repetitions, {e.days_per_week} days a week"
    if e.hold_s:
        words += f", hold {e.hold_s:g} s"
    if e.sets > 1:
        words += f", rest {e.rest_s:g} s between sets"
    return words + (f". {e.note}" if e.note else "")


def careplan_bundle(program: models.Program, patient: models.Patient,
                    targets: dict[str, models.PatientTarget],
                    sessions: Sequence[ProgramSession], today: date,
                    issued: datetime) -> dict[str, Any]:
    """The program's current version as FHIR R4, with the sessions' observations."""
    version = program.versions[-1]
    patient_res = {"resourceType": "Patient", "id": _uuid("patient", patient.id),
                   "identifier": [{"system": "urn:armtrack:patient", "value": str(patient.id)}],
                   "name": [{"text": patient.name}]}
    subject = {**_ref(patient_res), "display": patient.name}
    active = store.is_active(program, today)
    period = {"start": version.start_date.isoformat()}
    if version.end_date is not None:
        period["end"] = version.end_date.isoformat()
    plan_id = _uuid("program", program.id, "version", version.number)
    goals, requests, activities = [], [], []
    for e in version.exercises:
        entry = catalogue.CATALOGUE[e.exercise]
        (low, high), source = store.resolve_target(e, targets)
        movement = MOVEMENTS.get(e.angle, e.angle)
        goal = {
            "resourceType": "Goal", "id": _uuid("program", program.id, version.number,
                                                 "goal", e.exercise),
            "lifecycleStatus": "active" if active else "completed",
            "description": {"text": f"{entry.title}: {movement} from {low:g}° to {high:g}°"},
            "subject": subject,
            "target": [{"measure": {"coding": [ROM_CODE], "text": f"Range of motion: "
                                                                  f"{movement}"},
                        "detailRange": {"low": _deg(low), "high": _deg(high)}}],
            "note": [{"text": f"target from the {source}"}]}
        timing: dict[str, Any] = {"frequency": e.days_per_week, "period": 1,
                                  "periodUnit": "wk", "boundsPeriod": period}
        request = {
            "resourceType": "ServiceRequest",
            "id": _uuid("program", program.id, version.number, "request", e.exercise),
            "status": "active" if active else "completed", "intent": "order",
            "basedOn": [{"reference": f"urn:uuid:{plan_id}"}],
            "code": {"text": f"{entry.title} ({e.exercise}): {entry.instruction}"},
            "subject": subject,
            "occurrenceTiming": {"repeat": timing},
            "authoredOn": _iso(version.created_at),
            "bodySite": [body_site(e.angle, patient.side)] if e.angle in MOVEMENTS else [],
            "patientInstruction": dose_words(e)}
        if not request["bodySite"]:
            del request["bodySite"]
        goals.append(goal)
        requests.append(request)
        activities.append({"reference": _ref(request),
                           "progress": [{"text": dose_words(e)}]})
    plan = {
        "resourceType": "CarePlan", "id": plan_id,
        "status": "active" if active else "completed", "intent": "plan",
        "title": program.name,
        "description": version.note or f"exercise program, version {version.number}",
        "subject": subject, "period": period, "created": _iso(version.created_at),
        "goal": [_ref(g) for g in goals], "activity": activities,
        "note": [{"text": f"armtrack program {program.id}, version {version.number}"}]}
    observations = session_observations(program, patient, sessions, requests, subject)
    entries = [plan, *goals, *requests, *observations, patient_res]
    return {"resourceType": "Bundle", "id": _uuid("program", program.id, "bundle",
                                                  version.number),
            "type": "collection", "timestamp": _iso(issued),
            "entry": [{"fullUrl": f"urn:uuid:{r['id']}", "resource": r} for r in entries]}


def session_observations(program: models.Program, patient: models.Patient,
                         sessions: Sequence[ProgramSession], requests: Sequence[dict],
                         subject: dict) -> list[dict[str, Any]]:
    """Per program session: a range-of-motion Observation per exercise done, and the pain
    and effort given."""
    by_exercise = {r["id"]: r for r in requests}
    out = []
    for item in sessions:
        when = _iso(item.started_at)
        for name, result in item.results.items():
            entry = catalogue.CATALOGUE.get(name)
            if entry is None or result.repetitions <= 0 or result.range_deg is None:
                continue
            movement = MOVEMENTS.get(entry.angle, entry.angle)
            components = [
                {"code": {"text": f"{movement}: minimum angle"},
                 "valueQuantity": _deg(result.min_deg)},
                {"code": {"text": f"{movement}: maximum angle"},
                 "valueQuantity": _deg(result.max_deg)},
                {"code": {"text": "repetitions counted"}, "valueInteger": result.repetitions}]
            loinc = LOINC_COMPONENTS.get((entry.angle, patient.side))
            if loinc is not None:
                code, display, _ = loinc
                components.append({"code": {"coding": [{"system": LOINC, "code": code,
                                                        "display": display}]},
                                   "valueQuantity": _deg(result.max_deg)})
            if name in LOINC_BY_EXERCISE and result.min_deg is not None:
                code, display, _ = LOINC_BY_EXERCISE[name]
                components.append({"code": {"coding": [{"system": LOINC, "code": code,
                                                        "display": display}]},
                                   "valueQuantity": _deg(max(0.0, -result.min_deg))})
            request_id = _uuid("program", program.id, item.version.number, "request", name)
            obs = {
                "resourceType": "Observation",
                "id": _uuid("session", item.session.id, "program", program.id, name),
                "status": "final",
                "category": [{"coding": [{"system": CATEGORY, "code": "exam",
                                          "display": "Exam"}]}],
                "code": {"coding": [ROM_CODE], "text": f"Range of motion: {movement} "
                                                       f"({entry.title})"},
                "subject": subject, "effectiveDateTime": when,
                "valueQuantity": _deg(result.range_deg), "component": components,
                "bodySite": body_site(entry.angle, patient.side),
                "note": [{"text": f"armtrack session {item.session.id}, program version "
                                  f"{item.version.number}, angle {entry.angle}"}]}
            if request_id in by_exercise:
                obs["basedOn"] = [{"reference": f"urn:uuid:{request_id}"}]
            out.append(obs)
        for kind, code, value in (("pain", PAIN_CODE, item.pain),
                                  ("effort", EFFORT_CODE, item.effort)):
            if value is None:
                continue
            obs = {"resourceType": "Observation",
                   "id": _uuid("session", item.session.id, "program", program.id, kind),
                   "status": "final",
                   "category": [{"coding": [{"system": CATEGORY, "code": "survey",
                                             "display": "Survey"}]}],
                   "code": {"coding": [code], "text": "highest pain given in the session "
                            "(0-10 numeric rating scale)" if kind == "pain" else
                            "highest effort given in the session (Borg CR10, 0-10)"},
                   "subject": subject, "effectiveDateTime": when}
            if kind == "pain":
                obs["valueInteger"] = int(value)
            else:
                obs["valueQuantity"] = {"value": value, "unit": "{score}", "system": UCUM,
                                        "code": "{score}"}
            out.append(obs)
    return out


__all__ = ["SNOMED", "careplan_bundle"]
