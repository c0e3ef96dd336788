"""A program's dates on the patient's page read as the page's other dates do ("Nov 16,
2026"), in Debian's headless chromium at 390 and 1280 px against a real server.

Before, a program's header said "version 1, from 2026-11-16 to 2026-11-29" and its
adherence rows "2026-W47" (an ISO week number) beside sessions dated "Thu, Dec 3, 2026":
a therapist had to work out which week W47 is. Now "from Nov 16, 2026 to Nov 29, 2026"
and "week of Nov 16, 2026" (the ISO week stays in the row's title). And a program's
PDF or FHIR the server refuses is not saved as a file: the card says why. Skips with the
reason when chromium or Playwright is absent."""

from __future__ import annotations

import pytest
from browser_helpers import need_browser, page_at, sign_in_as

sync_api = need_browser()

pytestmark = pytest.mark.slow

PROGRAM = {"name": "Elbow after the fracture", "start_date": "2026-11-16",
           "end_date": "2026-11-29", "exercises": [
               {"exercise": "elbow_flexion", "sets": 2, "repetitions": 10, "days_per_week": 5}]}



@pytest.mark.parametrize("width", [390, 1280])
def test_a_programs_dates_read_as_dates(module_server, width, tmp_path):
    api = module_server.client("alice")
    patient = api.patient(f"Program Patient {width}")
    made = api.http.post(f"/api/patients/{patient['id']}/programs", json=PROGRAM)
    assert made.status_code == 201, made.text
    with page_at(width) as page:
        sign_in_as(page, module_server.url, "alice")
        page.goto(f"{module_server.url}/patients/{patient['id']}")
        card = page.locator(f'.program[data-program="{made.json()["id"]}"]')
        sync_api.expect(card).to_contain_text("from Nov 16, 2026 to Nov 29, 2026")
        week = card.locator('tr[data-week="2026-W47"] td').nth(0)
        sync_api.expect(week).to_contain_text("week of Nov 16, 2026")
        text = card.inner_text()
        page.screenshot(path=str(tmp_path / f"program-{width}.png"), full_page=True)
        print(f"\n{width} px: {tmp_path}\n{text}")
        assert "2026-11-16" not in text and "2026-W" not in text, text


@pytest.mark.parametrize("width", [390, 1280])
def test_the_editor_says_a_wrong_target_in_the_forms_words(module_server, width, tmp_path):
    """A target the wrong way round: the editor said the API's 422 as it came
    ("exercises.0: Value error, elbow_flexion: target_min_deg must be below
    target_max_deg, got 100.0 and 20.0"); it now names the exercise and the form's fields."""
    api = module_server.client("alice")
    patient = api.patient(f"Editor Patient {width}")
    with page_at(width) as page:
        sign_in_as(page, module_server.url, "alice")
        page.goto(f"{module_server.url}/patients/{patient['id']}")
        page.click("#new-program")
        editor = page.locator("#program-editor")
        editor.locator('[name="name"]').fill("Elbow after the fracture")
        row = editor.locator(".exercise-row").nth(0)
        row.locator('[name="exercise"]').select_option("elbow_flexion")
        row.locator('[name="target_min_deg"]').fill("100")
        row.locator('[name="target_max_deg"]').fill("20")
        page.click("#save-program")
        error = editor.locator(".error")
        sync_api.expect(error).to_contain_text(
            "Bend the elbow: the target's “from” (100°) must be below its “to” (20°)")
        said = error.inner_text()
        page.screenshot(path=str(tmp_path / f"editor-{width}.png"), full_page=True)
        print(f"\n{width} px: {said}  ({tmp_path})")
        assert "target_min_deg" not in said and "Value error" not in said, said
        row.locator('[name="target_max_deg"]').fill("")
        page.click("#save-program")
        sync_api.expect(error.first).to_contain_text(
            "Bend the elbow: give both ends of the target, or neither")
    assert api.http.get(f"/api/patients/{patient['id']}/programs").json() == []


@pytest.mark.parametrize("width", [390, 1280])
def test_the_pain_and_effort_line_dates_read_as_dates(module_server, width):
    """Found reviewing a week of home use: the program card's "Pain (0–10) and effort
    (Borg CR10) by session: 2026-11-30: pain 2, effort 3 · 2026-12-01: …" wrote ISO dates
    (broken "2026-12-" / "01" at 390 px) beside "week of Nov 30, 2026"."""
    import asyncio
    import re
    from datetime import UTC, date, datetime

    from armtrack.server.emulator import KitEmulator
    from test_programs_followed import Planned, recording_of

    api = module_server.client("alice")
    patient = api.patient(f"Rated {width}")
    token = api.device(patient["id"], "phone")["token"]
    made = api.http.post(f"/api/patients/{patient['id']}/programs", json={
        "name": "Elbow at home", "start_date": date.today().isoformat(), "exercises": [
            {"exercise": "elbow_flexion", "sets": 1, "repetitions": 3, "days_per_week": 5}]})
    assert made.status_code == 201, made.text
    kit = KitEmulator(recording_of(Planned(datetime.now(UTC), {"elbow_flexion": [(3, 90.0)]}),
                                   seed=7), module_server.ws_url, token, speed=0,
                      rows_per_message=50,
                      hello_extra={"extensions": ["programs/1", "effort-pain/1"],
                                   "program": "Elbow at home"},
                      ratings=[{"id": "r1", "exercise": "elbow_flexion", "t": 20.0,
                                "effort": 4.0, "pain": 3}])
    api.wait_processed(asyncio.run(kit.run()).session, timeout=240)
    with page_at(width) as page:
        sign_in_as(page, module_server.url, "alice")
        page.goto(f"{module_server.url}/patients/{patient['id']}")
        line = page.locator("p", has_text="Pain (0–10) and effort")
        sync_api.expect(line).to_be_visible(timeout=30_000)
        text = line.inner_text()
    print(f"\n{width} px: {text!r}")
    assert not re.search(r"\d{4}-\d\d-\d\d", text), text
    day = date.today()  # the clinic's day (its zone unset: UTC, as this machine's)
    assert f"{day:%b} {day.day}, {day.year}: pain 3, effort 4" in text, text


def test_a_program_report_the_server_refuses_is_not_saved_as_a_file(module_server, tmp_path):
    """The program's PDF (and FHIR) buttons saved whatever the server answered: with the
    patient gone meanwhile (erased or handed to a colleague in another tab) the therapist
    got "patient-N-progress.pdf" holding the JSON of a 404, a file no reader opens, and no
    word on the page. Now nothing is saved and the card says the server's words."""
    api = module_server.client("alice")
    patient = api.patient("Refused Report Patient")
    made = api.http.post(f"/api/patients/{patient['id']}/programs", json=PROGRAM)
    assert made.status_code == 201, made.text
    with page_at(390) as page:
        sign_in_as(page, module_server.url, "alice")
        page.goto(f"{module_server.url}/patients/{patient['id']}")
        card = page.locator(f'.program[data-program="{made.json()["id"]}"]')
        sync_api.expect(card).to_contain_text("Elbow after the fracture")
        saved = []
        page.on("download", lambda download: saved.append(download))
        assert api.http.delete(f"/api/patients/{patient['id']}").status_code == 204
        for button in ("PDF", "FHIR"):
            card.get_by_role("button", name=button, exact=True).click()
            sync_api.expect(page.locator("#programs .error").first).to_contain_text(
                f"no patient {patient['id']}" if button == "PDF" else "no program")
        page.screenshot(path=str(tmp_path / "refused-report-390.png"))
        print(f"\n{tmp_path}")
        assert saved == [], [d.suggested_filename for d in saved]


def test_a_file_asked_for_after_the_sign_in_ended_goes_to_the_sign_in_page(module_server):
    """The session page's files (angles.csv …) and the Progress card's progress.csv each
    fetched with their own copy of the programs' download, without its sign-in rule: once
    the sign-in had ended (signed out in another tab, expired) the card said the server's
    'Not authenticated'-like words and stayed. Now one download (app.js saveFile) for all:
    to the sign-in page, as every other request of the pages (review18). 390 px."""
    from armtrack.estimator.recording import format_recording
    from armtrack.estimator.simulation import SimulationConfig, simulate

    api = module_server.client("alice")
    patient = api.patient("Signed Out Files Patient")
    recording = simulate(SimulationConfig(exercise="elbow_flexion", repetitions=1)).recording
    made = api.http.post("/api/recordings", data={"patient_id": patient["id"]},
                         files={"file": ("s.csv", format_recording(recording), "text/csv")})
    assert made.status_code == 201, made.text
    with page_at(390) as page:
        for where, button in ((f"/sessions/{made.json()['id']}", '[data-export$="angles.csv"]'),
                              (f"/patients/{patient['id']}",
                               '#progress-card [data-export$="/progress.csv"]')):
            sign_in_as(page, module_server.url, "alice")
            page.goto(module_server.url + where)
            page.locator(button).wait_for()
            # the sign-in ends as the file is asked for: the server's 401
            page.route("**/*.csv", lambda route: route.fulfill(
                status=401, content_type="application/json",
                body='{"detail": "Not authenticated"}'))
            page.locator(button).dispatch_event("click")
            page.wait_for_url("**/signin?next=*", timeout=10_000)
