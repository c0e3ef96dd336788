"""The patient page's sessions list pages (issue 24): it shows the newest 50 sessions and
"Older sessions" adds the next 50, in order, none twice, until there are no older ones
(the button then goes). Real server, 55 uploaded recordings dated by their
``start_time`` header one day apart, real headless chromium."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from armtrack.estimator.recording import format_recording
from armtrack.estimator.simulation import SimulationConfig, simulate
from browser_helpers import sign_in_as
from test_pages_browser import browser_context, page, shots, sync_api  # noqa: F401

pytestmark = pytest.mark.slow
expect = sync_api.expect
SESSIONS = 55


def dated(text: bytes, moment: datetime) -> bytes:
    """The recording with a ``start_time`` header (docs/extensions/start-time.md)."""
    first, rest = text.split(b"\n", 1)
    return first + f"\n# start_time: {moment.isoformat()}\n".encode() + rest


def test_older_sessions_page_in(module_server, page, shots):  # noqa: F811
    api = module_server.client("alice")
    patient = api.patient("Paging Patient")
    text = format_recording(simulate(SimulationConfig(rate_hz=25.0, repetitions=1,
                                                      seed=3)).recording)
    newest = datetime.now(UTC).replace(microsecond=0) - timedelta(hours=1)
    for day in range(SESSIONS):
        answer = api.http.post("/api/recordings", data={"patient_id": patient["id"]},
                               files={"file": (f"day{day}.csv",
                                               dated(text, newest - timedelta(days=day)))})
        assert answer.status_code == 201, answer.text
    expected = [s["id"] for s in api.http.get(f"/api/patients/{patient['id']}/summaries",
                                              params={"limit": 200}).json()]
    assert len(expected) == SESSIONS

    page.set_viewport_size({"width": 1366, "height": 900})
    sign_in_as(page, module_server.url, "alice")
    page.goto(f"{module_server.url}/patients/{patient['id']}")
    rows = page.locator("#sessions tbody tr")
    expect(rows).to_have_count(50)
    shown = [int(x) for x in rows.evaluate_all("rs => rs.map(r => r.dataset.session)")]
    assert shown == expected[:50]
    older = page.locator("#older-sessions")
    expect(older).to_be_visible()
    expect(page.locator("#sessions-count")).to_have_text("the newest 50")
    older.click()
    expect(rows).to_have_count(SESSIONS)
    shown = [int(x) for x in rows.evaluate_all("rs => rs.map(r => r.dataset.session)")]
    assert shown == expected
    expect(older).to_be_hidden()
    expect(page.locator("#sessions-count")).to_have_text(f"the newest {SESSIONS}")
    # the last rows are the oldest days
    oldest = (newest - timedelta(days=SESSIONS - 1)).day
    expect(rows.last.locator("td").first).to_contain_text(str(oldest))
    width = page.evaluate("[document.scrollingElement.scrollWidth, innerWidth]")
    assert width[0] <= width[1], width
    page.screenshot(path=str(shots / "sessions-paged-1366.png"), full_page=False)
