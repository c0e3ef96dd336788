"""The 3D view (viser's page under its own strict policy, ``web/viewer/page.py``) loads in
real headless chromium without a console error. viser 1.1's client compiled its Gaussian
splat sorter (an Emscripten module whose embind glue builds its invokers with
``Function(...)``) eagerly at page load, splats shown or not; under a policy without
``'unsafe-eval'`` that threw "Evaluating a string as JavaScript violates the following
Content Security Policy directive…" on every 3D view. armtrack draws no splats: the page
it serves loads the sorter when a splat first needs it (never), and the policy stays
without ``'unsafe-eval'`` (docs/security.md)."""

from __future__ import annotations

import pytest
from test_api_docs_browser import strict_policy
from test_pages_browser import browser_context, page, shots, sync_api  # noqa: F401

pytestmark = pytest.mark.slow

#: Reports every policy refusal on the page as a console error (Chromium reports an
#: ``eval`` refusal only as an exception, or not at all when the promise is caught).
REPORT_VIOLATIONS = """
document.addEventListener("securitypolicyviolation", e => console.error(
  "CSP violation: " + e.violatedDirective + " " + e.blockedURI + " at " + e.sourceFile
  + ":" + e.lineNumber + ":" + e.columnNumber));
"""


def test_the_3d_view_loads_without_a_console_error(module_server, page, shots):  # noqa: F811
    api = module_server.client("alice")
    patient = api.patient("Console Clean")
    grant = api.http.post("/api/viewer", json={"patient_id": patient["id"]})
    assert grant.status_code == 200, grant.text
    problems: list[str] = []
    logs: list[str] = []
    page.on("console", lambda m: (problems if m.type == "error" else logs).append(m.text))
    page.on("pageerror", lambda e: problems.append(f"uncaught: {e}"))
    page.on("requestfailed", lambda r: problems.append(f"failed {r.url[:80]}"))
    page.add_init_script(REPORT_VIOLATIONS)
    answer = page.goto(module_server.url + grant.json()["url"])
    csp = answer.headers["content-security-policy"]
    script = dict(part.strip().split(" ", 1) for part in csp.split(";")
                  if part.strip())["script-src"]
    assert "'unsafe-eval'" not in script.split() and "'unsafe-inline'" not in script, csp
    canvas = page.locator("canvas").first
    sync_api.expect(canvas).to_be_visible(timeout=60_000)
    deadline_ms = 30_000
    while not any(text.startswith("Connected!") for text in logs) and deadline_ms > 0:
        page.wait_for_timeout(250)
        deadline_ms -= 250
    assert any(text.startswith("Connected!") for text in logs), logs
    sync_api.expect(page.get_by_text("Waiting for the kit").first).to_be_visible(  # panel
        timeout=30_000)
    page.wait_for_timeout(3000)  # anything the page starts after its first frames
    page.screenshot(path=str(shots / "viewer-console.png"))
    print(f"\n3D view console errors: {problems}")
    assert not problems, problems


def test_the_pages_policy_is_still_strict(module_server):
    """The view's policy allows WebAssembly (``'wasm-unsafe-eval'``: viser's zstd decoder)
    but not ``eval``; the pages' own policy neither (``strict_policy``)."""
    import httpx

    answer = httpx.get(module_server.url + "/signin")
    strict_policy(answer.headers["content-security-policy"])
