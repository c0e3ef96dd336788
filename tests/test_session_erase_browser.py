"""Erasing one session from its page, in Debian's headless chromium at 390 and 1280 px
against a real server: a recording imported to the wrong patient (or a session streamed
by the wrong kit) is a mistake the therapist must be able to correct without erasing the
whole patient.

Before, the pages had no way to erase a session: ``DELETE /api/sessions/{id}`` was only
reachable with curl, and the one erase button on the pages erased the patient with
every session. Now the finished session's page ends with "Erase this session…": it asks
first (naming the session), erases it and returns to the patient's page, where the
session is gone (the API answers 404 for it). Dismissing the question erases nothing.
Skips with the reason when chromium or Playwright is absent."""

from __future__ import annotations

import pytest
from browser_helpers import dismissed_question, need_browser, page_at, sign_in_as

sync_api = need_browser()

from test_layout_browser import fits  # noqa: E402
from test_pages_browser import _exercise  # noqa: E402

pytestmark = pytest.mark.slow



def _uploaded_session(server, patient_name: str) -> tuple[dict, dict, object]:
    """A patient of alice's with one uploaded, estimated elbow flexion session."""
    from armtrack.estimator.recording import format_recording

    api = server.client("alice")
    patient = api.patient(patient_name)
    answer = api.http.post("/api/recordings", data={"patient_id": str(patient["id"])},
                           files={"file": ("elbow.csv", format_recording(
                               _exercise("elbow_flexion", repetitions=3)))})
    answer.raise_for_status()
    return patient, api.wait_processed(answer.json()["id"], timeout=120), api


@pytest.mark.parametrize("width", [390, 1280])
def test_a_session_is_erased_from_its_page(module_server, width, tmp_path):
    patient, session, api = _uploaded_session(module_server, f"Wrong Patient {width}")
    url = module_server.url
    with page_at(width) as page:
        sign_in_as(page, url, "alice")
        page.goto(f"{url}/sessions/{session['id']}")
        button = page.get_by_role("button", name="Erase this session…")
        sync_api.expect(button).to_be_visible()
        fits(page, tmp_path, "session", width)  # no wider than the window, hints whole

        questions = dismissed_question(page, button)
        print(f"\nthe question: {questions}")
        assert questions and f"session {session['id']}" in questions[0], questions
        assert api.http.get(f"/api/sessions/{session['id']}").status_code == 200  # kept

        page.once("dialog", lambda dialog: dialog.accept())
        button.click()
        page.wait_for_url(f"{url}/patients/{patient['id']}")
        sync_api.expect(page.locator("#no-sessions")).to_be_visible()
        page.screenshot(path=str(tmp_path / f"patient-{width}.png"), full_page=True)
        print(f"screenshots at {width} px: {tmp_path}")
    assert api.http.get(f"/api/sessions/{session['id']}").status_code == 404
