"""The add-patient form and the patient record at 390 px (a therapist's phone), on a real
server: a date of birth after today (2030 typed for 1930) was taken, stored and shown
("born Jan 1, 2030"). Now the form refuses it before sending (the date field's range:
1900-01-01 to today), and the record's form too."""

from __future__ import annotations

from datetime import date, timedelta

from browser_helpers import need_browser, page_at, sign_in_as
from server_support import server_fixture

sync_api = need_browser()

server = server_fixture("patient-form", "alice")


def test_a_date_of_birth_after_today_is_refused_on_the_forms(server):
    later = (date.today() + timedelta(days=400)).isoformat()
    api = server.client("alice")
    with page_at(390) as page:
        sign_in_as(page, server.url, "alice")
        page.fill("#new-name", "Typo Patient")
        page.fill("#new-height", "1.70")
        page.fill("#new-dob", later)
        page.click("#add button[type=submit]")
        page.wait_for_timeout(1500)
        said = page.evaluate("document.querySelector('#new-dob').validationMessage")
        print(f"\nadd form, born {later}: {said!r}")
        assert page.url.endswith("/patients"), page.url
        assert [p["name"] for p in api.http.get("/api/patients").json()] == []
        assert said  # the browser says what the field takes

        patient = api.patient("Record Patient")
        page.goto(f"{server.url}/patients/{patient['id']}")
        page.fill("#edit-date_of_birth", later)
        page.click("#edit-patient button[type=submit]")
        page.wait_for_timeout(1500)
        said = page.evaluate("document.querySelector('#edit-date_of_birth').validationMessage")
        print(f"record form, born {later}: {said!r}")
        assert api.http.get(f"/api/patients/{patient['id']}").json()["date_of_birth"] is None
        assert said


def test_the_sensor_kits_read_on_a_phone(server, tmp_path):
    """Found at 390 px: the Sensor kits table squeezed four columns into the width, "Thu,
    Dec 3, 2026, 10:39 PM" on 4 lines and "active (shown only when the kit was added)" on
    5. Now each kit is a block: its name and Revoke, when it was added, its token's state."""
    api = server.client("alice")
    patient = api.patient("Kit Reader")
    for name in ("Maria's phone", "Sensor kit A"):
        api.device(patient["id"], name)
    with page_at(390) as page:
        sign_in_as(page, server.url, "alice")
        page.goto(f"{server.url}/patients/{patient['id']}")
        sync_api.expect(page.locator("#devices tbody tr")).to_have_count(2)
        lines = page.evaluate("""() => [...document.querySelectorAll('#devices tbody tr')]
          .map((tr) => [...tr.cells].slice(1, 3).map((td) => {
            const range = document.createRange(); range.selectNodeContents(td);
            // one rectangle per line box the text takes
            return new Set([...range.getClientRects()].map((r) => Math.round(r.top))).size;
          }))""")
        width = page.evaluate("document.documentElement.scrollWidth")
        page.locator("#devices").screenshot(path=str(tmp_path / "kits-390.png"))
    print(f"\nlines of (added, token) per kit at 390 px: {lines}")
    for added, state in lines:
        assert added == 1 and state <= 2, lines
    assert width <= 390
