"""``/docs`` (Swagger UI) and ``/redoc`` (ReDoc) render in real headless chromium with
the pages' strict Content-Security-Policy kept: their JavaScript and CSS come from this
server (the ``fastapi-offline`` package), not from a CDN, and no inline script runs.
Screenshots go to the printed folder. Skips when chromium or Playwright is absent."""

from __future__ import annotations

import httpx
import pytest
from test_pages_browser import browser_context, page, shots, sync_api  # noqa: F401

pytestmark = pytest.mark.slow


def strict_policy(csp: str) -> None:
    directives = dict([*part.strip().split(" ", 1), ""][:2] for part in csp.split(";")
                      if part.strip())
    script = directives["script-src"].split()
    assert script[0] == "'self'", csp
    assert all(s == "'self'" or s.startswith("'sha256-") for s in script), csp
    assert "unsafe-inline" not in directives["script-src"], csp
    assert "unsafe-eval" not in csp, csp
    assert "http" not in csp, f"a foreign origin is allowed: {csp}"


#: ReDoc's "API docs by Redocly" footer always asks for this logo; the policy refuses it
#: before any request leaves and ReDoc hides the picture when it fails.
REDOC_LOGO = "https://cdn.redoc.ly/redoc/logo-mini.svg"


def watch_console(page) -> list[str]:  # noqa: F811
    """Console errors and failed requests of the page (a CSP refusal is one)."""
    problems: list[str] = []
    page.on("console", lambda m: problems.append(m.text) if m.type == "error"
            and REDOC_LOGO not in m.text else None)
    page.on("requestfailed", lambda r: problems.append(f"failed {r.url}")
            if r.url != REDOC_LOGO else None)
    page.on("response", lambda r: problems.append(f"{r.status} {r.url}")
            if r.status >= 400 else None)
    return problems


@pytest.mark.parametrize("width", [1366, 390])
def test_swagger_ui_renders_the_operations(module_server, page, shots, width):  # noqa: F811
    page.set_viewport_size({"width": width, "height": 900})
    problems = watch_console(page)
    answer = page.goto(module_server.url + "/docs")
    strict_policy(answer.headers["content-security-policy"])
    operations = page.locator(".opblock")
    sync_api.expect(operations.first).to_be_visible(timeout=30_000)
    post = page.locator(".opblock-post .opblock-summary-path",
                        has_text="/api/patients").first
    sync_api.expect(post).to_be_visible()
    sync_api.expect(page.locator(".opblock-get .opblock-summary-path",
                                 has_text="/api/audit").first).to_be_visible()
    count = operations.count()
    spec = httpx.get(module_server.url + "/openapi.json").json()
    listed = sum(len(methods) for methods in spec["paths"].values())
    print(f"\n/docs at {width} px: {count} operation blocks of {listed} in the spec")
    assert count == listed
    # an operation opens, with its parameters: the UI runs, not only its first paint
    page.locator(".opblock-get .opblock-summary", has_text="/api/audit").first.click()
    sync_api.expect(page.locator(".opblock.is-open .parameters")
                    .first).to_contain_text("patient_id")
    page.screenshot(path=str(shots / f"api-docs-{width}.png"))
    assert not problems, problems


@pytest.mark.parametrize("width", [1366, 390])
def test_redoc_renders(module_server, page, shots, width):  # noqa: F811
    page.set_viewport_size({"width": width, "height": 900})
    problems = watch_console(page)
    answer = page.goto(module_server.url + "/redoc")
    strict_policy(answer.headers["content-security-policy"])
    sync_api.expect(page.locator("h1", has_text="armtrack").first).to_be_visible(timeout=30_000)
    operation = page.locator("h2", has_text="List Audit").first
    sync_api.expect(operation).to_be_attached()
    sync_api.expect(page.get_by_text("/api/audit").first).to_be_attached()
    page.screenshot(path=str(shots / f"api-redoc-{width}.png"))
    assert not problems, problems


def test_docs_assets_come_from_the_package_only(module_server):
    base = module_server.url
    for name, kind in (("swagger-ui-bundle.js", "text/javascript"),
                       ("swagger-ui.css", "text/css"),
                       ("redoc.standalone.js", "text/javascript")):
        answer = httpx.get(f"{base}/docs/assets/{name}")
        assert answer.status_code == 200, name
        assert answer.headers["content-type"].startswith(kind)
        assert len(answer.content) > 100_000, name
    for name in ("../core.py", "core.py", "favicon.png", "%2e%2e%2fcore.py"):
        assert httpx.get(f"{base}/docs/assets/{name}").status_code == 404, name
