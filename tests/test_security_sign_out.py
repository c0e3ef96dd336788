"""Signing out ends the sign-in on the server.

The dashboard's "Sign out" only forgot the token in its own tab: the token stayed good for
its whole lifetime (``ARMTRACK_ACCESS_TOKEN_HOURS``, 12 h), so any copy of it kept reading
the therapist's patients, a live feed opened with it kept streaming, and another tab opened
from the signed-out one (Ctrl-click: the token is handed over) stayed signed in — on a
shared clinic computer, for whoever sat down next. A real server, a real WebSocket feed
and Debian's headless chromium."""

from __future__ import annotations

import json
import re
import time

import httpx
import pytest
from browser_helpers import chromium, first_page, need_browser, sign_in_as
from server_support import server_fixture
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

server = server_fixture("sign_out", "alice")


def live_feed(server, token: str, patient_id: int):
    """An open ``/ws/live`` feed of the patient with ``token``."""
    return connect(f"ws://127.0.0.1:{server.port}/ws/live?patient={patient_id}", proxy=None,
                   additional_headers={"Authorization": f"Bearer {token}"})


def close_code(feed, seconds: float = 15.0) -> int | None:
    """The feed's close code once it closes within ``seconds``; None if still open."""
    try:
        while True:
            feed.recv(seconds)
    except TimeoutError:
        return None
    except ConnectionClosed as exc:
        return exc.rcvd.code if exc.rcvd else None


def test_signing_out_ends_that_sign_in_and_its_feeds_only(server):
    here, elsewhere = server.client("alice"), server.client("alice")
    patient = here.patient("Ada")
    with live_feed(server, here.token, patient["id"]) as feed, \
            live_feed(server, elsewhere.token, patient["id"]) as other_feed:
        answer = here.http.post("/api/auth/signout")
        assert answer.status_code == 204, answer.text
        assert here.http.get("/api/patients").status_code == 401
        assert close_code(feed) == 4401, "the signed-out token's live feed stayed open"
        assert elsewhere.http.get("/api/patients").status_code == 200
        assert close_code(other_feed, 1.0) is None, "another sign-in's feed was closed"
    again = here.http.post("/api/auth/signout")
    assert again.status_code == 401
    assert httpx.post(server.url + "/api/auth/signout").status_code == 401


@pytest.mark.parametrize("width", [1366, 390])
def test_the_sign_out_button_ends_the_sign_in_and_the_tabs_opened_from_it(server, width):
    sync_api = need_browser()
    api = server.client("alice")
    patient = api.patient(f"Bea {width}")
    with sync_api.sync_playwright() as playwright, chromium(playwright, width) as context:
        page = first_page(context)
        sign_in_as(page, server.url, "alice")
        token = page.evaluate("sessionStorage.getItem('armtrack.token')")
        link = page.locator(f"a[href='/patients/{patient['id']}'], "
                            f"tr.clickable:has-text('Bea {width}')").first
        with context.expect_page() as opened:
            link.click(modifiers=["Control"])
        other = opened.value
        other.set_default_timeout(30_000)
        other.wait_for_url(re.compile(rf".*/patients/{patient['id']}$"))
        other.wait_for_function("sessionStorage.getItem('armtrack.token') !== null")
        with live_feed(server, token, patient["id"]) as feed:
            page.locator("button", has_text="Sign out").click()
            page.wait_for_url(re.compile(r".*/signin"))
            deadline = time.monotonic() + 15  # the page's request goes on after it left
            while (still := httpx.get(server.url + "/api/patients", headers={
                    "Authorization": f"Bearer {token}"}).status_code) != 401 \
                    and time.monotonic() < deadline:
                time.sleep(0.2)
            print(f"{width} px: the signed-out token's GET /api/patients:", still)
            assert still == 401, "the token still works after Sign out"
            assert close_code(feed) == 4401
        other.wait_for_url(re.compile(r".*/signin"), timeout=15_000)
        assert other.evaluate("sessionStorage.getItem('armtrack.token')") is None
        assert json.dumps(patient["name"]) not in other.content()
