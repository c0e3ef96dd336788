"""The authorisation matrix (issue 9): every route of the OpenAPI document, the ingest and
live WebSockets and the 3D viewer × every kind of caller, on a real server.

Callers: nobody (no token), another therapist, a clinic admin who is not the patient's
therapist, the patient's own kit (device token), a revoked kit, the owner's expired
token, and the owner. Each cell is refused or allowed as designed, and a refusal leaks
nothing: the same status and body (the asked-for id aside) whether the object exists or
not, and no other patient's name in any body. A clinic admin holds no patients (issue 17):
they cannot add one nor be given one, and every patient's data is 404 to them. The matrix
is printed (``pytest -s``)."""

from __future__ import annotations

import asyncio
import hashlib
import re
import sqlite3

import httpx
import pytest
from server_support import PASSWORD, ServerProcess, armtrack
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

SECRET_NAME = "Zorba Quintrell"  # the owner's patient: no refusal may name them
MISSING = 999999
IDENTITIES = ("none", "other", "admin", "device", "revoked", "expired", "owner")
RECORDING = "left_reach_50hz.csv"

#: What each route is, and so who may use it:
#: owned — the owner only (others 404, as if it did not exist); list — every therapist,
#: each their own; self — acts on the caller's own account; admin — clinic admins;
#: upload — a therapist for their patient, or a kit for its own patient; reset — only a
#: one-time reset token; public — sign-in; device — a kit's own token only (its patient's);
#: signout — ends the caller's own sign-in.
KINDS = {
    ("POST", "/api/auth/token"): "public",
    ("POST", "/api/auth/password"): "self",
    ("POST", "/api/auth/signout"): "signout",
    ("POST", "/api/auth/reset"): "reset",
    ("POST", "/api/patients"): "list",
    ("GET", "/api/patients"): "list",
    ("GET", "/api/audit"): "list",
    ("POST", "/api/recordings"): "upload",
    ("POST", "/api/recordings/inspect"): "upload",
    ("GET", "/api/recordings/{session_id}/progress"): "upload",
    ("POST", "/api/viewer"): "owned",  # the patient is in the body
    ("GET", "/api/programs/catalogue"): "list",
    ("GET", "/api/clinic"): "list",
    ("GET", "/api/me"): "list",
    ("PATCH", "/api/me"): "list",  # each their own account
    ("GET", "/api/flags"): "list",
    ("GET", "/api/device/today"): "device",
}


def kind(method: str, path: str) -> str:
    if (method, path) in KINDS:
        return KINDS[(method, path)]
    if path.startswith("/api/admin/"):
        return "admin"
    assert "{" in path, f"{method} {path}: add it to KINDS of the matrix"
    return "owned"


EXPECTED_REFUSAL = {"none": 401, "device": 401, "revoked": 401, "expired": 401}
#: The accounts of the signed-in identities.
SIGNED_IN = {"owner": "alice", "other": "bob", "admin": "carol"}


class World:
    """The objects the matrix reaches, made through the API."""

    def __init__(self, server: ServerProcess, recording):
        self.server = server
        self.recording = recording
        self.alice = server.client("alice")
        self.bob = server.client("bob")
        self.carol = server.client("carol")  # a clinic admin
        self.patient = self.alice.patient(SECRET_NAME)
        self.session = self.upload(self.alice, self.patient["id"])
        self.alice.wait_processed(self.session["id"])
        self.device = self.alice.device(self.patient["id"], "home kit")
        revoked = self.alice.device(self.patient["id"], "old kit")
        assert self.alice.http.delete(f"/api/devices/{revoked['id']}").status_code == 204
        answer = self.alice.http.put(f"/api/patients/{self.patient['id']}/targets/"
                                     "elbow_flexion", json={"min_deg": 0, "max_deg": 120})
        assert answer.status_code == 200, answer.text
        answer = self.alice.http.post(f"/api/patients/{self.patient['id']}/programs",
                                      json=program_body("Shoulder program"))
        assert answer.status_code == 201, answer.text
        self.program = answer.json()
        therapists = {t["username"]: t for t in self.carol.http.get(
            "/api/admin/therapists").json()}
        self.alice_id = therapists["alice"]["id"]
        made = self.carol.http.post("/api/admin/therapists", json={
            "username": "dave", "password": PASSWORD})
        assert made.status_code == 201, made.text
        self.dave_id = made.json()["id"]
        expired = server.client("alice")
        with sqlite3.connect(server.data_dir / "armtrack.db") as db:
            db.execute("UPDATE access_tokens SET expires_at = '2000-01-01 00:00:00.000000' "
                       "WHERE token_hash = ?",
                       (hashlib.sha256(expired.token.encode()).hexdigest(),))
        self.tokens = {"none": None, "other": self.bob.token, "admin": self.carol.token,
                       "device": self.device["token"], "revoked": revoked["token"],
                       "expired": expired.token, "owner": self.alice.token}

    def upload(self, api, patient_id: int) -> dict:
        with open(self.recording, "rb") as f:
            answer = api.http.post("/api/recordings", data={"patient_id": patient_id},
                                   files={"file": (RECORDING, f)})
        assert answer.status_code == 201, answer.text
        return answer.json()

    def grant(self) -> str:
        answer = self.alice.http.post("/api/viewer", json={"patient_id": self.patient["id"]})
        assert answer.status_code == 200, answer.text
        return answer.json()["url"].split("/")[2]

    def values(self, identity: str, method: str, path: str, missing: bool) -> dict:
        """Path parameters: the owner's objects (a throwaway one where the owner erases
        it), or ids that exist nowhere."""
        if missing:
            return {"patient_id": MISSING, "session_id": MISSING, "device_id": MISSING,
                    "therapist_id": MISSING, "grant_id": "no-such-grant-0000000000000000",
                    "program_id": MISSING,
                    "angle": "elbow_flexion"}
        values = {"patient_id": self.patient["id"], "session_id": self.session["id"],
                  "device_id": self.device["id"], "therapist_id": self.dave_id,
                  "program_id": self.program["id"],
                  "grant_id": self.grant() if "{grant_id}" in path else "",
                  "angle": "elbow_flexion"}
        if identity == "owner" and method == "DELETE":
            if path == "/api/patients/{patient_id}":
                values["patient_id"] = self.alice.patient("Throwaway")["id"]
            elif path == "/api/sessions/{session_id}":
                values["session_id"] = self.upload(self.alice, self.patient["id"])["id"]
            elif path == "/api/devices/{device_id}":
                values["device_id"] = self.alice.device(self.patient["id"], "spare")["id"]
        return values

    def request(self, identity: str, method: str, path: str, missing: bool = False
                ) -> httpx.Response:
        values = self.values(identity, method, path, missing)
        url = path.format(**values)
        token = self.tokens[identity]
        if (method, path) == ("POST", "/api/auth/signout") and identity in SIGNED_IN:
            token = self.server.client(SIGNED_IN[identity]).token  # a sign-in to end
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        patient_id = values["patient_id"]
        kwargs: dict = {}
        if (method, path) in (("POST", "/api/recordings"), ("POST", "/api/recordings/inspect")):
            field = "file" if path == "/api/recordings" else "files"
            kwargs["files"] = {field: (RECORDING, open(self.recording, "rb").read())}
            if identity != "device" or missing:
                kwargs["data"] = {"patient_id": patient_id}
        else:
            kwargs["json"] = body(method, path, identity, patient_id, self.alice_id)
        with httpx.Client(base_url=self.server.url, timeout=120) as http:
            return http.request(method, url, headers=headers, **kwargs)


def body(method: str, path: str, identity: str, patient_id: int, alice_id: int):
    return {
        "/api/auth/password": {"old_password": "not the old password",
                               "new_password": "a new password 1"},
        "/api/auth/reset": {"new_password": "a new password 1"},
        "/api/me": {"full_name": f"Full name of {identity}"},
        "/api/patients": {"name": f"Own {identity}", "side": "left", "height_m": 1.7},
        "/api/patients/{patient_id}/devices": {"name": "kit"},
        "/api/patients/{patient_id}": {"clinic_number": f"C-{identity}"},
        "/api/patients/{patient_id}/targets/{angle}": {"min_deg": 5, "max_deg": 110},
        "/api/viewer": {"patient_id": patient_id, "session_id": None},
        "/api/admin/therapists": {"username": f"made-by-{identity}", "password": PASSWORD},
        "/api/admin/patients/{patient_id}/reassign": {"therapist_id": alice_id},
        "/api/patients/{patient_id}/programs": program_body(f"Program of {identity}"),
        "/api/programs/{program_id}": {k: v for k, v in program_body("").items()
                                       if k != "name"},
    }.get(path) if method in ("POST", "PUT", "PATCH") else None


def program_body(name: str) -> dict:
    return {"name": name, "start_date": "2026-12-01", "exercises": [
        {"exercise": "elbow_flexion", "sets": 2, "repetitions": 10, "days_per_week": 5}]}


def expected(route_kind: str, identity: str, method: str, path: str) -> set[int]:
    """The statuses that mean 'as designed'."""
    if route_kind == "public":
        return {422}  # no form: the sign-in itself is tested elsewhere
    if route_kind == "reset":
        return {401}  # only a reset token opens it
    if route_kind == "device":
        return {200} if identity == "device" else {401}  # no therapist token opens it
    if identity in EXPECTED_REFUSAL:
        if route_kind == "upload" and identity == "device":
            # a kit uploads for its own patient, looks inside its files, follows them
            return {201} if (method, path) == ("POST", "/api/recordings") else {200}
        return {EXPECTED_REFUSAL[identity]}
    if route_kind == "self":
        return {400}  # their own account only: the old password is wrong
    if route_kind == "signout":
        return {204}  # each ends a sign-in of their own (a fresh one: the matrix goes on)
    if route_kind == "admin":
        return {200, 201} if identity == "admin" else {403}
    if route_kind == "list":
        if identity == "admin" and (method, path) == ("POST", "/api/patients"):
            return {403}  # a clinic admin holds no patients
        return {200, 201}
    if identity in ("other", "admin"):
        return {404}
    if (method, path) == ("POST", "/api/sessions/{session_id}/close"):
        return {409}  # the owner may: an uploaded session is closed already
    return {200, 201, 204}


def normalised(answer: httpx.Response, values: list) -> tuple[int, str]:
    text = answer.text
    for value in values:
        text = re.sub(rf"\b{re.escape(str(value))}\b", "<id>", text)
    return answer.status_code, text


@pytest.fixture(scope="module")
def world(tmp_path_factory, recordings_dir):
    server = ServerProcess(tmp_path_factory.mktemp("matrix"))
    for name in ("alice", "bob"):
        server.create_user(name)
    done = armtrack("create-user", "carol", "--admin", "--password", PASSWORD,
                    "--data-dir", str(server.data_dir))
    assert done.returncode == 0, done.stderr
    server.start()
    yield World(server, recordings_dir / RECORDING)
    server.stop()


async def ws_outcome(url: str, token: str | None) -> str:
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    try:
        async with connect(url, additional_headers=headers, open_timeout=20) as ws:
            if "/ws/ingest" in url:
                await ws.send('{"type": "hello", "protocol": 1, "device": "m", "side": '
                              '"left", "sensors": ["forearm"], "rate_hz": 50, '
                              '"nine_axis": false, "resume": null}')
            try:
                message = await asyncio.wait_for(ws.recv(), 3)
            except TimeoutError:
                return "open"
            if "/ws/ingest" in url and '"ready"' in message:
                await ws.send('{"type": "bye"}')
                return "ready"
            return "open"
    except ConnectionClosed as exc:
        return f"{exc.rcvd.code if exc.rcvd else '?'} {exc.rcvd.reason if exc.rcvd else ''}"
    except InvalidStatus as exc:
        return f"http {exc.response.status_code}"


def test_the_authorisation_matrix(world):
    schema = httpx.get(world.server.url + "/openapi.json").json()
    routes = [(m.upper(), p) for p, ops in schema["paths"].items() for m in ops]
    assert len(routes) >= 40
    # the owner goes last: refusals must find everything still there
    rows, failures = [], []
    for method, path in routes:
        route_kind = kind(method, path)
        cells = []
        for identity in IDENTITIES:
            answer = world.request(identity, method, path)
            want = expected(route_kind, identity, method, path)
            cell = str(answer.status_code)
            if answer.status_code not in want:
                failures.append(f"{method} {path} as {identity}: {answer.status_code} "
                                f"(want {sorted(want)}): {answer.text[:200]}")
                cell += "!"
            refused = answer.status_code in (401, 403, 404)
            if identity != "owner" and SECRET_NAME in answer.text and not (
                    identity == "admin" and path.startswith("/api/admin/patients")):
                failures.append(f"{method} {path} as {identity}: the owner's patient's "
                                "name is in the answer")
            if identity == "other" and route_kind == "list" and answer.status_code == 200:
                if any(isinstance(x, dict) and world.patient["id"] in (
                        x.get("id"), x.get("patient_id")) for x in answer.json()):
                    failures.append(f"{method} {path} as other: lists the owner's patient")
            if refused and route_kind in ("owned", "upload"):
                twin = world.request(identity, method, path, missing=True)
                ids = [world.patient["id"], world.session["id"], world.device["id"],
                       world.program["id"], MISSING]
                if normalised(answer, ids) != normalised(twin, ids):
                    failures.append(f"{method} {path} as {identity}: the refusal differs for "
                                    f"a missing object: {answer.status_code} {answer.text!r} "
                                    f"vs {twin.status_code} {twin.text!r}")
            cells.append(cell)
        rows.append((f"{method} {path}", route_kind, cells))

    # a kit's token uploads for its own patient only (another's: as if it did not exist)
    cells = []
    for patient_id in (world.bob.patient("Bob's")["id"], MISSING):
        with open(world.recording, "rb") as f:
            answer = httpx.post(world.server.url + "/api/recordings",
                                data={"patient_id": patient_id}, files={"file": (RECORDING, f)},
                                headers={"Authorization": f"Bearer {world.device['token']}"},
                                timeout=120)
        cells.append(normalised(answer, [patient_id]))
    if cells[0] != cells[1] or cells[0][0] != 404:
        failures.append(f"POST /api/recordings by a kit for another patient: {cells}")
    rows.append(("POST /api/recordings (kit, another patient)", "upload",
                 ["" if i != "device" else str(cells[0][0]) for i in IDENTITIES]))

    # an admin cannot give a patient to themself (nor to another admin) to read it
    carol_id = next(t["id"] for t in world.carol.http.get("/api/admin/therapists").json()
                    if t["username"] == "carol")
    to_self = world.carol.http.post(f"/api/admin/patients/{world.patient['id']}/reassign",
                                    json={"therapist_id": carol_id})
    if to_self.status_code != 409 or SECRET_NAME in to_self.text:
        failures.append(f"reassign to the admin themself: {to_self.status_code} "
                        f"{to_self.text[:200]}")
    rows.append(("POST /api/admin/patients/{patient_id}/reassign (to self)", "admin",
                 ["" if i != "admin" else str(to_self.status_code) for i in IDENTITIES]))

    # the WebSockets and the viewer
    base = world.server.url.replace("http", "ws")
    ws_rows = {
        "WS /ws/ingest": ({"device": "ready"}, "4401"),
        "WS /ws/live?patient={patient_id}": ({"owner": "open", "other": "4404",
                                              "admin": "4404"}, "4401"),
    }
    for label, (allowed, refusal) in ws_rows.items():
        cells = []
        for identity in IDENTITIES:
            url = base + label[3:].format(patient_id=world.patient["id"])
            outcome = asyncio.run(ws_outcome(url, world.tokens[identity]))
            want = allowed.get(identity, refusal)
            if not outcome.startswith(want):
                failures.append(f"{label} as {identity}: {outcome} (want {want})")
            if want == "4404":
                twin = asyncio.run(ws_outcome(base + label[3:].format(patient_id=MISSING),
                                              world.tokens[identity]))
                if twin.replace(str(MISSING), "<id>") != outcome.replace(
                        str(world.patient["id"]), "<id>"):
                    failures.append(f"{label} as {identity}: {outcome} vs missing {twin}")
            cells.append(outcome.split(" ")[0] + ("" if outcome.startswith(want) else "!"))
        rows.append((label, "ws", cells))
    grant = world.grant()
    assert httpx.get(f"{world.server.url}/viewer/{grant}/").status_code == 200  # the owner's
    for label, url in (("GET /viewer/<unknown grant>/", "/viewer/not-a-grant-000000000/"),):
        cells = []
        for identity in IDENTITIES:
            token = world.tokens[identity]
            answer = httpx.get(world.server.url + url, headers={
                "Authorization": f"Bearer {token}"} if token else {})
            if answer.status_code != 404:
                failures.append(f"{label} as {identity}: {answer.status_code}")
            cells.append(str(answer.status_code))
        rows.append((label, "grant", cells))
    cells = []
    for identity in IDENTITIES:
        token = world.tokens[identity]
        outcome = asyncio.run(ws_outcome(f"{base}/viewer/not-a-grant-000000000", token))
        if outcome != "http 403":
            failures.append(f"WS /viewer/<unknown grant> as {identity}: {outcome}")
        cells.append(outcome.replace("http ", ""))
    rows.append(("WS /viewer/<unknown grant>", "grant", cells))

    width = max(len(r[0]) for r in rows)
    print("\n" + f"{'route':<{width}}  {'kind':<6} " + " ".join(f"{i:>7}" for i in IDENTITIES))
    for label, route_kind, cells in rows:
        print(f"{label:<{width}}  {route_kind:<6} " + " ".join(f"{c:>7}" for c in cells))
    assert not failures, "\n".join(failures)
