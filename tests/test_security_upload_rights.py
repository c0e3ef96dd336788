"""An upload is stored only while the right it was let in with still holds (att19).

A recording upload is checked (the uploader's token, their patient) when its body has
arrived, then read and parsed (seconds for a large file, up to two minutes for an APDM
``.h5``), then stored. A right that went in between — the patient reassigned to another
therapist or erased, the account disabled, the sign-in ended, the kit revoked — was not
looked at again: the session was stored in the patient's record all the same, written by
someone who no longer held it. Real server, real HTTP clients, the server's SQLite file.

The window is held open without guessing at timing: the test takes SQLite's write lock, so
each upload waits at its first write, past its checks and inside its therapist's read turn
(``imports.therapist_turn``, two at once); a third request of the therapist answered 429
says both are there. The change is then made in the lock's transaction, as another server
instance on the same database makes it, and the lock given back."""

from __future__ import annotations

import concurrent.futures
import sqlite3
import time

import httpx

TINY = ("# armtrack-recording: 1\n# side: right\n# height_m: 1.75\n"
        "t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz\n"
        + "".join(f"{i * 0.02:.2f},forearm,0,9.81,0,0,0,0,,,\n" for i in range(100))).encode()


def _upload(server, token: str, patient_id: int) -> httpx.Response:
    """An upload, sent again while the therapist's read turns are taken (by a probe)."""
    while True:
        answer = httpx.post(server.url + "/api/recordings", timeout=120,
                            headers={"Authorization": f"Bearer {token}"},
                            data={"patient_id": str(patient_id), "wait": "false"},
                            files={"file": ("r.csv", TINY, "text/csv")})
        if answer.status_code != 429:
            return answer


def _both_inside(server, token: str, patient_id: int, uploads, timeout: float = 60) -> None:
    """Return once the therapist's two read turns are taken (an inspection answered 429):
    only ``uploads`` hold them long, each past its checks, waiting at its first write."""
    deadline = time.monotonic() + timeout
    while True:
        answer = httpx.post(server.url + "/api/recordings/inspect", timeout=30,
                            headers={"Authorization": f"Bearer {token}"},
                            data={"patient_id": str(patient_id)},
                            files={"files": ("r.csv", TINY, "text/csv")})
        if answer.status_code == 429:
            return
        assert answer.status_code == 200, answer.text
        assert time.monotonic() < deadline and not any(u.done() for u in uploads), \
            [u.result().text for u in uploads if u.done()]
        time.sleep(0.05)


def test_an_upload_whose_patient_is_reassigned_while_it_is_read_is_not_stored(
        module_server):
    server = module_server
    alice = server.client("alice")
    patient = alice.patient("Moves while uploading")
    bob_id = server.sql("SELECT id FROM therapists WHERE username = 'bob'")[0][0]
    database = server.database_url.removeprefix("sqlite:///")
    lock = sqlite3.connect(database, timeout=30, isolation_level=None)
    try:
        lock.execute("BEGIN IMMEDIATE")  # every write of the server waits for it
        with concurrent.futures.ThreadPoolExecutor(2) as pool:
            uploads = [pool.submit(_upload, server, alice.token, patient["id"])
                       for _ in range(2)]
            _both_inside(server, alice.token, patient["id"], uploads)
            assert not any(u.done() for u in uploads), [u.result().text for u in uploads]
            # another instance reassigns the patient to bob meanwhile
            lock.execute("UPDATE patients SET therapist_id = ? WHERE id = ?",
                         (bob_id, patient["id"]))
            lock.execute("COMMIT")
            answers = [u.result() for u in uploads]
    finally:
        lock.close()
    print("\n" + "\n".join(f"{a.status_code} {a.text}" for a in answers))
    stored = server.sql("SELECT COUNT(*) FROM sessions WHERE patient_id = :p",
                        p=patient["id"])[0][0]
    assert stored == 0, f"alice stored {stored} sessions in a patient no longer hers"
    for answer in answers:
        assert answer.status_code == 404, answer.text
        assert "nothing of the upload was stored" in answer.json()["detail"], answer.text
    # bob, who holds the patient now, uploads as before; alice's own patients too
    assert _upload(server, server.client("bob").token, patient["id"]).status_code == 202
    assert _upload(server, alice.token, alice.patient("Stays")["id"]).status_code == 202
