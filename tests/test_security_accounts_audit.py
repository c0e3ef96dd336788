"""Attacks on the clinic admin's accounts and the audit log (issue 21's screens), against a
real server and database: a reset code must die with the account's disabling; the audit
log's day filters take any day without a 500; a kit (or a therapist) cannot grow the
server's memory or the audit table by varying a query string."""

from __future__ import annotations

import secrets
import time

import httpx
import pytest
from server_support import PASSWORD, ServerProcess

#: East of UTC on 0001-01-01 (local mean time +9:19): the clinic's midnight of that day
#: is before the first moment Python holds in UTC.
FAR_EAST = "Asia/Tokyo"


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("accounts"),
                           env={"ARMTRACK_CLINIC_TIMEZONE": FAR_EAST})
    server.create_user("alice")
    done = server.armtrack("create-user", "root", "--admin", "--password", PASSWORD)
    assert done.returncode == 0, done.stderr
    server.start()
    yield server
    server.stop()


def _id(srv, name: str) -> int:
    return srv.sql("SELECT id FROM therapists WHERE username = :n", n=name)[0][0]


def _sign_in(srv, name: str, password: str) -> int:
    return httpx.post(srv.url + "/api/auth/token",
                      data={"username": name, "password": password}).status_code


def _reset(srv, code: str, password: str) -> httpx.Response:
    return httpx.post(srv.url + "/api/auth/reset", json={"new_password": password},
                      headers={"Authorization": f"Bearer {code}"})


def test_a_reset_code_dies_when_the_account_is_disabled(srv):
    """An admin makes a reset code for carol, then disables carol (she left the clinic).
    Whoever holds the code must not set carol's password — neither while she is disabled
    nor once an admin enables the account again (it would open with the code-holder's
    password)."""
    srv.create_user("carol")
    root = srv.client("root")
    carol = _id(srv, "carol")
    code = root.http.post(f"/api/admin/therapists/{carol}/reset").json()["reset_token"]
    assert root.http.post(f"/api/admin/therapists/{carol}/disable").status_code == 200

    used = _reset(srv, code, "holder-chose-this")
    assert used.status_code == 401, used.text
    assert "ask your admin" in used.json()["detail"]

    assert root.http.post(f"/api/admin/therapists/{carol}/enable").status_code == 200
    assert _reset(srv, code, "holder-chose-this").status_code == 401
    assert _sign_in(srv, "carol", "holder-chose-this") == 401
    assert _sign_in(srv, "carol", PASSWORD) == 200


def test_a_reset_code_dies_when_the_command_line_disables_the_account(srv):
    """The same through ``armtrack create-user NAME --disable`` on the server."""
    srv.create_user("cleo")
    root = srv.client("root")
    cleo = _id(srv, "cleo")
    code = root.http.post(f"/api/admin/therapists/{cleo}/reset").json()["reset_token"]
    done = srv.armtrack("create-user", "cleo", "--disable")
    assert done.returncode == 0, done.stderr
    assert root.http.post(f"/api/admin/therapists/{cleo}/enable").status_code == 200
    assert _reset(srv, code, "holder-chose-this").status_code == 401
    assert _sign_in(srv, "cleo", PASSWORD) == 200


def test_a_reset_code_issued_to_a_disabled_account_waits_for_its_enabling(srv):
    """A code made for a disabled account sets nothing while it is disabled; enabled
    again, the therapist uses it (the admin meant it for their return)."""
    srv.create_user("dora")
    root = srv.client("root")
    dora = _id(srv, "dora")
    assert root.http.post(f"/api/admin/therapists/{dora}/disable").status_code == 200
    code = root.http.post(f"/api/admin/therapists/{dora}/reset").json()["reset_token"]
    refused = _reset(srv, code, "dora-new-password")
    assert refused.status_code == 403, refused.text
    assert "disabled" in refused.json()["detail"]
    assert root.http.post(f"/api/admin/therapists/{dora}/enable").status_code == 200
    assert _reset(srv, code, "dora-new-password").status_code == 204
    assert _sign_in(srv, "dora", "dora-new-password") == 200


def test_a_reset_code_dies_when_the_therapist_changes_their_password(srv):
    """A therapist who learns that a reset code of theirs went astray (read over a
    shoulder, a chat message forwarded) changes their password. The code must not set it
    again after them: it stayed good for its 24 h, and whoever held it chose the password
    the therapist's next sign-in needed (att19)."""
    srv.create_user("hana")
    root = srv.client("root")
    hana = _id(srv, "hana")
    code = root.http.post(f"/api/admin/therapists/{hana}/reset").json()["reset_token"]
    changed = srv.client("hana").http.post("/api/auth/password", json={
        "old_password": PASSWORD, "new_password": "hana-chose-this"})
    assert changed.status_code == 204, changed.text
    used = _reset(srv, code, "holder-chose-this")
    assert used.status_code == 401, used.text
    assert "ask your admin" in used.json()["detail"]
    assert _sign_in(srv, "hana", "holder-chose-this") == 401
    assert _sign_in(srv, "hana", "hana-chose-this") == 200


def test_who_opened_closed_or_changed_an_account_is_in_the_audit_log(srv):
    """An admin who enables a departed therapist's account again (their patients stay
    with it) lets its holder read those patients: the log showed the account's views but
    not that, when or by whom it was opened again; nor who made an account (a second
    admin's too), closed one, or changed its password. Now each is an entry: the admin
    (or the therapist) acting, the account in the route, the address (att19)."""
    root = srv.client("root")
    made = root.http.post("/api/admin/therapists", json={"username": "ivy",
                                                         "password": PASSWORD})
    assert made.status_code == 201, made.text
    ivy = made.json()["id"]
    for step in ("disable", "enable"):
        answer = root.http.post(f"/api/admin/therapists/{ivy}/{step}")
        assert answer.status_code == 200, answer.text
    changed = srv.client("ivy").http.post("/api/auth/password", json={
        "old_password": PASSWORD, "new_password": "ivy-chose-this"})
    assert changed.status_code == 204, changed.text
    root_id = _id(srv, "root")
    entries = [(e["action"], e["therapist_id"], e["route"], e["client"])
               for e in reversed(root.http.get("/api/audit").json())
               if e["action"].endswith(("_account", "_password"))
               and (str(ivy) in e["route"] or e["therapist_id"] == ivy)]
    print("\n", entries)
    assert entries == [
        ("created_account", root_id, f"POST /api/admin/therapists (account {ivy})",
         "127.0.0.1"),
        ("disabled_account", root_id, f"POST /api/admin/therapists/{ivy}/disable",
         "127.0.0.1"),
        ("enabled_account", root_id, f"POST /api/admin/therapists/{ivy}/enable",
         "127.0.0.1"),
        ("changed_password", ivy, "POST /api/auth/password", "127.0.0.1")], entries
    ivy_api = srv.client("ivy", "ivy-chose-this")  # she sees her own change
    assert [e["action"] for e in ivy_api.http.get("/api/audit").json()] == \
        ["changed_password"]


def test_an_account_made_or_disabled_on_the_command_line_is_in_the_audit_log(srv):
    """``armtrack create-user`` (and ``--disable``) wrote no entry, where an admin's same
    change on the Clinic accounts page does (att19): an account made on the server's
    command line signed in and read patients with no entry of who made it, or when. Now
    each is an entry: the command, the account, the operating-system user who ran it."""
    import getpass
    root = srv.client("root")
    made = root.http.post("/api/admin/therapists", json={"username": "uma",
                                                         "password": PASSWORD})
    assert made.status_code == 201, made.text
    done = srv.armtrack("create-user", "uma", "--disable")
    assert done.returncode == 0, done.stderr
    alice, uma = _id(srv, "alice"), made.json()["id"]

    def entries(action: str, account: int) -> list[tuple]:
        return [(e["therapist_id"], e["route"], e["client"], e["actor"])
                for e in root.http.get("/api/audit", params={"action": action}).json()
                if e["route"].endswith(f"(account {account})")]
    by = f"{getpass.getuser()} (operating-system user)"
    command = "armtrack create-user (command line)"
    # alice was made by the module's server fixture, with create-user
    assert entries("created_account", alice) == [
        (None, f"armtrack create-user alice (account {alice})", by, command)]
    assert entries("disabled_account", uma) == [
        (None, f"armtrack create-user uma --disable (account {uma})", by, command)]


@pytest.mark.parametrize("params", [
    {"to_date": "9999-12-31"},          # the day after it is beyond Python's dates
    {"from_date": "0001-01-01"},        # its midnight at +9:19 is before year 1 in UTC
    {"from_date": "0001-01-01", "to_date": "9999-12-31"},
])
def test_the_audit_log_takes_the_first_and_last_days_there_are(srv, params):
    alice = srv.client("alice")
    patient = alice.patient("Edge Days")
    assert alice.http.get(f"/api/patients/{patient['id']}").status_code == 200
    deadline = time.monotonic() + 10
    while True:  # an entry is written just after its request's answer
        answer = alice.http.get("/api/audit", params={**params, "patient_id": patient["id"]})
        assert answer.status_code == 200, answer.text
        if answer.json() or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    assert [e["action"] for e in answer.json()] == ["viewed"]
    csv = alice.http.get("/api/audit", params={**params, "format": "csv"})
    assert csv.status_code == 200, csv.text


def _rss_kib(pid: int) -> int:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise AssertionError("no VmRSS")


def test_query_strings_neither_grow_the_server_nor_the_audit_log(srv):
    """The audit log writes a repeated view once a minute (``ARMTRACK_AUDIT_REPEAT_S``):
    its entry names the route without its query, so a query string makes no new entry
    and is not kept. Was: each distinct query string was a new entry and stayed in the
    server's memory for the minute, whole — a kit asking ``/api/device/today?<16 kB of
    noise>`` 1,500 times wrote 1,500 entries and grew the server by ~30 MB (a kit's token
    sits on a patient's phone)."""
    alice = srv.client("alice")
    patient = alice.patient("Noisy Kit")
    kit = alice.device(patient["id"], "phone")
    token = kit["token"]
    pid = srv.process.pid
    noise = secrets.token_hex(8 * 1024)  # 16 kB
    requests = 1500
    with httpx.Client(base_url=srv.url, headers={"Authorization": f"Bearer {token}"},
                      timeout=30) as client:
        assert client.get("/api/device/today").status_code == 200
        time.sleep(0.5)
        before = _rss_kib(pid)
        for n in range(requests):
            answer = client.get(f"/api/device/today?n={n}&x={noise}")
            assert answer.status_code == 200, answer.text[:200]
    time.sleep(0.5)
    grown_mb = (_rss_kib(pid) - before) / 1024
    rows = srv.sql("SELECT count(*) FROM audit_log WHERE device_id = :d", d=kit["id"])
    print(f"\n{requests} device reads with 16 kB query strings: server grew {grown_mb:.1f} MB, "
          f"{rows[0][0]} audit entries")
    assert rows[0][0] == 1
    assert grown_mb < 10, f"the server grew {grown_mb:.1f} MB"



def test_repeated_live_feeds_are_logged_once_a_minute(srv):
    """Opening ``/ws/live`` wrote one ``viewed_live`` entry every time, with no repeat
    window: one signed-in therapist (or a stolen token) opening and closing a feed in a
    loop wrote 200 entries in about 2 s, each a commit of the database, without bound.
    A repeated view of the same patient's feed is logged once a minute like a repeated
    REST view (``ARMTRACK_AUDIT_REPEAT_S``); another patient's is its own entry."""
    import asyncio

    from websockets.asyncio.client import connect

    alice = srv.client("alice")
    first, second = alice.patient("Watched Often"), alice.patient("Watched Once")

    async def open_feeds(patient_id: int, times: int) -> None:
        for _ in range(times):
            async with connect(f"ws://127.0.0.1:{srv.port}/ws/live?patient={patient_id}",
                               additional_headers={"Authorization": f"Bearer {alice.token}"}):
                pass

    asyncio.run(open_feeds(first["id"], 200))
    asyncio.run(open_feeds(second["id"], 3))
    rows = dict(srv.sql("SELECT patient_id, count(*) FROM audit_log WHERE action = "
                        "'viewed_live' AND patient_id IN (:a, :b) GROUP BY patient_id",
                        a=first["id"], b=second["id"]))
    print(f"\n200 feeds of one patient, 3 of another: viewed_live entries {rows}")
    assert rows == {first["id"]: 1, second["id"]: 1}, rows


def test_a_reset_code_sets_a_password_once_when_sent_many_times_at_once(srv):
    """A code sent 8 times at once (two tabs, a double click, or its holder racing the
    therapist): each request read it unused, hashed its password, then marked it used,
    so several were 204 and the last one's password stood. Exactly one is 204, the others
    401, and the account opens with that one's password only."""
    import concurrent.futures

    srv.create_user("rita")
    root = srv.client("root")
    rita = _id(srv, "rita")
    for attempt in range(3):
        code = root.http.post(f"/api/admin/therapists/{rita}/reset").json()["reset_token"]
        passwords = [f"race-{attempt}-{k}-{secrets.token_hex(4)}" for k in range(8)]
        with concurrent.futures.ThreadPoolExecutor(8) as pool:
            answers = list(pool.map(lambda p, c=code: httpx.post(
                srv.url + "/api/auth/reset", json={"new_password": p}, timeout=120,
                headers={"Authorization": f"Bearer {c}"}), passwords))
        codes = [a.status_code for a in answers]
        print(f"attempt {attempt}: {codes}")
        assert sorted(codes) == [204] + [401] * 7, codes
        (winner,) = [p for p, a in zip(passwords, answers, strict=True) if a.status_code == 204]
        loser = next(p for p in passwords if p != winner)  # one: failures slow sign-in
        assert _sign_in(srv, "rita", loser) == 401
        assert _sign_in(srv, "rita", winner) == 200


def test_a_password_reset_is_in_the_audit_log_with_its_address(srv):
    """An admin's reset code sets the therapist's password: the admin who holds it could
    use it themself, sign in as the therapist and read their patients (an admin holds
    none), and the log then showed only the therapist's views: neither issuing nor using
    a reset was written. Now both are, each with its actor and address, so the admin's
    audit page and the therapist's own show who reset the account, from where, and when
    the views under that account began."""
    srv.create_user("tess")
    root = srv.client("root")
    tess_id = _id(srv, "tess")
    code = root.http.post(f"/api/admin/therapists/{tess_id}/reset").json()["reset_token"]
    used = httpx.post(srv.url + "/api/auth/reset", json={"new_password": "chosen by whom"},
                      headers={"Authorization": f"Bearer {code}"})
    assert used.status_code == 204, used.text
    root_id = _id(srv, "root")
    entries = root.http.get("/api/audit").json()
    issued = [e for e in entries if e["action"] == "issued_reset"
              and e["route"].endswith(f"/{tess_id}/reset")]
    reset = [e for e in entries if e["action"] == "reset_password"
             and e["therapist_id"] == tess_id]
    print("\n", issued[:1], reset[:1])
    assert [(e["therapist_id"], e["route"]) for e in issued] == [
        (root_id, f"POST /api/admin/therapists/{tess_id}/reset")], issued
    assert [(e["therapist_id"], e["client"]) for e in reset] == [(tess_id, "127.0.0.1")], reset
    tess = srv.client("tess", "chosen by whom")
    assert [e["action"] for e in tess.http.get("/api/audit").json()
            if e["action"] == "reset_password"] == ["reset_password"]

