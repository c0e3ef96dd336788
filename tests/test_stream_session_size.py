"""``armtrack stream`` at the server's session-size cap (``ARMTRACK_MAX_SESSION_SAMPLES``),
on a real server with a small cap, streaming as fast as it can (``--speed 0``).

The server refuses the message that would take a session past the cap with words telling
the kit to start a new session. Before, the command took them as its own bad data: every
message it had in flight was refused, the server stopped the stream for too many refused
messages (close 4429, the session marked "stopped by the server") and the command exited
1 with the rest never sent. Now it closes the full session (``bye``: it is estimated),
starts a new one with what was refused and goes on: every row stored once, in sessions
of at most the cap, all closed, none stopped."""

from __future__ import annotations

import json
import subprocess

from server_support import armtrack, server_fixture

CAP = 4000
server = server_fixture("stream_session_size", "alice",
                        env={"ARMTRACK_MAX_SESSION_SAMPLES": str(CAP)})


def test_stream_goes_on_in_a_new_session_at_the_cap(server, tmp_path):
    api = server.client("alice")
    patient = api.patient("Long Session")
    token = api.device(patient["id"])["token"]
    recording = tmp_path / "long.csv"
    made = armtrack("simulate", "--exercise", "shoulder_abduction", "-o",
                           str(recording))
    assert made.returncode == 0, made.stderr
    checked = armtrack("check", str(recording), "--json")
    rows = sum(s["samples"] for s in json.loads(checked.stdout)["sensors"].values())
    done = armtrack("stream", str(recording), "--url", server.ws_url, "--token", token,
                           "--speed", "0", "--quiet", timeout=300)
    print(f"\nexit {done.returncode}\nstdout:\n{done.stdout}\nstderr:\n{done.stderr}")
    assert done.returncode == 0
    sessions = api.http.get(f"/api/patients/{patient['id']}/sessions").json()
    sessions = [api.http.get(f"/api/sessions/{s['id']}").json() for s in sessions]
    print(f"{rows} rows; sessions: "
          + ", ".join(f"{s['id']} {s['status']} {s['samples']} rows" for s in sessions))
    assert sum(s["samples"] for s in sessions) == rows
    assert len(sessions) == -(-rows // CAP) and all(s["samples"] <= CAP for s in sessions)
    assert all(s["status"] == "closed" and not s.get("stopped_by_server") for s in sessions)
    assert "new session" in done.stdout
    # each new session names the full one it carries on (carried-on/1): its page says why
    # it has no calibration poses of its own
    ids = sorted(s["id"] for s in sessions)
    carries = {s["id"]: s.get("carries_on") for s in sessions}
    print(f"carries_on: {carries}")
    assert [carries[i] for i in ids] == [None, *ids[:-1]]
    # the link is the server's own note: a session's exported recording (handed to a
    # colleague, read back by another server) carries no "carries_on" header line, whose
    # number would name a session of this server only
    header = [line for line in api.http.get(f"/api/sessions/{ids[1]}/recording.csv").text
              .splitlines() if line.startswith("#")]
    print("exported header:", header)
    assert header and not any("carries_on" in line for line in header)
    # its report says which calibration it used, in words (not "default; poses: none"):
    # the JSON and the PDF's first and last pages
    api.wait_processed(ids[1], timeout=120)
    said = api.http.get(f"/api/sessions/{ids[1]}/report").json()["quality"]["calibration"]
    pdf = tmp_path / "carried.pdf"
    pdf.write_bytes(api.http.get(f"/api/sessions/{ids[1]}/report.pdf").content)
    text = " ".join(subprocess.run(["pdftotext", str(pdf), "-"], capture_output=True,
                                   text=True, check=True).stdout.split())
    print(f"report: {said}\nPDF: ...{text[text.find('Calibration'):][:400]}")
    assert said["carries_on"] == ids[0]
    assert (f"carries on session {ids[0]}" in said["words"]
            and "default sensor mounting" in said["words"])
    assert f"carries on session {ids[0]}" in text and "default sensor mounting" in text


def test_an_uploaded_headers_own_carries_on_line_is_exported_again():
    """Only the server's link (an int, carried-on/1) stays out of an exported header: a
    recording uploaded with its own ``carries_on`` header line (text, the kit's or the
    clinic's) kept it as metadata and lost it on export, the file no longer reading back
    to what was stored."""
    from armtrack.server.ingest.carried_on import KEY
    from armtrack.server.store.recordings import header_metadata

    assert header_metadata({KEY: 12, "device": "kit 7"}) == {"device": "kit 7"}
    assert header_metadata({KEY: "the morning set"}) == {KEY: "the morning set"}
