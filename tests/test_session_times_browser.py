"""Sessions started within the same minute are told apart in the patient's session list, in
Debian's headless chromium at 390 and 1280 px against a real server.

Before, two sessions 35 s apart both read "…, 01:42 PM" (a kit restarted, or a stream and
an upload of the same morning): the therapist could not tell which row was which without
opening both. Now a row whose minute another row shares shows its seconds ("01:42:05 PM",
"01:42:40 PM"); a session alone in its minute reads as before, to the minute (the seconds
of every row would be noise a therapist reads past). Skips with the reason when chromium
or Playwright is absent."""

from __future__ import annotations

import re
from datetime import UTC, datetime

import pytest
from armtrack.estimator.recording import format_recording
from armtrack.estimator.simulation import SimulationConfig, simulate
from browser_helpers import need_browser, page_at, sign_in_as
from test_sessions_paging_browser import dated

sync_api = need_browser()

pytestmark = pytest.mark.slow

STARTS = [datetime(2026, 11, 20, 13, 42, 5, tzinfo=UTC),
          datetime(2026, 11, 20, 13, 42, 40, tzinfo=UTC),  # 35 s later, the same minute
          datetime(2026, 11, 19, 9, 15, 30, tzinfo=UTC)]


@pytest.mark.parametrize("width", [390, 1280])
def test_sessions_of_the_same_minute_are_told_apart(module_server, width, tmp_path):
    api = module_server.client("alice")
    patient = api.patient(f"Same Minute {width}")
    text = format_recording(simulate(SimulationConfig(rate_hz=25.0, repetitions=1,
                                                      seed=5)).recording)
    for k, start in enumerate(STARTS):
        answer = api.http.post("/api/recordings", data={"patient_id": patient["id"]},
                               files={"file": (f"s{k}.csv", dated(text, start))})
        assert answer.status_code == 201, answer.text
    with page_at(width) as page:
        sign_in_as(page, module_server.url, "alice")
        page.goto(f"{module_server.url}/patients/{patient['id']}")
        rows = page.locator("#sessions tbody tr")
        sync_api.expect(rows).to_have_count(3)
        dates = [d.strip() for d in rows.locator("td:first-child a").all_inner_texts()]
        page.screenshot(path=str(tmp_path / f"sessions-{width}.png"), full_page=True)
        print(f"\n{width} px: {dates} ({tmp_path})")
        # the session's own page names the same moment as its row, seconds and all
        rows.first.locator("td:first-child a").click()
        facts = page.locator("#facts")
        sync_api.expect(facts).to_contain_text("recorded")
        print(f"{width} px, the session's page: {facts.inner_text()}")
        assert dates[0] in facts.inner_text()
    # newest first: 13:42:40, 13:42:05, then the day before at 09:15 (UTC, the clinic's zone)
    assert re.search(r"\b0?1:42:40\b|\b13:42:40\b", dates[0]), dates
    assert re.search(r"\b0?1:42:05\b|\b13:42:05\b", dates[1]), dates
    assert dates[0] != dates[1]
    assert re.search(r"\b0?9:15\b", dates[2]) and ":30" not in dates[2], dates


def test_a_session_over_an_hour_reads_in_hours(module_server, tmp_path):
    """Found by a new user: a phone session that lasted 20 h read "1200 min 56 s" in the
    patient's session list (and the PDF says durations alike): minutes past the hour,
    which the therapist must divide. A session may last hours (ARMTRACK_MAX_SESSION_SAMPLES:
    ~9 h of a phone). Here an upload whose last second comes 65 min after the rest (a kit
    left on): its row and its PDF say "1 h 05 min", to the minute."""
    import subprocess

    api = module_server.client("alice")
    patient = api.patient("Long Session")
    text = format_recording(simulate(SimulationConfig(rate_hz=25.0, repetitions=1,
                                                      seed=6)).recording).decode()
    lines = text.splitlines()
    first_row = next(i for i, line in enumerate(lines) if line[:1].isdigit())
    t_end = float(lines[-1].split(",")[0])
    late = [i for i in range(first_row, len(lines)) if float(lines[i].split(",")[0]) > t_end - 1]
    for i in late:  # the last second, 65 min later: the session spans 1 h 05 min and more
        t, rest = lines[i].split(",", 1)
        lines[i] = f"{float(t) + 3900:.4f},{rest}"
    answer = api.http.post("/api/recordings", data={"patient_id": patient["id"]},
                           files={"file": ("long.csv", ("\n".join(lines) + "\n").encode())})
    assert answer.status_code == 201, answer.text
    session = api.wait_processed(answer.json()["id"], timeout=120)
    with page_at(1280) as page:
        sign_in_as(page, module_server.url, "alice")
        page.goto(f"{module_server.url}/patients/{patient['id']}")
        row = page.locator("#sessions tbody tr").first
        sync_api.expect(row).to_contain_text("Finished", timeout=30_000)
        shown = row.inner_text()
        page.screenshot(path=str(tmp_path / "long-session.png"))
    pdf = tmp_path / "long.pdf"
    pdf.write_bytes(api.http.get(f"/api/sessions/{session['id']}/report.pdf").content)
    first = subprocess.run(["pdftotext", "-l", "1", str(pdf), "-"], capture_output=True,
                           text=True, check=True).stdout
    seconds = round(api.http.get(f"/api/sessions/{session['id']}/summary").json()["duration_s"])
    words = f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"  # 1 h 05 min
    print(f"\n{seconds} s; the row: {shown!r}; the PDF's session line: "
          f"{next(line for line in first.splitlines() if 'min' in line)!r}")
    assert words in shown
    assert words in first
