"""Programs over REST on a real server (``docs/programs.md``): a therapist prescribes,
changes (new versions, the old ones kept), ends; bad prescriptions are refused whole with
an error naming the fault; another therapist sees nothing. Both databases."""

from __future__ import annotations

from datetime import date, timedelta

import pytest

pytestmark = pytest.mark.both_databases

ELBOW = {"exercise": "elbow_flexion", "sets": 3, "repetitions": 10,
         "target_min_deg": 0, "target_max_deg": 120, "hold_s": 2, "rest_s": 45,
         "days_per_week": 5, "note": "slowly"}
REACH = {"exercise": "reach", "sets": 2, "repetitions": 8, "days_per_week": 3}


@pytest.fixture(scope="module")
def alice(module_server):
    return module_server.client("alice")


@pytest.fixture(scope="module")
def bob(module_server):
    return module_server.client("bob")


def test_the_catalogue_names_the_angle_of_each_exercise(alice):
    catalogue = {e["name"]: e for e in alice.http.get("/api/programs/catalogue").json()}
    assert catalogue["elbow_flexion"]["angle"] == "elbow_flexion"
    assert catalogue["pronation"]["angle"] == "forearm_pronation"
    # a multi-joint exercise names the angle it is counted on
    assert catalogue["reach"]["angle"] == "shoulder_flexion"
    assert "forward raise" in catalogue["reach"]["instruction"]


def test_a_therapist_prescribes_changes_and_ends_a_program(alice, bob):
    patient = alice.patient("Programme Patient")
    http = alice.http
    answer = http.post(f"/api/patients/{patient['id']}/programs", json={
        "name": "After the fracture", "start_date": "2026-12-01", "end_date": "2027-01-31",
        "note": "twice a day if you can", "exercises": [ELBOW, REACH]})
    assert answer.status_code == 201, answer.text
    program = answer.json()
    v1 = program["version"]
    assert v1["number"] == 1 and [e["exercise"] for e in v1["exercises"]] == [
        "elbow_flexion", "reach"]
    assert v1["exercises"][0]["target"] == [0, 120]
    assert v1["exercises"][0]["target_source"] == "program"
    # reach has no target of its own: the catalogue's until the patient has one
    assert v1["exercises"][1]["target_source"] == "catalogue"
    put = http.put(f"/api/patients/{patient['id']}/targets/shoulder_flexion",
                   json={"min_deg": 0, "max_deg": 95})
    assert put.status_code == 200
    again = http.get(f"/api/programs/{program['id']}").json()
    assert again["version"]["exercises"][1]["target"] == [0, 95]
    assert again["version"]["exercises"][1]["target_source"] == "patient"

    # a change is a new version; the first stays as it was
    changed = http.put(f"/api/programs/{program['id']}", json={
        "start_date": "2026-12-01", "exercises": [{**ELBOW, "sets": 4}]})
    assert changed.status_code == 200, changed.text
    assert changed.json()["version"]["number"] == 2
    versions = http.get(f"/api/programs/{program['id']}/versions").json()
    assert [v["number"] for v in versions] == [1, 2]
    assert [len(v["exercises"]) for v in versions] == [2, 1]
    assert versions[0]["exercises"][0]["sets"] == 3 and versions[1]["exercises"][0]["sets"] == 4

    listed = http.get(f"/api/patients/{patient['id']}/programs").json()
    assert [p["id"] for p in listed] == [program["id"]]
    ended = http.post(f"/api/programs/{program['id']}/end").json()
    assert ended["ended_at"] is not None and ended["active"] is False

    # the name is the patient's: a second program of that name is a conflict
    twice = http.post(f"/api/patients/{patient['id']}/programs", json={
        "name": "After the fracture", "start_date": "2026-12-01", "exercises": [ELBOW]})
    assert twice.status_code == 409 and "already" in twice.json()["detail"]

    # another therapist: as if nothing existed
    for method, path in (("GET", f"/api/programs/{program['id']}"),
                         ("GET", f"/api/programs/{program['id']}/versions"),
                         ("POST", f"/api/programs/{program['id']}/end")):
        assert bob.http.request(method, path).status_code == 404
    assert bob.http.get(f"/api/patients/{patient['id']}/programs").status_code == 404


@pytest.mark.parametrize(("change", "words"), [
    ({"exercises": [{**ELBOW, "exercise": "juggling"}]}, "unknown exercise 'juggling'"),
    ({"exercises": [ELBOW, ELBOW]}, "prescribed twice: elbow_flexion"),
    ({"exercises": [{**ELBOW, "target_max_deg": None}]}, "give both target_min_deg"),
    ({"exercises": [{**ELBOW, "target_min_deg": 130}]}, "must be below target_max_deg"),
    ({"exercises": [{**ELBOW, "days_per_week": 8}]}, "less than or equal to 7"),
    ({"exercises": []}, "at least 1 item"),
    ({"end_date": "2026-11-01"}, "is before start_date"),
])
def test_a_bad_prescription_is_refused_whole_naming_the_fault(alice, change, words):
    patient = alice.patient("Refused")
    body = {"name": "p", "start_date": "2026-12-01", "exercises": [ELBOW], **change}
    answer = alice.http.post(f"/api/patients/{patient['id']}/programs", json=body)
    assert answer.status_code == 422, answer.text
    assert words in answer.text
    assert alice.http.get(f"/api/patients/{patient['id']}/programs").json() == []


def test_a_start_date_centuries_back_is_refused_not_listed_week_by_week(alice):
    # a year mistyped (0001 for 2026) made a program whose adherence listed every week
    # since: 105,000 weeks, 23.6 MB in 7.5 s for each adherence and progress PDF read
    patient = alice.patient("Mistyped year")
    body = {"name": "p", "start_date": "0001-12-01", "exercises": [ELBOW]}
    answer = alice.http.post(f"/api/patients/{patient['id']}/programs", json=body)
    if answer.status_code == 201:
        adherence = alice.http.get(f"/api/programs/{answer.json()['id']}/adherence")
        print(f"\naccepted: adherence of {len(adherence.json()['weeks'])} weeks, "
              f"{len(adherence.content) / 1e6:.1f} MB in {adherence.elapsed.total_seconds():.1f} s")
    assert answer.status_code == 422, answer.text[:200]
    assert "start_date 0001-12-01 is more than 10 years ago" in answer.text
    assert alice.http.get(f"/api/patients/{patient['id']}/programs").json() == []
    # ten years back is still a program (one kept on paper, entered late), its weeks listed
    ten = date.today().replace(year=date.today().year - 10) + timedelta(days=1)
    kept = alice.http.post(f"/api/patients/{patient['id']}/programs",
                           json={**body, "start_date": ten.isoformat()})
    assert kept.status_code == 201, kept.text
    weeks = alice.http.get(f"/api/programs/{kept.json()['id']}/adherence").json()["weeks"]
    assert 520 <= len(weeks) <= 524, len(weeks)
    # and a change to a program is held to the same
    changed = alice.http.put(f"/api/programs/{kept.json()['id']}",
                             json={"start_date": "1926-12-01", "exercises": [ELBOW]})
    assert changed.status_code == 422 and "more than 10 years ago" in changed.text


def test_the_start_dates_bound_reads_the_servers_clock(tmp_path):
    # "today" is the server's clock (server/clock.py: a test runs the server on a
    # simulated calendar); the ten-years-back bound read the machine's date instead, so on
    # a calendar of 2012 a program starting in 2010 was refused as "more than 10 years ago"
    from server_support import Zygote, ZygoteServerProcess

    zygote = Zygote("import datetime as _dt, armtrack.server.clock as _clock\n"
                    "_clock.now = lambda: _dt.datetime(2012, 6, 1, 9, 0, tzinfo=_dt.UTC)\n")
    server = ZygoteServerProcess(tmp_path / "server", zygote)
    try:
        server.create_user("alice")
        server.start()
        alice = server.client("alice")
        patient = alice.patient("On a 2012 calendar")
        answers = {start: alice.http.post(f"/api/patients/{patient['id']}/programs", json={
            "name": "p", "start_date": start, "exercises": [ELBOW]})
            for start in ("2010-01-04", "2002-05-31")}
        print({start: (a.status_code, a.text[:120]) for start, a in answers.items()})
        assert answers["2010-01-04"].status_code == 201, answers["2010-01-04"].text
        assert answers["2002-05-31"].status_code == 422
        assert "the earliest is 2002-06-01" in answers["2002-05-31"].text
    finally:
        server.stop()
        zygote.close()
