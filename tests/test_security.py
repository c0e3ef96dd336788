"""The server's protections (issue 9) on real server processes: sign-in rate limits, CORS
closed by default, body size limits, security headers, roles (admin, disable, reassign),
password change and reset, the demo account outside demo mode, `armtrack serve`'s refusal
of unsafe settings, the audit log, the patient's export archive, erasure that leaves no
readable copy in the SQLite files, retention, and revoking a kit mid-stream."""

from __future__ import annotations

import asyncio
import base64
import csv
import hashlib
import io
import json
import re
import shutil
import subprocess
import time
import zipfile
from datetime import UTC, datetime, timedelta

import httpx
import pytest
from server_support import PASSWORD, ServerProcess, armtrack, free_port
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

RECORDING = "left_reach_50hz.csv"
UPLOAD_LIMIT = 200_000


def make_admin(server: ServerProcess, name: str) -> None:
    done = armtrack("create-user", name, "--admin", "--password", PASSWORD,
                    "--data-dir", str(server.data_dir))
    assert done.returncode == 0, done.stderr


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    """alice, bob (therapists) and root (clinic admin); uploads over 200 kB refused; one
    browser origin allowed."""
    server = ServerProcess(tmp_path_factory.mktemp("security"), env={
        "ARMTRACK_MAX_UPLOAD_BYTES": str(UPLOAD_LIMIT),
        "ARMTRACK_CORS_ORIGINS": "https://clinic.example"})
    server.create_user("alice")
    server.create_user("bob")
    make_admin(server, "root")
    server.start()
    yield server
    server.stop()


@pytest.fixture(scope="module")
def recording(recordings_dir):
    return recordings_dir / RECORDING


def upload(api, patient_id, path):
    with open(path, "rb") as f:
        answer = api.http.post("/api/recordings", data={"patient_id": patient_id},
                               files={"file": (path.name, f)})
    return answer


def small_recording(path, tmp_path, rows=1500):
    """The first ``rows`` data lines of a recording: under the upload limit."""
    lines = path.read_text().splitlines(keepends=True)
    header = [line for line in lines if line.startswith("#") or line.startswith("t")]
    data = [line for line in lines if not (line.startswith("#") or line.startswith("t"))]
    small = tmp_path / "small.csv"
    small.write_text("".join(header + data[:rows]))
    return small


def sign_in(server, user, password=PASSWORD, source="127.0.0.1"):
    transport = httpx.HTTPTransport(local_address=source)
    with httpx.Client(transport=transport, base_url=server.url, timeout=30) as http:
        return http.post("/api/auth/token", data={"username": user, "password": password})


# -- sign-in rate limit --------------------------------------------------------------------
def test_sign_in_is_rate_limited_per_user_name_and_per_address(tmp_path):
    server = ServerProcess(tmp_path / "limits")
    server.create_user("alice")
    server.create_user("bob")
    server.start()
    try:
        # ten failures for alice, each from another address: alice is locked
        for i in range(10):
            assert sign_in(server, "alice", "wrong password", f"127.0.0.{10 + i}"
                           ).status_code == 401
        locked = sign_in(server, "alice", PASSWORD, "127.0.0.50")  # the right password too
        assert locked.status_code == 429, locked.text
        assert 1 <= int(locked.headers["Retry-After"]) <= 300
        assert "too many failed sign-ins" in locked.json()["detail"]
        assert sign_in(server, "bob", PASSWORD, "127.0.0.50").status_code == 200
        # ten failures from one address, each for another name: the address is locked
        for i in range(10):
            assert sign_in(server, f"guess{i}", "wrong password", "127.0.0.60"
                           ).status_code == 401
        assert sign_in(server, "bob", PASSWORD, "127.0.0.60").status_code == 429
        assert sign_in(server, "bob", PASSWORD, "127.0.0.61").status_code == 200
    finally:
        server.stop()


# -- CORS, headers, body limits ---------------------------------------------------------------
def preflight(server, origin):
    return httpx.options(server.url + "/api/patients", headers={
        "Origin": origin, "Access-Control-Request-Method": "GET",
        "Access-Control-Request-Headers": "authorization"})


def test_cors_allows_only_the_listed_origins(srv, retention_server):
    allowed = preflight(srv, "https://clinic.example")
    assert allowed.headers.get("access-control-allow-origin") == "https://clinic.example"
    for server, origin in ((srv, "https://evil.example"), (retention_server,
                                                           "https://clinic.example")):
        answer = preflight(server, origin)  # not listed; or no origin listed (the default)
        assert "access-control-allow-origin" not in answer.headers
        simple = httpx.get(server.url + "/api/patients", headers={"Origin": origin})
        assert "access-control-allow-origin" not in simple.headers


def inline_script_hashes(html: str) -> list[str]:
    return ["'sha256-" + base64.b64encode(hashlib.sha256(body.encode()).digest()).decode()
            + "'" for body in re.findall(r"<script(?![^>]*\bsrc=)[^>]*>(.*?)</script>",
                                         html, re.S)]


def test_pages_and_answers_carry_security_headers(srv):
    for path in ("/signin", "/patients", "/patients/1", "/sessions/1"):
        page = httpx.get(srv.url + path)
        assert page.status_code == 200
        csp = page.headers["content-security-policy"]
        assert "default-src 'self'" in csp and "frame-ancestors 'self'" in csp
        assert "frame-src 'self'" in csp and "object-src 'none'" in csp
        assert "'unsafe-inline'" not in csp.split("script-src")[1].split(";")[0]
        for digest in inline_script_hashes(page.text):  # the page's own scripts may run
            assert digest in csp
        assert page.headers["x-frame-options"] == "SAMEORIGIN"
        assert page.headers["referrer-policy"] == "no-referrer"
        assert page.headers["x-content-type-options"] == "nosniff"
    alice = srv.client("alice")
    patient = alice.patient("Headers")
    grant = alice.http.post("/api/viewer", json={"patient_id": patient["id"]}).json()
    viewer = httpx.get(srv.url + grant["url"])
    assert viewer.status_code == 200
    assert "frame-ancestors 'self'" in viewer.headers["content-security-policy"]
    assert viewer.headers["x-frame-options"] == "SAMEORIGIN"
    api = alice.http.get(f"/api/patients/{patient['id']}")
    assert api.headers["cache-control"] == "no-store"
    assert api.headers["x-content-type-options"] == "nosniff"
    assert not any(k.lower() == "set-cookie" for k in api.headers)  # no cookies at all


def test_bodies_over_the_limits_are_refused_with_413(srv, recording):
    alice = srv.client("alice")
    patient = alice.patient("Big upload")
    assert recording.stat().st_size > UPLOAD_LIMIT
    answer = upload(alice, patient["id"], recording)
    assert answer.status_code == 413
    assert "ARMTRACK_MAX_UPLOAD_BYTES" in answer.json()["detail"]
    assert str(UPLOAD_LIMIT) in answer.json()["detail"]
    # chunked, with no Content-Length: refused once the limit is passed
    boundary = "xyzzy"
    head = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"patient_id\"\r\n\r\n"
            f"{patient['id']}\r\n--{boundary}\r\nContent-Disposition: form-data; "
            f"name=\"file\"; filename=\"r.csv\"\r\n\r\n").encode()

    def chunks():
        yield head
        data = recording.read_bytes()
        for i in range(0, len(data), 65536):
            yield data[i:i + 65536]
        yield f"\r\n--{boundary}--\r\n".encode()

    chunked = alice.http.post("/api/recordings", content=chunks(), headers={
        "Content-Type": f"multipart/form-data; boundary={boundary}"})
    assert chunked.status_code == 413, chunked.text
    assert "ARMTRACK_MAX_UPLOAD_BYTES" in chunked.json()["detail"]
    huge = alice.http.post("/api/patients", content=b'{"name": "' + b"x" * (2 << 20) + b'"}',
                           headers={"Content-Type": "application/json"})
    assert huge.status_code == 413 and "ARMTRACK_MAX_BODY_BYTES" in huge.json()["detail"]
    assert alice.http.get("/api/patients", params={"q": "Big upload"}).status_code == 200


# -- roles, passwords, the demo account --------------------------------------------------------
def test_an_admin_manages_therapists_and_reassigns_a_patient(srv):
    root = srv.client("root")
    made = root.http.post("/api/admin/therapists", json={"username": "erin",
                                                         "password": PASSWORD})
    assert made.status_code == 201, made.text
    erin_id = made.json()["id"]
    assert root.http.post("/api/admin/therapists", json={
        "username": "erin", "password": PASSWORD}).status_code == 409
    erin = srv.client("erin")
    patient = erin.patient("Covered")
    names = {t["username"]: t for t in root.http.get("/api/admin/therapists").json()}
    assert names["erin"]["patients"] == 1 and names["root"]["is_admin"]
    # erin is disabled: her token stops working at once, and she cannot sign in
    assert erin.http.get("/api/patients").status_code == 200
    assert root.http.post(f"/api/admin/therapists/{erin_id}/disable").status_code == 200
    assert erin.http.get("/api/patients").status_code == 401
    assert sign_in(srv, "erin").status_code == 403
    # her patient goes to a covering therapist
    bob = srv.client("bob")
    assert bob.http.get(f"/api/patients/{patient['id']}").status_code == 404
    moved = root.http.post(f"/api/admin/patients/{patient['id']}/reassign",
                           json={"therapist_id": names["bob"]["id"]})
    assert moved.status_code == 200 and moved.json()["therapist_id"] == names["bob"]["id"]
    assert bob.http.get(f"/api/patients/{patient['id']}").json()["name"] == "Covered"
    refused = root.http.post(f"/api/admin/patients/{patient['id']}/reassign",
                             json={"therapist_id": erin_id})
    assert refused.status_code == 409  # not to a disabled account
    assert root.http.post(f"/api/admin/therapists/{names['root']['id']}/disable"
                          ).status_code == 409
    assert root.http.post(f"/api/admin/therapists/{erin_id}/enable").status_code == 200
    assert sign_in(srv, "erin").status_code == 200
    # the command line disables too
    done = armtrack("create-user", "erin", "--disable", "--data-dir", str(srv.data_dir))
    assert done.returncode == 0, done.stderr
    assert sign_in(srv, "erin").status_code == 403


def test_a_therapist_changes_their_password_and_an_admin_issues_a_reset(srv):
    root = srv.client("root")
    root.http.post("/api/admin/therapists", json={"username": "fay", "password": PASSWORD})
    fay, elsewhere = srv.client("fay"), srv.client("fay")
    wrong = fay.http.post("/api/auth/password", json={"old_password": "not it",
                                                      "new_password": "fay's new one"})
    assert wrong.status_code == 400
    short = fay.http.post("/api/auth/password", json={"old_password": PASSWORD,
                                                      "new_password": "short"})
    assert short.status_code == 422
    changed = fay.http.post("/api/auth/password", json={"old_password": PASSWORD,
                                                        "new_password": "fay's new one"})
    assert changed.status_code == 204
    assert fay.http.get("/api/patients").status_code == 200  # this sign-in stays
    assert elsewhere.http.get("/api/patients").status_code == 401  # the others end
    assert sign_in(srv, "fay").status_code == 401
    assert sign_in(srv, "fay", "fay's new one").status_code == 200
    # forgotten: the admin issues a one-time reset token
    fay_id = next(t["id"] for t in root.http.get("/api/admin/therapists").json()
                  if t["username"] == "fay")
    issued = root.http.post(f"/api/admin/therapists/{fay_id}/reset")
    assert issued.status_code == 200
    token = issued.json()["reset_token"]
    reset = httpx.post(srv.url + "/api/auth/reset", json={"new_password": "fay's third one"},
                       headers={"Authorization": f"Bearer {token}"})
    assert reset.status_code == 204, reset.text
    assert fay.http.get("/api/patients").status_code == 401  # every sign-in ended
    assert sign_in(srv, "fay", "fay's third one").status_code == 200
    again = httpx.post(srv.url + "/api/auth/reset", json={"new_password": "a fourth one!"},
                       headers={"Authorization": f"Bearer {token}"})
    assert again.status_code == 401  # once only
    with __import__("sqlite3").connect(srv.data_dir / "armtrack.db") as db:
        stored = [r[0] for r in db.execute("SELECT token_hash FROM password_resets")]
    assert token not in stored and hashlib.sha256(token.encode()).hexdigest() in stored


def test_the_demo_account_signs_in_only_in_demo_mode(srv):
    done = armtrack("create-user", "demo", "--password", PASSWORD,
                    "--data-dir", str(srv.data_dir))
    assert done.returncode == 0, done.stderr
    answer = sign_in(srv, "demo")
    assert answer.status_code == 401 and answer.json()["detail"] == "wrong user name or password"
    armtrack("create-user", "demo", "--disable", "--data-dir", str(srv.data_dir))


# -- armtrack serve refuses unsafe settings -----------------------------------------------------
def serve(data_dir, *args, env=None, timeout=60):
    import os
    return subprocess.run([*armtrack_cmd(), "serve", "--port", str(free_port()),
                           "--data-dir", str(data_dir), *args], capture_output=True,
                          text=True, env={**os.environ, **(env or {})}, timeout=timeout)


def armtrack_cmd():
    import sys
    return [sys.executable, "-m", "armtrack.server.cli"]


def test_serve_refuses_unsafe_settings_outside_demo_mode(tmp_path):
    cases = [
        (["--host", "0.0.0.0"], {}, ["ARMTRACK_HOST=0.0.0.0", "ARMTRACK_TLS_CERT",
                                     "ARMTRACK_BEHIND_PROXY"]),
        ([], {"ARMTRACK_CORS_ORIGINS": "*"}, ["ARMTRACK_CORS_ORIGINS"]),
        ([], {"ARMTRACK_TLS_CERT": str(tmp_path / "missing.pem"),
              "ARMTRACK_TLS_KEY": str(tmp_path / "missing.key")}, ["no such file"]),
    ]
    for args, env, words in cases:
        done = serve(tmp_path / "a", *args, env=env)
        assert done.returncode == 2, (args, env, done.stdout, done.stderr)
        assert "refusing to start" in done.stderr
        for word in words:
            assert word in done.stderr, (word, done.stderr)
    # the demo's account in the database: refused until it is disabled
    armtrack("create-user", "demo", "--password", PASSWORD, "--data-dir", str(tmp_path / "d"))
    done = serve(tmp_path / "d")
    assert done.returncode == 2 and "demo account" in done.stderr, done.stderr
    assert "ARMTRACK_DEMO_MODE" in done.stderr


def test_serve_warns_of_compose_placeholder_password_and_plain_http():
    """Found by ops20 reading docker/compose.yaml: PostgreSQL's password falls back to
    ``change-me`` when POSTGRES_PASSWORD is unset, and nothing said so. It is a warning at
    every start, not a refusal: the postgres container took the password when it made its
    database, so an install running on it must change it in the database first (the
    words say how); refusing would stop a clinic's running server at its next upgrade.
    A server others reach over plain http is warned of too (phones need https), unless
    TLS is given or the https address patients' phones use is set. (The wiring into the
    server's log: tests/test_first_run.py.)"""
    from armtrack.server.security import setting_warnings
    from armtrack.server.settings import Settings

    placeholder = "postgresql+psycopg://armtrack:change-me@postgres/armtrack"
    warnings = setting_warnings(Settings(database_url=placeholder))
    assert len(warnings) == 1, warnings
    for words in ("POSTGRES_PASSWORD", "ALTER USER armtrack PASSWORD",
                  "docs/operator.md#postgresql"):
        assert words in warnings[0], (words, warnings[0])
    print("\n" + warnings[0])
    chosen = "postgresql+psycopg://armtrack:Tr0ub4dor@postgres/armtrack"
    assert setting_warnings(Settings(database_url=chosen)) == []
    assert setting_warnings(Settings()) == []  # SQLite on 127.0.0.1

    public = {"host": "0.0.0.0", "behind_proxy": True}
    http = setting_warnings(Settings(**public))
    assert len(http) == 1 and "plain http on 0.0.0.0:8000" in http[0], http
    assert "ARMTRACK_PUBLIC_URL" in http[0] and "Caddy" in http[0]
    print(http[0])
    assert setting_warnings(Settings(**public, public_url="https://rehab.example.org")) == []
    assert len(setting_warnings(Settings(**public, public_url="http://10.0.0.5:8000"))) == 1


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")
def test_serve_speaks_tls_with_a_certificate(tmp_path):
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
                    "-subj", "/CN=localhost", "-keyout", str(key), "-out", str(cert)],
                   check=True, capture_output=True)
    server = ServerProcess(tmp_path / "tls", env={"ARMTRACK_TLS_CERT": str(cert),
                                                  "ARMTRACK_TLS_KEY": str(key)})
    server.process = subprocess.Popen(
        [*armtrack_cmd(), "serve", "--port", str(server.port), "--data-dir",
         str(server.data_dir)], env=server.env, stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                answer = httpx.get(f"https://127.0.0.1:{server.port}/healthz", verify=False)
                break
            except httpx.HTTPError:
                assert time.monotonic() < deadline and server.process.poll() is None
                time.sleep(0.2)
        assert answer.status_code == 200
        assert "max-age" in answer.headers["strict-transport-security"]
    finally:
        server.stop()


# -- the audit log, export, erasure -----------------------------------------------------------
def test_reads_exports_and_erasures_are_in_the_audit_log(srv, recording, tmp_path):
    alice, bob, root = srv.client("alice"), srv.client("bob"), srv.client("root")
    patient = alice.patient("Audited")
    small = small_recording(recording, tmp_path)
    session = upload(alice, patient["id"], small)
    assert session.status_code == 201, session.text
    session = alice.wait_processed(session.json()["id"])
    alice.http.get(f"/api/patients/{patient['id']}")
    alice.http.get(f"/api/sessions/{session['id']}/report")
    alice.http.get(f"/api/sessions/{session['id']}/recording.csv")
    assert alice.http.get(f"/api/patients/{patient['id']}/export").status_code == 200
    device = alice.device(patient["id"])
    kit = httpx.Client(base_url=srv.url, headers={"Authorization": f"Bearer {device['token']}"},
                       timeout=60)
    with open(small, "rb") as f:
        by_kit = kit.post("/api/recordings", files={"file": ("r.csv", f)})
    assert by_kit.status_code == 201
    assert alice.http.delete(f"/api/sessions/{session['id']}").status_code == 204

    deadline = time.monotonic() + 10  # an entry is written just after its answer is sent
    while True:
        mine = alice.http.get("/api/audit", params={"patient_id": patient["id"]}).json()
        seen = {(e["action"], e["session_id"]) for e in mine}
        if ("erased", session["id"]) in seen or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    assert ("viewed", None) in seen and ("viewed", session["id"]) in seen
    assert ("exported", session["id"]) in seen  # recording.csv
    assert ("exported", None) in seen  # the archive
    assert ("erased", session["id"]) in seen and ("uploaded", session["id"]) in seen
    alice_id = alice.http.get("/api/me").json()["id"]
    assert all(e["client"] == "127.0.0.1" for e in mine)
    # the patient's whole trail: their therapist's actions and their kit's upload, named
    assert {(e["therapist_id"], e["device_id"]) for e in mine} == {(alice_id, None),
                                                                  (None, device["id"])}
    assert {e["actor"] for e in mine} == {"alice", f"kit {device['name']}"}
    assert [e["id"] for e in mine] == sorted((e["id"] for e in mine), reverse=True)
    assert all(e["route"].startswith(("GET /api/", "POST /api/", "DELETE /api/"))
               for e in mine)
    # another therapist sees nothing of it; an admin sees everyone's
    assert bob.http.get("/api/audit", params={"patient_id": patient["id"]}).json() == []
    everyone = root.http.get("/api/audit", params={"patient_id": patient["id"]}).json()
    assert {e["device_id"] for e in everyone} >= {device["id"]}
    assert any(e["action"] == "uploaded" and e["device_id"] == device["id"] for e in everyone)
    page = root.http.get("/api/audit", params={"patient_id": patient["id"], "limit": 2,
                                               "offset": 1}).json()
    assert [e["id"] for e in page] == [e["id"] for e in everyone[1:3]]
    exported = root.http.get("/api/audit", params={"patient_id": patient["id"],
                                                   "format": "csv"})
    assert exported.headers["content-type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(exported.text)))
    assert [int(r["id"]) for r in rows] == [e["id"] for e in everyone]
    assert "Audited" not in exported.text  # ids only, never names
    # a view repeated within a minute is logged once (the dashboard polls); one of a
    # patient whose data were read within it (above), not at all: one entry a patient
    polled = alice.patient("Polled")
    before = len(alice.http.get("/api/audit").json())
    for _ in range(3):
        alice.http.get(f"/api/patients/{patient['id']}/live")
        alice.http.get(f"/api/patients/{polled['id']}/live")
    deadline = time.monotonic() + 10  # written just after the answer (was read at once:
    while len(alice.http.get("/api/audit").json()) == before \
            and time.monotonic() < deadline:  # on a busy machine, not yet there)
        time.sleep(0.1)
    time.sleep(0.5)  # the other two, were they written, would be there by now
    after = alice.http.get("/api/audit").json()
    assert len(after) == before + 1 and after[0]["action"] == "viewed"
    assert after[0]["patient_id"] == polled["id"]


def test_the_export_holds_everything_about_the_patient(srv, recording, tmp_path):
    alice = srv.client("alice")
    patient = alice.patient("Exported")
    small = small_recording(recording, tmp_path)
    session = alice.wait_processed(upload(alice, patient["id"], small).json()["id"])
    alice.http.put(f"/api/patients/{patient['id']}/targets/elbow_flexion",
                   json={"min_deg": 0, "max_deg": 130})
    alice.device(patient["id"], "kit one")
    answer = alice.http.get(f"/api/patients/{patient['id']}/export")
    assert answer.status_code == 200
    assert answer.headers["content-type"] == "application/zip"
    archive = zipfile.ZipFile(io.BytesIO(answer.content))
    names = set(archive.namelist())
    folder = f"sessions/{session['id']}/"
    assert {"patient.json", "sessions.json", "devices.json", "targets.json", "audit.json",
            folder + "recording.csv", folder + "angles.csv", folder + "report.json"} <= names
    assert json.loads(archive.read("patient.json"))["name"] == "Exported"
    assert [s["id"] for s in json.loads(archive.read("sessions.json"))] == [session["id"]]
    assert archive.read(folder + "recording.csv").decode() == alice.http.get(
        f"/api/sessions/{session['id']}/recording.csv").text
    assert archive.read(folder + "angles.csv").decode() == alice.http.get(
        f"/api/sessions/{session['id']}/angles.csv").text
    assert "rom" in json.loads(archive.read(folder + "report.json"))
    assert "token" not in archive.read("devices.json").decode()
    audit = json.loads(archive.read("audit.json"))
    assert audit and all(e["patient_id"] == patient["id"] for e in audit)


def test_an_erased_patient_is_not_left_readable_in_the_database_files(srv, recording,
                                                                      tmp_path):
    alice = srv.client("alice")
    name = "Quillon Erasmia Vandersloot"
    patient = alice.patient(name)
    alice.wait_processed(upload(alice, patient["id"], small_recording(recording, tmp_path)
                                ).json()["id"])

    def files_hold(text: bytes) -> bool:
        return any(text in path.read_bytes() for path in srv.data_dir.glob("armtrack.db*"))

    assert files_hold(name.encode())
    assert alice.http.delete(f"/api/patients/{patient['id']}").status_code == 204
    assert not files_hold(name.encode())


# -- retention ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def retention_server(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("retention"), env={
        "ARMTRACK_RETENTION_DAYS": str(3 / 86400),  # 3 s
        "ARMTRACK_RETENTION_CHECK_S": "0.5"})
    server.create_user("alice")
    make_admin(server, "root")
    server.start()
    yield server
    server.stop()


def test_closed_sessions_past_the_retention_period_are_erased_and_logged(
        retention_server, recording, tmp_path):
    alice = retention_server.client("alice")
    patient = alice.patient("Kept a while")
    session = upload(alice, patient["id"], small_recording(recording, tmp_path))
    assert session.status_code == 201, session.text
    session_id = session.json()["id"]
    deadline = time.monotonic() + 30
    while alice.http.get(f"/api/sessions/{session_id}").status_code == 200:
        assert time.monotonic() < deadline, "the retention task did not erase the session"
        time.sleep(0.3)
    assert alice.http.get(f"/api/patients/{patient['id']}").status_code == 200  # kept
    entries = retention_server.client("root").http.get(
        "/api/audit", params={"action": "erased_retention"}).json()
    assert [(e["patient_id"], e["session_id"]) for e in entries] == [(patient["id"],
                                                                      session_id)]


def test_an_upload_whose_times_run_years_ahead_is_erased_like_any_other(retention_server,
                                                                        tmp_path):
    """A session's end for retention was ``started_at`` + the recording's span of ``t``,
    and ``t`` may step up to a day (docs/extensions/time-bounds.md): 3650 rows a day apart,
    uploaded now (by a kit's token, or anyone's), made a session that 'ended' in ten years,
    which ``ARMTRACK_RETENTION_DAYS`` would erase only then. An uploaded session was
    recorded before it arrived: it is erased at the latest a day after its arrival is past
    the period (here: it arrived two days ago, set in the database)."""
    alice = retention_server.client("alice")
    patient = alice.patient("Ten years ahead")
    kit = alice.device(patient["id"])
    rows = "".join(f"{day * 86400.0},forearm,0,9.81,0,0,0,0,,,\n" for day in range(3650))
    answer = httpx.post(retention_server.url + "/api/recordings",
                        headers={"Authorization": f"Bearer {kit['token']}"},
                        data={"wait": "false"}, files={"file": ("years.csv", (
                            "# armtrack-recording: 1\n# side: right\n# height_m: 1.75\n"
                            "t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz\n" + rows).encode())},
                        timeout=60)
    assert answer.status_code == 202, answer.text
    session = answer.json()
    print("uploaded", session["started_at"], "ends", session["ended_at"])
    retention_server.sql("UPDATE sessions SET created_at = :at WHERE id = :id",
                         at=(datetime.now(UTC) - timedelta(days=2)).strftime(
                             "%Y-%m-%d %H:%M:%S.%f"), id=session["id"])
    deadline = time.monotonic() + 30
    while alice.http.get(f"/api/sessions/{session['id']}").status_code == 200:
        assert time.monotonic() < deadline, (
            f"not erased 30 s past a 3 s retention: it 'ends' {session['ended_at']}")
        time.sleep(0.3)


# -- device tokens ----------------------------------------------------------------------------
def test_revoking_a_kit_closes_its_open_stream_at_once(srv):
    alice = srv.client("alice")
    patient = alice.patient("Streaming")
    device = alice.device(patient["id"])

    async def scenario():
        url = srv.ws_url
        async with connect(url, additional_headers={
                "Authorization": f"Bearer {device['token']}"}) as ws:
            await ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "k",
                                      "side": "right", "sensors": ["forearm"],
                                      "rate_hz": 50, "nine_axis": False, "resume": None}))
            assert json.loads(await ws.recv())["type"] == "ready"
            started = time.monotonic()
            revoked = await asyncio.to_thread(alice.http.delete,
                                              f"/api/devices/{device['id']}")
            assert revoked.status_code == 204
            with pytest.raises(ConnectionClosed) as closed:
                while True:
                    await asyncio.wait_for(ws.recv(), 5)
            assert closed.value.rcvd.code == 4401
            assert time.monotonic() - started < 5

    asyncio.run(scenario())
    with pytest.raises(ConnectionClosed) as closed:
        async def again():
            async with connect(srv.ws_url, additional_headers={
                    "Authorization": f"Bearer {device['token']}"}) as ws:
                await ws.recv()
        asyncio.run(again())
    assert closed.value.rcvd.code == 4401
