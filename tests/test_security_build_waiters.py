"""Requests waiting for a session's report or summary build cannot take the server's
worker threads and (PostgreSQL) database connections from everyone else.

The finding (att18): a request for a summary or report not kept yet waits for its build
(``server/builds.py``: one per session, two at once), holding one of the 40 worker threads
and, on PostgreSQL, its database connection (pool 5 + 10) while it waits. One therapist's
45 requests for one session's summary, its build slow, held them all: another therapist's
plain ``GET /api/patients`` waited for the whole build (and, past the pool's 30-s wait,
failed). A test hook holds the build (``_summarise``) until the test lets it go, so the
waiters are certain however fast the machine."""

from __future__ import annotations

import asyncio
import os
import tempfile
import time
from pathlib import Path

import httpx
import pytest
from armtrack.estimator.recording import format_recording
from armtrack.estimator.simulation import SimulationConfig, simulate
from armtrack.server.builds import PER_CALLER
from conftest import fresh_postgres_database
from server_support import ServerProcess

#: While ``BUILD_GATE/hold-<session id>`` exists, that session's summary build (or, with
#: ``hold-report-<session id>``, its report's build; ``hold-programs-<patient id>``, its
#: programs' adherence; ``hold-flags-<patient id>``, the flags of their therapist) says so
#: (``reached-…``) and waits until the file is gone. Each request counted in for a build
#: (``Builds._enter``) says how many its caller then has building or waiting
#: (``counted-<kind>-<id>-<n>``).
BUILD_GATE = Path(tempfile.mkdtemp(prefix="armtrack-build-gate-"))
GATE_HOOK = """
import os as _os, sys as _sys, threading as _threading, time as _time
from pathlib import Path as _Path


def _install(gate):
    while True:
        module = _sys.modules.get("armtrack.server.api.session_summary")
        if module is not None and hasattr(module, "_summarise"):
            break
        _time.sleep(0.1)
    original = module._summarise

    def wait(name):
        hold = gate / f"hold-{name}"
        if hold.exists():
            (gate / f"reached-{name}").touch()
            deadline = _time.monotonic() + 120
            while hold.exists() and _time.monotonic() < deadline:
                _time.sleep(0.01)

    def gated(db, session, key):
        wait(session.id)
        return original(db, session, key)
    module._summarise = gated
    builds = _sys.modules["armtrack.server.builds"]  # (session_summary imports it)
    enter = builds.Builds._enter

    def counted(self, who):
        enter(self, who)
        with self._lock:
            n = self._callers.get(who, 0)
        (gate / f"counted-{who[0]}-{who[1]}-{n}").touch()
    builds.Builds._enter = counted

    import armtrack.server.reports.content as content
    build_report = content.build_report

    def gated_report(data, targets):
        wait(f"report-{data.session.id}")
        return build_report(data, targets)
    content.build_report = gated_report

    import armtrack.server.programs.adherence as adherence
    programs_progress = adherence.patient_programs_progress

    def gated_programs(db, patient, *args, **kwargs):
        wait(f"programs-{patient.id}")
        return programs_progress(db, patient, *args, **kwargs)
    adherence.patient_programs_progress = gated_programs
    flags_by_patient = adherence.flags_by_patient

    def gated_flags(db, patients, *args, **kwargs):
        for patient_id in patients:
            wait(f"flags-{patient_id}")
        return flags_by_patient(db, patients, *args, **kwargs)
    adherence.flags_by_patient = gated_flags


if _os.environ.get("TEST_BUILD_GATE"):
    _threading.Thread(target=_install, args=(_Path(_os.environ["TEST_BUILD_GATE"]),),
                      daemon=True).start()
"""
(BUILD_GATE / "hook").mkdir()
(BUILD_GATE / "hook" / "sitecustomize.py").write_text(GATE_HOOK)

#: Requests of one account at once for a summary being built: more than the 40 threads.
FLOOD = 45


@pytest.fixture(scope="module")
def server(tmp_path_factory, postgres_url):
    process = ServerProcess(tmp_path_factory.mktemp("build_waiters"), {
        "ARMTRACK_DATABASE_URL": fresh_postgres_database(postgres_url),
        "TEST_BUILD_GATE": str(BUILD_GATE),
        "PYTHONPATH": os.pathsep.join(filter(None, [str(BUILD_GATE / "hook"),
                                                    os.environ.get("PYTHONPATH")]))})
    for user in ("alice", "carol"):
        process.create_user(user)
    process.create_admin("root")
    process.start()
    yield process
    process.stop()


def _session(api) -> dict:
    patient = api.patient(name="Waits")
    recording = simulate(SimulationConfig(exercise="elbow_flexion", repetitions=1)).recording
    answer = api.http.post("/api/recordings", data={"patient_id": patient["id"]},
                           files={"file": ("s.csv", format_recording(recording), "text/csv")})
    assert answer.status_code == 201, answer.text
    return answer.json()


def test_one_accounts_waiting_builds_leave_threads_and_connections_to_others(server):
    alice, carol = server.client("alice"), server.client("carol")
    held, own = _session(alice), _session(carol)
    hold = BUILD_GATE / f"hold-{held['id']}"

    async def run() -> tuple[list[httpx.Response], float, httpx.Response, float, int]:
        limits = httpx.Limits(max_connections=FLOOD + 5, max_keepalive_connections=FLOOD + 5)
        async with httpx.AsyncClient(base_url=server.url, timeout=120, limits=limits,
                                     headers={"Authorization": f"Bearer {alice.token}"}
                                     ) as http, \
                httpx.AsyncClient(base_url=server.url, timeout=60, headers={
                    "Authorization": f"Bearer {carol.token}"}) as other:
            hold.touch()
            try:
                flood = [asyncio.ensure_future(http.get(f"/api/sessions/{held['id']}/summary"))
                         for _ in range(FLOOD)]
                deadline = time.monotonic() + 30
                while not (BUILD_GATE / f"reached-{held['id']}").exists():
                    assert time.monotonic() < deadline, "the held build never began"
                    await asyncio.sleep(0.02)
                # the refused come back at once; before, none did: wait for them (or 3 s)
                deadline = time.monotonic() + 3
                while sum(f.done() for f in flood) < FLOOD - 4 and time.monotonic() < deadline:
                    await asyncio.sleep(0.02)
                answered_early = sum(f.done() for f in flood)
                began = time.monotonic()
                plain = await other.get("/api/patients")
                plain_s = time.monotonic() - began
                began = time.monotonic()
                summary = await other.get(f"/api/sessions/{own['id']}/summary")
                summary_s = time.monotonic() - began
            finally:
                hold.unlink()
            return await asyncio.gather(*flood), plain_s, summary, summary_s, answered_early, \
                plain
    answers, plain_s, summary, summary_s, early, plain = asyncio.run(run())
    statuses = sorted(a.status_code for a in answers)
    print(f"\n{FLOOD} of alice's summary requests waiting: {early} answered at once "
          f"({statuses.count(429)} 429); carol's patients list {plain_s:.2f} s, "
          f"her own summary {summary_s:.2f} s")
    assert plain.status_code == 200, plain.text
    assert summary.status_code == 200, summary.text
    assert plain_s < 2 and summary_s < 5, (plain_s, summary_s)
    refused = [a for a in answers if a.status_code == 429]
    assert refused and set(statuses) == {200, 429}, statuses
    assert refused[0].headers["Retry-After"].isdigit()
    assert "at once" in refused[0].json()["detail"], refused[0].text
    # once the build is done, the account's summary is there as for anyone
    assert alice.http.get(f"/api/sessions/{held['id']}/summary").status_code == 200


def test_a_page_refused_for_builds_at_once_asks_again_when_told(server):
    """The account already has 4 requests waiting for a build (its other tabs on a cold
    server): the session page's summary is refused (429, Retry-After: 5). The page asks
    again after the time the server gave and shows the session; before, it showed
    'ask again in 5 s' in a card the therapist could only reload (review18). 390 px."""
    from browser_helpers import need_browser, page_at, sign_in_as
    need_browser()

    alice = server.client("alice")
    held, shown = _session(alice), _session(alice)
    hold = BUILD_GATE / f"hold-{held['id']}"
    refused: list[int] = []

    async def waiters() -> list[httpx.Response]:
        async with httpx.AsyncClient(base_url=server.url, timeout=120, headers={
                "Authorization": f"Bearer {alice.token}"}) as http:
            return await asyncio.gather(*(http.get(f"/api/sessions/{held['id']}/summary")
                                          for _ in range(4)))

    import threading
    results: list = []
    for stale in BUILD_GATE.glob("counted-*"):  # the test before's
        stale.unlink()
    hold.touch()
    thread = threading.Thread(target=lambda: results.extend(asyncio.run(waiters())))
    try:
        thread.start()
        deadline = time.monotonic() + 30
        while not (BUILD_GATE / f"reached-{held['id']}").exists():
            assert time.monotonic() < deadline, "the held build never began"
            time.sleep(0.02)
        # all four are counted in (the other three waiting for the held build): the
        # page's next summary is the account's fifth
        while not any(BUILD_GATE.glob(f"counted-therapist-*-{PER_CALLER}")):
            assert time.monotonic() < deadline, "the four requests were never all counted"
            time.sleep(0.02)
        with page_at(390) as page:
            sign_in_as(page, server.url, "alice")

            def seen(response):
                if response.url.endswith(f"/api/sessions/{shown['id']}/summary") \
                        and response.status == 429:
                    refused.append(response.status)
                    hold.unlink(missing_ok=True)  # the other tabs' builds come
            page.on("response", seen)
            page.goto(f"{server.url}/sessions/{shown['id']}")
            try:
                page.wait_for_selector("#angles-card h2:has-text('Range of motion')",
                                       timeout=20_000)
            finally:
                text = page.inner_text("main")
                print(f"\nrefused {len(refused)} time(s); the page: {text[:400]!r}")
    finally:
        hold.unlink(missing_ok=True)
        thread.join(60)
    assert refused, "the page's summary was never refused: the test proved nothing"
    assert "at once" not in text, text
    assert [r.status_code for r in results] == [200] * 4


def _held_answer(server, api, path: str, name: str, meanwhile) -> httpx.Response:
    """``api``'s GET of ``path`` with its build held (``hold-<name>``) until
    ``meanwhile()`` has run."""
    import threading
    hold = BUILD_GATE / f"hold-{name}"
    answers: list[httpx.Response] = []
    hold.touch()
    asking = threading.Thread(target=lambda: answers.append(api.http.get(path)))
    try:
        asking.start()
        deadline = time.monotonic() + 30
        while not (BUILD_GATE / f"reached-{name}").exists():
            assert time.monotonic() < deadline, "the held build never began"
            time.sleep(0.02)
        meanwhile()
    finally:
        hold.unlink(missing_ok=True)
        asking.join(60)
    return answers[0]


def test_a_summary_built_while_its_patient_is_reassigned_is_not_sent(server):
    """att19's finding: ``/summary`` checked the therapist's right when the request came;
    the patient reassigned to carol while the build ran, alice still got it. Now the right
    is read again when the answer goes, as an export's is: 404."""
    alice, root = server.client("alice"), server.client("root")
    carol = next(t for t in root.http.get("/api/admin/therapists").json()
                 if t["username"] == "carol")
    session = _session(alice)

    def reassign() -> None:
        moved = root.http.post(f"/api/admin/patients/{session['patient_id']}/reassign",
                               json={"therapist_id": carol["id"]})
        assert moved.status_code == 200, moved.text
    answer = _held_answer(server, alice, f"/api/sessions/{session['id']}/summary",
                          str(session["id"]), reassign)
    assert answer.status_code == 404, answer.text[:200]
    assert answer.json()["detail"] == f"no session {session['id']}"


@pytest.mark.parametrize("form", ["report", "report.pdf"])
def test_a_report_built_while_its_sign_in_ends_is_not_sent(server, form):
    """The same for ``/report``, the sign-in ended (signed out) while it was built: 401;
    and for ``report.pdf``, an export sent whole, whose right was read at its turn only."""
    alice = server.client("alice")
    session = _session(alice)
    alice.wait_processed(session["id"])
    other_tab = server.client("alice")
    other_tab.http.headers["Authorization"] = alice.http.headers["Authorization"]

    def sign_out() -> None:
        assert other_tab.http.post("/api/auth/signout").status_code == 204
    answer = _held_answer(server, alice, f"/api/sessions/{session['id']}/{form}",
                          f"report-{session['id']}", sign_out)
    assert answer.status_code == 401, answer.text[:200]
    assert "sign in" in answer.json()["detail"]


def test_a_programs_adherence_made_while_its_patient_is_reassigned_is_not_sent(server):
    """The same for a program's ``/adherence`` (each of its sessions' reports)."""
    alice, root = server.client("alice"), server.client("root")
    carol = next(t for t in root.http.get("/api/admin/therapists").json()
                 if t["username"] == "carol")
    patient = alice.patient(name="Programmed")
    program = alice.http.post(f"/api/patients/{patient['id']}/programs", json={
        "name": "Daily", "start_date": "2026-12-01",
        "exercises": [{"exercise": "elbow_flexion", "sets": 2,
                                        "repetitions": 10, "days_per_week": 5}]})
    assert program.status_code == 201, program.text

    def reassign() -> None:
        moved = root.http.post(f"/api/admin/patients/{patient['id']}/reassign",
                               json={"therapist_id": carol["id"]})
        assert moved.status_code == 200, moved.text
    answer = _held_answer(server, alice, f"/api/programs/{program.json()['id']}/adherence",
                          f"programs-{patient['id']}", reassign)
    assert answer.status_code == 404, answer.text[:200]
    assert answer.json()["detail"].startswith(f"no patient {patient['id']} among yours")


def test_flags_made_while_a_patient_is_reassigned_leave_that_patient_out(server):
    """The therapist's ``/flags`` (every patient's programs): a patient reassigned while
    they were made is left out, as a request made then would leave them."""
    alice, root = server.client("alice"), server.client("root")
    carol = next(t for t in root.http.get("/api/admin/therapists").json()
                 if t["username"] == "carol")
    patient = alice.patient(name="Flagged")  # a program begun long ago, no session: flagged
    program = alice.http.post(f"/api/patients/{patient['id']}/programs", json={
        "name": "Daily", "start_date": "2026-01-05",
        "exercises": [{"exercise": "elbow_flexion", "sets": 2,
                       "repetitions": 10, "days_per_week": 5}]})
    assert program.status_code == 201, program.text
    flagged = [f["patient_id"] for f in alice.http.get("/api/flags").json()]
    assert patient["id"] in flagged, flagged

    def reassign() -> None:
        moved = root.http.post(f"/api/admin/patients/{patient['id']}/reassign",
                               json={"therapist_id": carol["id"]})
        assert moved.status_code == 200, moved.text
    answer = _held_answer(server, alice, "/api/flags", f"flags-{patient['id']}", reassign)
    assert answer.status_code == 200, answer.text[:200]
    assert patient["id"] not in [f["patient_id"] for f in answer.json()], answer.json()
