"""A therapist prescribes a program; an emulated patient follows it for two weeks of
simulated sessions (some days skipped, some sessions partial, one kit that names no
program, a session that starts on Sunday in UTC but on Monday in the clinic); the
therapist changes the program half way. A real server (on a simulated calendar: its clock
is replaced in the server process, ``server/clock.py``), real WebSockets
(``server/emulator``), real processing.

The expected adherence, progress and flags are computed here, independently of the
server's code, from the raw sessions (their start times and their reports' marked
exercises) by the words of ``docs/programs.md``, and must equal the server's."""

from __future__ import annotations

import asyncio
import dataclasses
import os
from datetime import UTC, date, datetime, timedelta
from zoneinfo import ZoneInfo

import numpy as np
import pytest
from armtrack.estimator.recording import Mark
from armtrack.estimator.simulation import SimulationConfig, simulate
from armtrack.estimator.simulation.profiles import Motion, Profile
from armtrack.estimator.simulation.scenarios import EXERCISES, calibration_sequence
from armtrack.server.emulator import KitEmulator
from server_support import SIMULATED_CLOCK_PREAMBLE, Zygote, ZygoteServerProcess

ZONE = ZoneInfo("Europe/Zurich")  # UTC+1 in November
MONDAY = date(2026, 11, 2)
#: catalogue name → (simulator scenario, catalogue angle)
SIMULATED = {"elbow_flexion": ("elbow_flexion", "elbow_flexion"),
             "reach": ("reach", "shoulder_flexion"),
             "pronation": ("pronation", "forearm_pronation")}
SETTINGS = {"no_session_days": 3, "window_days": 14, "min_sessions": 3,
            "range_drop": 5.0, "pain_rise": 1.0}

V1 = {"start_date": "2026-11-02", "note": "every morning", "exercises": [
    {"exercise": "elbow_flexion", "sets": 2, "repetitions": 5, "days_per_week": 5,
     "target_min_deg": 0, "target_max_deg": 115, "hold_s": 1, "rest_s": 20},
    {"exercise": "reach", "sets": 1, "repetitions": 5, "days_per_week": 3}]}
V2 = {"start_date": "2026-11-02", "note": "reach dropped, forearm turns added", "exercises": [
    {"exercise": "elbow_flexion", "sets": 2, "repetitions": 5, "days_per_week": 5,
     "target_min_deg": 0, "target_max_deg": 115, "hold_s": 1, "rest_s": 20},
    {"exercise": "pronation", "sets": 1, "repetitions": 3, "days_per_week": 3}]}


@dataclasses.dataclass
class Planned:
    """One simulated session: when it starts (UTC), what is done (exercise → sets of
    (repetitions, amplitude [deg])), the pain given after each exercise, and whether the
    kit names the program."""

    start: datetime
    done: dict[str, list[tuple[int, float]]]
    pain: int | None = 2
    names_program: bool = True


def local(day: int, hour: float) -> datetime:
    """Day ``day`` of the simulated calendar (0: Monday 2026-11-02) at ``hour`` in the
    clinic, as UTC."""
    moment = datetime(MONDAY.year, MONDAY.month, MONDAY.day, tzinfo=ZONE) + timedelta(
        days=day, hours=hour)
    return moment.astimezone(UTC)


FULL_V1 = {"elbow_flexion": [(5, 120.0), (5, 120.0)], "reach": [(5, 80.0)]}
PLAN = [
    Planned(local(0, 9), FULL_V1, pain=2),
    Planned(local(1, 9), FULL_V1, pain=2),
    # day 2 skipped
    Planned(local(3, 9), {"elbow_flexion": [(5, 120.0)]}, pain=3),  # partial: one set
    Planned(local(4, 9), FULL_V1, pain=2),
    # day 5 skipped; Sunday 23:30 UTC is Monday 00:30 in the clinic: week 2, day 7
    Planned(datetime(2026, 11, 8, 23, 30, tzinfo=UTC),
            {"elbow_flexion": [(5, 120.0), (5, 120.0)]}, pain=None, names_program=False),
    Planned(local(7, 18), FULL_V1, pain=3),
    Planned(local(8, 9), {"elbow_flexion": [(5, 110.0), (5, 110.0)], "reach": [(5, 80.0)]},
            pain=3),
    # the therapist changes the program on day 9 at 07:00 (version 2)
    Planned(local(9, 18), {"elbow_flexion": [(5, 100.0), (5, 100.0)],
                           "pronation": [(3, 75.0)]}, pain=4),
    # day 10 skipped
    Planned(local(11, 9), {"elbow_flexion": [(5, 90.0), (5, 90.0)],
                           "pronation": [(3, 75.0)]}, pain=5),
    Planned(local(12, 9), {"elbow_flexion": [(5, 85.0)]}, pain=6),  # partial
    # days 13 to 17 without a session
]
V1_AT = local(0, 8)
V2_AT = local(9, 7)
FINAL_NOW = local(17, 12)

def recording_of(planned: Planned, seed: int):
    """A simulated upper-arm + forearm session: calibration, then each exercise's sets
    with marks ``exercise:<name>`` … ``end:exercise:<name>`` around each set."""
    joints: dict[str, Profile] = dict(calibration_sequence())
    marks = []
    t = 11.0
    for name, sets in planned.done.items():
        scenario, _ = SIMULATED[name]
        for reps, amplitude in sets:
            parts, _ = EXERCISES[scenario](reps, amplitude, t + 0.5)
            for joint, profile in parts.items():
                joints[joint] = joints.get(joint, Profile()) + profile
            end = Motion(joints=parts).end_time() + 0.5
            marks += [Mark(t, f"exercise:{name}"), Mark(end, f"end:exercise:{name}")]
            t = end + 3.0
    config = SimulationConfig(sensors=("upper_arm", "forearm"), rate_hz=50.0,
                              nine_axis=False, seed=seed, tail_s=2.0)
    sim = simulate(config, Motion(joints=joints))
    return dataclasses.replace(sim.recording, marks=tuple(marks))


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    folder = tmp_path_factory.mktemp("programs")
    now_file = folder / "now.txt"
    zygote = Zygote(SIMULATED_CLOCK_PREAMBLE.format(path=str(now_file)))
    server = ZygoteServerProcess(folder / "server", zygote, env={
        "ARMTRACK_CLINIC_TIMEZONE": "Europe/Zurich",
        "ARMTRACK_FLAG_NO_SESSION_DAYS": str(SETTINGS["no_session_days"]),
        "ARMTRACK_FLAG_WINDOW_DAYS": str(SETTINGS["window_days"]),
        "ARMTRACK_FLAG_MIN_SESSIONS": str(SETTINGS["min_sessions"]),
        "ARMTRACK_FLAG_RANGE_DROP_DEG_PER_WEEK": str(SETTINGS["range_drop"]),
        "ARMTRACK_FLAG_PAIN_RISE_PER_WEEK": str(SETTINGS["pain_rise"])})
    server.create_user("alice")
    server.start()
    try:
        yield run_two_weeks(server, now_file)
    finally:
        server.stop()
        zygote.close()


def run_two_weeks(server, now_file) -> dict:
    def set_now(moment: datetime) -> None:
        now_file.write_text(moment.isoformat())

    alice = server.client("alice")
    patient = alice.patient("Follower", side="right")
    device = alice.device(patient["id"], "home kit")
    set_now(V1_AT)
    made = alice.http.post(f"/api/patients/{patient['id']}/programs",
                           json={"name": "Elbow after the fracture", **V1})
    assert made.status_code == 201, made.text
    program = made.json()
    out = {"alice": alice, "patient": patient, "program": program, "sessions": [],
           "readies": [], "server": server}
    for i, planned in enumerate(PLAN):
        if planned.start > V2_AT and "v2" not in out:
            set_now(V2_AT)
            out["week1_before_v2"] = alice.http.get(
                f"/api/programs/{program['id']}/adherence").json()["weeks"][0]
            changed = alice.http.put(f"/api/programs/{program['id']}", json=V2)
            assert changed.status_code == 200, changed.text
            out["v2"] = changed.json()
            out["week1_after_v2"] = alice.http.get(
                f"/api/programs/{program['id']}/adherence").json()["weeks"][0]
        set_now(planned.start)
        ratings = [{"id": f"{i}-{name}", "exercise": name, "t": 20.0,
                    "effort": 3.5, "pain": planned.pain}
                   for name in planned.done] if planned.pain is not None else []
        extra = ({"extensions": ["programs/1", "effort-pain/1"],
                  "program": "Elbow after the fracture"} if planned.names_program else {})
        kit = KitEmulator(recording_of(planned, seed=100 + i), server.ws_url, device["token"],
                          speed=0, rows_per_message=50, hello_extra=extra, ratings=ratings)
        stats = asyncio.run(kit.run())
        session = alice.wait_processed(stats.session, timeout=180)
        assert session["processed"], session
        out["sessions"].append((planned, session))
        out["readies"].append(kit.ready)
    set_now(FINAL_NOW)
    out["adherence"] = alice.http.get(f"/api/programs/{program['id']}/adherence").json()
    out["progress"] = alice.http.get(f"/api/patients/{patient['id']}/progress").json()
    out["flags"] = alice.http.get("/api/flags").json()
    pdf = alice.http.get(f"/api/patients/{patient['id']}/progress.pdf")
    assert pdf.status_code == 200 and pdf.headers["content-type"] == "application/pdf"
    out["pdf"] = pdf.content
    fhir = alice.http.get(f"/api/programs/{program['id']}/careplan.fhir.json")
    assert fhir.status_code == 200 and fhir.headers["content-type"] == "application/fhir+json"
    out["fhir"] = fhir.json()
    out["reports"] = {s["id"]: alice.http.get(f"/api/sessions/{s['id']}/report").json()
                      for _, s in out["sessions"]}
    return out


# --- the expected numbers, from docs/programs.md's words ------------------------------

def utc(text: str) -> datetime:
    """An API time; one without a zone is UTC (SQLite gives them back naive)."""
    moment = datetime.fromisoformat(text)
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


def report_results(report: dict) -> dict[str, dict]:
    """Per marked catalogue exercise: repetitions on its angle summed over its periods,
    the largest period range, the lowest minimum, the highest maximum."""
    out: dict[str, dict] = {}
    for ex in report["exercises"]:
        if ex["source"] != "marks" or ex["name"] not in SIMULATED:
            continue
        angle = SIMULATED[ex["name"]][1]
        r = out.setdefault(ex["name"], {"reps": 0, "range": None, "min": None, "max": None})
        r["reps"] += sum(a["repetitions"] for a in ex["angles"] if a["angle"] == angle)
        rom = ex["rom"].get(angle)
        if rom is not None:
            r["range"] = rom["range"] if r["range"] is None else max(r["range"], rom["range"])
            r["min"] = rom["min"] if r["min"] is None else min(r["min"], rom["min"])
            r["max"] = rom["max"] if r["max"] is None else max(r["max"], rom["max"])
    return out


def expected_sessions(world) -> list[dict]:
    """Each session: its clinic day, the version it followed (named in hello: the version
    current when it started; not named: the version in force, as it has marked exercises
    of it), its results and pain."""
    rows = []
    for planned, session in world["sessions"]:
        started = utc(session["started_at"])
        version = 2 if started >= V2_AT else 1
        report = world["reports"][session["id"]]
        rows.append({"id": session["id"], "started": started,
                     "day": started.astimezone(ZONE).date(), "version": version,
                     "how": "hello" if planned.names_program else "attributed",
                     "results": report_results(report), "pain": planned.pain})
    return rows


def expected_weeks(rows: list[dict], today: date) -> list[dict]:
    versions = {1: V1, 2: V2}
    out = []
    week = MONDAY - timedelta(days=MONDAY.weekday())
    while week <= today - timedelta(days=today.weekday()):
        monday_start = datetime(week.year, week.month, week.day, tzinfo=ZONE)
        number = 2 if monday_start >= V2_AT else 1
        v = versions[number]
        start = date.fromisoformat(v["start_date"])
        active = sum(1 for k in range(7) if week + timedelta(days=k) >= start)
        in_week = [r for r in rows if week <= r["day"] < week + timedelta(days=7)]
        names = [e["exercise"] for e in v["exercises"]]
        days_e = {e["exercise"]: min(e["days_per_week"], active) for e in v["exercises"]}
        reps_e = {e["exercise"]: days_e[e["exercise"]] * e["sets"] * e["repetitions"]
                  for e in v["exercises"]}
        done_reps = {n: sum(r["results"][n]["reps"] for r in in_week if n in r["results"])
                     for n in names}
        done_days = {n: len({r["day"] for r in in_week
                             if r["results"].get(n, {}).get("reps", 0) > 0}) for n in names}
        per_week = max(e["days_per_week"] for e in v["exercises"])
        sessions = min(per_week, active)
        total = sum(reps_e.values())
        # why fewer days are asked than the list's days a week (docs/programs.md)
        shortened = None if sessions == per_week else {
            "starts_on": start.isoformat() if start > week else None, "ends_on": None}
        changed_at = V2_AT.astimezone(ZONE).date()
        changed_on = (changed_at.isoformat() if number == 1 and week <= changed_at
                      < week + timedelta(days=7) and max(e["days_per_week"] for e in V2[
                          "exercises"]) != per_week else None)
        out.append({
            "week": f"{week.isocalendar()[0]}-W{week.isocalendar()[1]:02d}",
            "monday": week.isoformat(), "version": number, "active_days": active,
            "prescribed": {"sessions": sessions, "days": sessions,
                           "exercises": sum(days_e.values()), "repetitions": total},
            "done": {"sessions": len(in_week), "days": len({r["day"] for r in in_week}),
                     "exercises": sum(done_days.values()),
                     "repetitions": sum(done_reps.values())},
            "adherence_percent": round(100 * sum(min(done_reps[n], reps_e[n]) for n in names)
                                       / total, 1),
            "shortened": shortened, "changed_on": changed_on})
        week += timedelta(days=7)
    return out


def slope_per_week(times: list[datetime], values: list[float]) -> float:
    t = np.array([m.timestamp() for m in times])
    return float(np.polyfit(t, np.array(values, dtype=float), 1)[0]) * 7 * 86400


def expected_flags(rows: list[dict], today: date) -> list[dict]:
    flags = []
    last = max(r["day"] for r in rows)
    if (today - last).days >= SETTINGS["no_session_days"]:
        flags.append(("no_session", None, (today - last).days))
    first = today - timedelta(days=SETTINGS["window_days"] - 1)
    window = [r for r in rows if first <= r["day"] <= today]
    for e in V2["exercises"]:
        name = e["exercise"]
        done = [(r["started"], r["results"][name]["range"]) for r in window
                if r["results"].get(name, {}).get("reps", 0) > 0
                and r["results"][name]["range"] is not None]
        if len(done) >= SETTINGS["min_sessions"]:
            slope = slope_per_week([d[0] for d in done], [d[1] for d in done])
            if slope <= -SETTINGS["range_drop"]:
                flags.append(("range_falling", name, round(slope, 2)))
    rated = [(r["started"], r["pain"]) for r in window if r["pain"] is not None]
    if len(rated) >= SETTINGS["min_sessions"]:
        slope = slope_per_week([r[0] for r in rated], [r[1] for r in rated])
        if slope >= SETTINGS["pain_rise"]:
            flags.append(("pain_rising", None, round(slope, 2)))
    return flags


# --- the tests --------------------------------------------------------------------------

def test_sessions_are_dated_on_the_simulated_calendar_and_follow_their_version(world):
    rows = expected_sessions(world)
    for planned, session in world["sessions"]:
        assert utc(session["started_at"]) == planned.start
    # the session that started on Sunday in UTC counts on Monday in the clinic
    assert rows[4]["started"].date() == date(2026, 11, 8)
    assert rows[4]["day"] == date(2026, 11, 9)
    got = world["adherence"]["sessions"]
    assert [(s["session_id"], s["day"], s["version"], s["how"]) for s in got] == [
        (r["id"], r["day"].isoformat(), r["version"], r["how"]) for r in rows]
    # what ready said: the version current when the session started, with its exercises
    readies = world["readies"]
    for planned, ready in zip(PLAN, readies, strict=True):
        if not planned.names_program:
            assert "program" not in ready and "extensions" not in ready
            continue
        assert ready["extensions"] == ["programs/1", "effort-pain/1"]
        number = 2 if planned.start > V2_AT else 1
        assert ready["program"]["version"] == number
        assert [e["name"] for e in ready["program"]["exercises"]] == [
            e["exercise"] for e in (V2 if number == 2 else V1)["exercises"]]
    assert readies[0]["program"]["exercises"][0]["target"] == {
        "min_deg": 0, "max_deg": 115, "from": "program"}


def test_the_report_counts_the_simulated_repetitions(world):
    """The raw numbers the rest stands on: each marked set's repetitions, as simulated
    (docs/programs.md, One repetition: pronation's palm down, then up, is one)."""
    for planned, session in world["sessions"]:
        results = report_results(world["reports"][session["id"]])
        for name, sets in planned.done.items():
            want = sum(r for r, _ in sets)
            print(f"session {session['id']} {name}: {results[name]['reps']} of {want}, "
                  f"range {results[name]['range']}")
            assert results[name]["reps"] == want


def test_the_reports_target_then_is_the_band_of_the_program_version_followed(world, tmp_path):
    """A session that followed a program version is judged against the band that version
    gave each exercise (the band the phone showed the patient): elbow flexion 0–115°
    (the version's own), though the patient has no target of their own; a session that
    named no program has no target then. The report's range of motion, its exercises'
    and the PDF's "Target then" column say so. Before, only the patient's targets counted:
    every session read "–"."""
    import shutil
    import subprocess

    pdftotext = shutil.which("pdftotext")
    for planned, session in world["sessions"]:
        report = world["reports"][session["id"]]
        elbow = report["rom"].get("elbow_flexion")
        if elbow is None:
            continue
        band = ([0, 115] if planned.names_program else [None, None])
        assert [elbow["target_min"], elbow["target_max"]] == band, (session["id"], elbow)
        for ex in report["exercises"]:
            if ex["name"] == "elbow_flexion":
                rom = ex["rom"]["elbow_flexion"]
                assert [rom["target_min"], rom["target_max"]] == band, (session["id"], rom)
            if ex["name"] == "reach" and "shoulder_flexion" in ex["rom"]:
                # the version gives reach no band and the patient has no target: none
                assert ex["rom"]["shoulder_flexion"]["target_max"] is None
    if not pdftotext:
        pytest.skip("needs poppler-utils (pdftotext)")
    followed = next(s for p, s in world["sessions"] if p.names_program)
    pdf = world["alice"].http.get(f"/api/sessions/{followed['id']}/report.pdf")
    path = tmp_path / "report.pdf"
    path.write_bytes(pdf.content)
    text = subprocess.run([pdftotext, "-layout", "-l", "1", str(path), "-"],
                          capture_output=True, text=True, check=True).stdout
    print(text)
    assert "0° to 115°" in text


def test_adherence_per_iso_week_equals_the_docs_count(world):
    rows = expected_sessions(world)
    today = FINAL_NOW.astimezone(ZONE).date()
    want = expected_weeks(rows, today)
    got = world["adherence"]["weeks"]
    for w in got:
        print(w["week"], "v", w["version"], "prescribed", w["prescribed"], "done", w["done"],
              f"{w['adherence_percent']} %")
    assert got == want
    assert [w["week"] for w in got] == ["2026-W45", "2026-W46", "2026-W47"]
    assert got[2]["done"]["sessions"] == 0  # week 3: nothing done yet
    # the progress route carries the same, per program
    (in_progress,) = world["progress"]["programs"]
    assert in_progress["weeks"] == got


def test_a_new_version_keeps_the_old_weeks_and_sessions_right(world):
    assert world["v2"]["version"]["number"] == 2
    assert world["week1_before_v2"] == world["week1_after_v2"]
    week1 = world["adherence"]["weeks"][0]
    assert week1["version"] == 1 and week1 == world["week1_before_v2"]
    progress = {e["exercise"]: e for e in world["adherence"]["exercises"]}
    # reach was dropped in version 2: its points are the version 1 sessions' only
    assert {p["version"] for p in progress["reach"]["points"]} == {1}
    assert {p["version"] for p in progress["pronation"]["points"]} == {2}
    versions = world["alice"].http.get(
        f"/api/programs/{world['program']['id']}/versions").json()
    assert [[e["exercise"] for e in v["exercises"]] for v in versions] == [
        ["elbow_flexion", "reach"], ["elbow_flexion", "pronation"]]


def test_progress_per_exercise_and_pain_equal_the_sessions(world):
    rows = expected_sessions(world)
    progress = {e["exercise"]: e for e in world["adherence"]["exercises"]}
    for name in ("elbow_flexion", "reach", "pronation"):
        want = [(r["id"], r["version"], r["results"][name]["reps"],
                 r["results"][name]["range"]) for r in rows
                if r["results"].get(name, {}).get("reps", 0) > 0]
        got = [(p["session_id"], p["version"], p["repetitions"], p["range_deg"])
               for p in progress[name]["points"]]
        assert got == want, name
    elbow = progress["elbow_flexion"]["points"]
    assert all((p["target_min_deg"], p["target_max_deg"], p["target_source"]) ==
               (0, 115, "program") for p in elbow)
    for p in elbow:
        assert p["target_reached"] == (p["min_deg"] <= 0 and p["max_deg"] >= 115)
    print("elbow ranges:", [p["range_deg"] for p in elbow])
    pain = [(p["session_id"], p["pain"], p["effort"]) for p in world["adherence"]["pain"]]
    assert pain == [(r["id"], r["pain"], 3.5) for r in rows if r["pain"] is not None]


def test_flags_equal_the_docs_definitions(world):
    rows = expected_sessions(world)
    today = FINAL_NOW.astimezone(ZONE).date()
    want = expected_flags(rows, today)
    got = [(f["kind"], f["exercise"], f["value"]) for f in world["adherence"]["flags"]]
    for f in world["adherence"]["flags"]:
        print("flag:", f["message"])
    assert got == want
    assert {k for k, _, _ in want} == {"no_session", "range_falling", "pain_rising"}
    (patient_flags,) = world["flags"]
    assert patient_flags["patient_id"] == world["patient"]["id"]
    assert [(f["kind"], f["exercise"], f["value"]) for f in patient_flags["flags"]] == want


def test_the_program_as_fhir_r4_validates(world):
    from fhir.resources.R4B.bundle import Bundle
    from fhir.resources.R4B.careplan import CarePlan
    from fhir.resources.R4B.goal import Goal
    from fhir.resources.R4B.observation import Observation
    from fhir.resources.R4B.servicerequest import ServiceRequest

    bundle = Bundle.model_validate(world["fhir"])  # raises on an invalid resource
    resources = [e.resource for e in bundle.entry]
    urls = {e.fullUrl for e in bundle.entry}
    (plan,) = [r for r in resources if isinstance(r, CarePlan)]
    goals = [r for r in resources if isinstance(r, Goal)]
    requests = [r for r in resources if isinstance(r, ServiceRequest)]
    observations = [r for r in resources if isinstance(r, Observation)]
    assert plan.status == "active" and plan.intent == "plan"
    assert plan.title == "Elbow after the fracture"
    # the current version: one activity, goal and request per exercise, in order
    assert len(plan.activity) == len(goals) == len(requests) == len(V2["exercises"])
    assert [a.reference.reference for a in plan.activity] == [
        f"urn:uuid:{r.id}" for r in requests]
    assert {g.reference for g in plan.goal} <= urls
    elbow = requests[0]
    assert elbow.occurrenceTiming.repeat.frequency == 5
    assert elbow.occurrenceTiming.repeat.periodUnit == "wk"
    assert "2 × 5 repetitions" in elbow.patientInstruction
    target = goals[0].target[0].detailRange
    assert (float(target.low.value), float(target.high.value)) == (0, 115)
    rows = expected_sessions(world)
    rom = [o for o in observations if o.code.coding[0].code == "364564000"]
    want = sorted((r["id"], n, r["results"][n]["range"]) for r in rows
                  for n in r["results"] if r["results"][n]["reps"] > 0)
    got = sorted((int(o.note[0].text.split()[2].rstrip(",")),
                  o.code.text.split("(")[-1].rstrip(")"), float(o.valueQuantity.value))
                 for o in rom)
    titles = {"elbow_flexion": "Bend the elbow", "reach": "Reach forward",
              "pronation": "Turn the palm"}
    assert got == sorted((i, titles[n], v) for i, n, v in want)
    pain = [o for o in observations if o.code.coding[0].code == "72514-3"]
    effort = [o for o in observations if o.code.coding[0].code == "82289-0"]
    assert sorted(o.valueInteger for o in pain) == sorted(
        r["pain"] for r in rows if r["pain"] is not None)
    assert len(effort) == len(pain) and {float(o.valueQuantity.value) for o in effort} == {3.5}
    for o in observations:
        assert o.subject.reference in urls
        for ref in o.basedOn or []:
            assert ref.reference in urls


def test_the_progress_pdf_says_what_the_api_says(world, tmp_path):
    import shutil
    import subprocess

    if not shutil.which("pdftotext"):
        pytest.skip("needs poppler-utils (pdftotext)")
    path = tmp_path / "progress.pdf"
    path.write_bytes(world["pdf"])
    text = subprocess.run(["pdftotext", "-layout", str(path), "-"], capture_output=True,
                          text=True, check=True).stdout
    assert "Elbow after the fracture" in text and "version 2" in text
    # the clinic's zone whole: the heading ran past the page's edge ("(Europe/Zur")
    assert "the clinic's day (Europe/Zurich)" in text, text
    for f in world["adherence"]["flags"]:
        assert f["message"] in text.replace("\n", " ") or f["message"][:30] in text
    import re
    from datetime import date

    from armtrack.server.reports.words import day_words

    for w in world["adherence"]["weeks"]:  # named by their Monday, as the pages name them
        assert f'week of {day_words(date.fromisoformat(w["monday"]))}' in text
        assert f'{w["done"]["repetitions"]} / {w["prescribed"]["repetitions"]}' in text
        # the Days column, as on the therapist's weeks table (adherence.week_days), before
        # the sessions
        row = (rf'week of {day_words(date.fromisoformat(w["monday"]))}\s+v{w["version"]}\s+'
               rf'{w["done"]["days"]}\s*/\s*{w["prescribed"]["days"]}\s+'  # "4/5": pdftotext
               rf'{w["done"]["sessions"]}\s*/\s*{w["prescribed"]["sessions"]}\s')
        assert re.search(row, text), (row, text)
    assert re.search(r"week\s+version\s+days\s+sessions", text), text
    pages = subprocess.run(["pdfinfo", str(path)], capture_output=True, text=True).stdout
    assert re.search(r"^Pages:\s+1$", pages, re.M), pages
    import os

    if os.environ.get("ARMTRACK_SCREENSHOTS"):
        subprocess.run(["pdftoppm", "-png", "-r", "70", str(path),
                        os.path.join(os.environ["ARMTRACK_SCREENSHOTS"], "progress-pdf")],
                       check=True)


# --- the dashboard, in the real browser -------------------------------------------------

@pytest.fixture(scope="module")
def browser(world, tmp_path_factory):
    from browser_helpers import chromium, need_browser, screenshots_folder

    sync_api = need_browser()
    shots = screenshots_folder(tmp_path_factory, "shots")
    with sync_api.sync_playwright() as playwright, chromium(playwright, 1366) as context:
        yield context, sync_api, shots


def _signed_in_page(context, sync_api, base: str, width: int):
    import re

    from server_support import PASSWORD

    page = context.new_page()
    page.set_default_timeout(60_000)
    page.set_viewport_size({"width": width, "height": 900})
    page.goto(base + "/signin")
    page.fill("#username", "alice")
    page.fill("#password", PASSWORD)
    page.click("#submit")
    page.wait_for_url(re.compile(r".*/patients$"))
    return page


def _programs_fit(page) -> None:
    """The programs' part of the page fits the window: the card within it, nothing in it
    past the card's right edge (wide tables scroll inside their own box). Other parts
    of the page are other issues' (issue 21 reports the patient page's overflow)."""
    found = page.evaluate("""() => {
      const card = document.querySelector("#programs");
      const box = card.getBoundingClientRect();
      const bad = [];
      for (const e of card.querySelectorAll("*")) {
        if (e.parentElement.closest(".scroll")) continue;  // scrolls inside its box
        const r = e.getBoundingClientRect();
        if (r.width && r.right > box.right + 1) bad.push(`${e.tagName}.${e.className}`);
      }
      return {right: box.right, width: window.innerWidth, bad};
    }""")
    assert found["right"] <= found["width"] and not found["bad"], found


@pytest.mark.parametrize("width", [1366, 390])
def test_the_patients_list_flags_who_needs_a_look(world, browser, width):
    context, sync_api, shots = browser
    page = _signed_in_page(context, sync_api, world["server"].url, width)
    row = page.locator(f'#patients tr[data-patient="{world["patient"]["id"]}"]')
    sync_api.expect(row.locator(".chip.flag")).to_have_count(3)
    text = row.inner_text()
    messages = [f["message"] for f in world["flags"][0]["flags"]]
    titles = [row.locator(".chip.flag").nth(i).get_attribute("title") for i in range(3)]
    assert titles == messages  # the server's words, as text
    for message in messages:  # written out beside the chips where there is room
        assert (message in text) == (width > 700)
    page.screenshot(path=str(shots / f"patients-flags-{width}.png"), full_page=True)
    page.close()


@pytest.mark.parametrize("width", [1366, 390])
def test_the_patient_page_shows_the_program_and_its_adherence(world, browser, width):
    context, sync_api, shots = browser
    page = _signed_in_page(context, sync_api, world["server"].url, width)
    page.goto(f"{world['server'].url}/patients/{world['patient']['id']}")
    card = page.locator(f'.program[data-program="{world["program"]["id"]}"]')
    sync_api.expect(card.locator("h3")).to_contain_text("Elbow after the fracture")
    sync_api.expect(card.locator(".program-exercises tbody tr")).to_have_count(2)
    for w in world["adherence"]["weeks"]:
        cells = card.locator(f'tr[data-week="{w["week"]}"] td')
        # the days, the figure the patient's phone says ("This week: 2 of 5 days done")
        sync_api.expect(cells.nth(1)).to_have_text(
            f'{w["done"]["days"]} / {w["prescribed"]["days"]}')
        sync_api.expect(cells.nth(4)).to_have_text(
            f'{w["done"]["repetitions"]} / {w["prescribed"]["repetitions"]}')
        sync_api.expect(cells.nth(5)).to_have_text(f'{w["adherence_percent"]:.0f} %')
    sync_api.expect(card.locator(".flag-line")).to_have_count(3)
    last = world["adherence"]["exercises"][0]["points"][-1]["range_deg"]
    sync_api.expect(card.locator('tr[data-exercise="elbow_flexion"] td').nth(4)).to_contain_text(
        f"{round(last)}°")
    _programs_fit(page)
    page.screenshot(path=str(shots / f"patient-program-{width}.png"), full_page=True)
    page.close()


def test_the_editor_prescribes_and_changes_a_program(world, browser):
    context, sync_api, shots = browser
    alice = world["alice"]
    patient = alice.patient("Editor Patient", side="left")
    page = _signed_in_page(context, sync_api, world["server"].url, 1366)
    page.goto(f"{world['server'].url}/patients/{patient['id']}")
    page.click("#new-program")
    editor = page.locator("#program-editor")
    editor.locator('[name="name"]').fill("Shoulder <b>home</b> plan")  # text, never HTML
    editor.locator('[name="start_date"]').fill("2026-11-16")
    first = editor.locator(".exercise-row").nth(0)
    first.locator('[name="exercise"]').select_option("shoulder_abduction")
    first.locator('[name="sets"]').fill("3")
    first.locator('[name="repetitions"]').fill("8")
    first.locator('[name="days_per_week"]').fill("4")
    first.locator('[name="target_min_deg"]').fill("0")
    first.locator('[name="target_max_deg"]').fill("90")
    page.click("#add-exercise")
    second = editor.locator(".exercise-row").nth(1)
    second.locator('[name="exercise"]').select_option("reach")
    second.locator('[name="target_min_deg"]').fill("100")
    second.locator('[name="target_max_deg"]').fill("20")  # wrong way round: refused
    page.screenshot(path=str(shots / "editor-new-1366.png"), full_page=True)
    page.click("#save-program")
    sync_api.expect(page.locator("#program-editor .error")).to_contain_text(
        "the target's “from” (100°) must be below its “to” (20°)")  # the form's words
    assert alice.http.get(f"/api/patients/{patient['id']}/programs").json() == []
    second.locator('[name="target_min_deg"]').fill("")
    second.locator('[name="target_max_deg"]').fill("")
    second.locator("button[aria-label='Move up']").click()  # reach first
    page.click("#save-program")
    sync_api.expect(page.locator(".program h3")).to_contain_text("Shoulder <b>home</b> plan")
    assert page.locator(".program h3 b").count() == 0
    (made,) = alice.http.get(f"/api/patients/{patient['id']}/programs").json()
    assert [(e["exercise"], e["sets"], e["repetitions"], e["days_per_week"])
            for e in made["version"]["exercises"]] == [("reach", 2, 10, 5),
                                                       ("shoulder_abduction", 3, 8, 4)]
    assert made["version"]["exercises"][1]["target"] == [0, 90]
    # change it: a new version; the first kept
    page.locator(".program button", has_text="Change").click()
    rows = page.locator("#program-editor .exercise-row")
    sync_api.expect(rows).to_have_count(2)
    rows.nth(0).locator("button", has_text="Remove").click()
    rows.nth(0).locator('[name="sets"]').fill("4")
    page.screenshot(path=str(shots / "editor-change-1366.png"), full_page=True)
    page.click("#save-program")
    sync_api.expect(page.locator(".program h3")).to_contain_text("version 2")
    versions = alice.http.get(f"/api/programs/{made['id']}/versions").json()
    assert [[(e["exercise"], e["sets"]) for e in v["exercises"]] for v in versions] == [
        [("reach", 2), ("shoulder_abduction", 3)], [("shoulder_abduction", 4)]]
    page.set_viewport_size({"width": 390, "height": 900})
    page.locator(".program button", has_text="Change").click()
    _programs_fit(page)
    page.screenshot(path=str(shots / "editor-change-390.png"), full_page=True)
    page.close()


@pytest.mark.parametrize("width", [1280, 390])
def test_the_session_page_shows_the_target_then_of_the_version_followed(world, browser,
                                                                        width):
    """The session page's "Target then" line is the band of the program version the
    session followed (the phone's), as the report and the PDF give it; it fits the card."""
    context, sync_api, shots = browser
    followed = next(s for p, s in world["sessions"] if p.names_program)
    page = _signed_in_page(context, sync_api, world["server"].url, width)
    page.goto(f"{world['server'].url}/sessions/{followed['id']}")
    line = page.locator('#rom-targets p[data-angle="elbow_flexion"]')
    sync_api.expect(line).to_contain_text("Target then: Elbow flexion 0° to 115°")
    box = page.locator("#angles-card").bounding_box()
    shown = line.bounding_box()
    assert shown["x"] + shown["width"] <= box["x"] + box["width"] + 1, (shown, box)
    if os.environ.get("ARMTRACK_SCREENSHOTS"):  # the 3D view makes it slow at 390 px (20 s)
        page.screenshot(path=str(shots / f"session-target-then-{width}.png"), full_page=True)
    page.close()
