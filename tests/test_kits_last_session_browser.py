"""A patient with two phones (a new one bought mid-week, the old one still used on some
days): the patient page's "Sensor kits" said of both only "added …, active", so the
therapist could not tell which one the patient still uses, nor which to revoke. Each kit
now says when its newest session started ("last session …", or "no session yet"). A real
server, ``armtrack stream`` on one of two kits, the patient page at 390 and 1280 px in
Debian's chromium."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest
from browser_helpers import need_browser, page_at, sign_in_as
from server_support import server_fixture

sync_api = need_browser()

server = server_fixture("kits-last-session", "alice")


@pytest.fixture(scope="module")
def patient(server):
    api = server.client("alice")
    patient = api.patient("Two Phones")
    api.device(patient["id"], "Old phone")
    new = api.device(patient["id"], "New phone")
    done = subprocess.run(
        [sys.executable, "-m", "armtrack.server.cli", "stream", "--exercise", "elbow_flexion",
         "--url", server.ws_url, "--token", new["token"], "--speed", "0", "--quiet"],
        capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    session = api.http.get(f"/api/patients/{patient['id']}/sessions").json()[0]
    return patient, session


@pytest.mark.parametrize("width", [390, 1280])
def test_each_kit_says_when_it_was_last_used(server, patient, width):
    patient, session = patient
    kits = server.client("alice").http.get(f"/api/patients/{patient['id']}/devices").json()
    print("\n", [(k["name"], k.get("last_session_at")) for k in kits])
    assert [k["name"] for k in kits] == ["Old phone", "New phone"]
    assert kits[0]["last_session_at"] is None
    assert kits[1]["last_session_at"] == session["started_at"]
    with page_at(width) as page:
        sign_in_as(page, server.url, "alice")
        page.goto(f"{server.url}/patients/{patient['id']}")
        rows = page.locator("#devices tbody tr")
        sync_api.expect(rows).to_have_count(2, timeout=30_000)
        used = page.locator("#devices td.last-used")
        old, new = used.nth(0).inner_text(), used.nth(1).inner_text()
        # the words before the time: the column's head at 1280, before the cell at 390
        said = page.evaluate("""() => [...document.querySelectorAll('#devices td.last-used')]
          .map((td) => getComputedStyle(td, '::before').content)""")
        head = page.locator("#devices thead th").nth(3)
        heading = head.inner_text() if head.is_visible() else None
        width_px = page.evaluate("document.documentElement.scrollWidth")
        page.locator("#devices").screenshot(path=f"/tmp/kits-last-session-{width}.png")
    print(f"{width} px: {old!r} / {new!r}, before: {said}, head: {heading!r}")
    assert old == "no session yet"
    assert re.search(r"\d{4}, \d{1,2}:\d\d", new), new  # a date and time, as pages write
    assert "no session yet" not in new
    if width < 600:
        assert said == ["none", '"last session "'], said
    else:
        assert heading.lower() == "last session"
    assert width_px <= width
