"""``GET /api/audit`` as the dashboard's audit page uses it (issue 21): a therapist sees
the trail of their own patients — whoever acted: they, the patient's kit, the admin who
reassigned the patient to them, a former therapist — and their own actions; another
therapist sees none of it; each entry names its actor in words; ``from_date``/``to_date``
are days of the clinic's time zone. Real server, on SQLite and PostgreSQL."""

from __future__ import annotations

import time
from datetime import UTC, datetime, timedelta
from zoneinfo import ZoneInfo

import pytest
from conftest import _database_env
from server_support import ServerProcess


def clinic_zone_off_utc_date() -> str:
    """A zone whose calendar day differs from UTC's right now (so that a day read in UTC
    instead of the clinic's zone picks the wrong entries)."""
    return "Pacific/Pago_Pago" if datetime.now(UTC).hour < 11 else "Pacific/Kiritimati"


@pytest.fixture(scope="module", params=["sqlite", "postgres"])
def srv(tmp_path_factory, request):
    """alice, bob and the admin root; the clinic in a zone whose day is not UTC's; on
    SQLite and on PostgreSQL (which compare moments differently)."""
    zone = clinic_zone_off_utc_date()
    server = ServerProcess(tmp_path_factory.mktemp("audit"),
                           env={"ARMTRACK_CLINIC_TIMEZONE": zone, **_database_env(request)})
    server.create_user("alice")
    server.create_user("bob")
    server.create_admin("root")
    server.start()
    server.zone = zone
    yield server
    server.stop()


def entries(client, **params) -> list[dict]:
    answer = client.http.get("/api/audit", params=params)
    assert answer.status_code == 200, answer.text
    return answer.json()


def entries_once(client, done, **params) -> list[dict]:
    """The entries once ``done(entries)`` holds: an entry is written just after its
    request's answer is sent."""
    deadline = time.monotonic() + 10
    while not done(found := entries(client, **params)) and time.monotonic() < deadline:
        time.sleep(0.1)
    return found


def test_a_therapist_sees_their_patients_trail_whoever_acted(srv):
    alice, bob, root = srv.client("alice"), srv.client("bob"), srv.client("root")
    ids = {name: c.http.get("/api/me").json()["id"] for name, c in
           (("alice", alice), ("bob", bob), ("root", root))}
    bob.http.patch("/api/me", json={"full_name": "Dr Bob Stone"})
    patient = alice.patient("Trail Patient")
    assert alice.http.get(f"/api/patients/{patient['id']}").status_code == 200
    assert bob.http.get(f"/api/patients/{patient['id']}").status_code == 404  # not logged
    assert entries(bob, patient_id=patient["id"]) == []

    # the admin gives the patient to bob: bob now sees alice's views and the reassignment
    moved = root.http.post(f"/api/admin/patients/{patient['id']}/reassign",
                           json={"therapist_id": ids["bob"]})
    assert moved.status_code == 200, moved.text
    assert bob.http.get(f"/api/patients/{patient['id']}").status_code == 200
    expected = {("alice", "viewed"), ("root", "reassigned"), ("Dr Bob Stone (bob)", "viewed")}
    trail = entries_once(bob, lambda found: expected <= {(e["actor"], e["action"])
                                                         for e in found},
                         patient_id=patient["id"])
    seen = {(e["actor"], e["action"]) for e in trail}
    assert expected <= seen, seen
    assert [e["id"] for e in trail] == sorted((e["id"] for e in trail), reverse=True)
    # alice keeps her own actions (ids only), not the patient's later trail
    hers = entries(alice, patient_id=patient["id"])
    assert hers and all(e["therapist_id"] == ids["alice"] for e in hers)
    # the filters: by actor, by action
    assert {e["actor"] for e in entries(bob, patient_id=patient["id"],
                                        therapist_id=ids["root"])} == {"root"}
    assert {e["action"] for e in entries(bob, action="reassigned")} == {"reassigned"}
    # the CSV stays ids only: no actor's or patient's name
    csv_text = bob.http.get("/api/audit", params={"format": "csv"}).text
    assert "Trail Patient" not in csv_text and "Dr Bob Stone" not in csv_text
    assert csv_text.splitlines()[0] == ("id,at,therapist_id,device_id,action,patient_id,"
                                        "session_id,route,client")


def test_dates_are_days_of_the_clinics_calendar(srv):
    alice = srv.client("alice")
    patient = alice.patient("Dated Patient")
    today = datetime.now(ZoneInfo(srv.zone)).date()
    assert today != datetime.now(UTC).date(), "the test needs a zone off UTC's day"
    print(f"\nclinic zone {srv.zone}: its today is {today}, UTC's "
          f"{datetime.now(UTC).date()}")
    assert alice.http.get(f"/api/patients/{patient['id']}").status_code == 200
    mine = entries_once(alice, bool, patient_id=patient["id"])
    assert mine
    assert entries(alice, patient_id=patient["id"], from_date=today.isoformat(),
                   to_date=today.isoformat()) == mine
    yesterday, tomorrow = today - timedelta(days=1), today + timedelta(days=1)
    assert entries(alice, patient_id=patient["id"], to_date=yesterday.isoformat()) == []
    assert entries(alice, patient_id=patient["id"], from_date=tomorrow.isoformat()) == []
    # paging, over entries this test makes itself (the module's other tests may have run
    # in another process: pytest -n)
    other = alice.patient("Paged Patient")
    assert alice.http.get(f"/api/patients/{other['id']}").status_code == 200
    assert entries_once(alice, bool, patient_id=other["id"])
    all_mine = entries(alice)
    assert len(all_mine) >= 2
    assert entries(alice, limit=1, offset=1) == all_mine[1:2]


@pytest.mark.parametrize("params,what", [({"from_date": "yesterday"}, "from_date"),
                                         ({"to_date": "2026-13-01"}, "to_date"),
                                         ({"action": "x" * 25}, "action"),
                                         ({"limit": 0}, "limit")])
def test_bad_filters_are_named(srv, params, what):
    answer = srv.client("alice").http.get("/api/audit", params=params)
    assert answer.status_code == 422
    assert what in answer.text
