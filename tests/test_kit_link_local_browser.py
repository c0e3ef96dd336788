"""The phone kit's link when the server was opened on its own computer: a therapist (or the
clinic's IT trying armtrack out) adds a phone kit on ``http://127.0.0.1:…`` and got a link
and QR code naming 127.0.0.1 — which on the patient's phone is the phone itself — with no
word of it (a loopback address counts as secure, so the https notice stayed away). Now the
box says a phone cannot open it and what to set; with ``ARMTRACK_PUBLIC_URL`` there is
no such notice. On the patient page at 1280 px, a real server, Debian's chromium."""

from __future__ import annotations

import pytest
from browser_helpers import need_browser, page_at, screenshots_folder, sign_in_as
from server_support import server_fixture

sync_api = need_browser()

local = server_fixture("kit-link-local", "alice")
public = server_fixture("kit-link-public", "alice",
                        env={"ARMTRACK_PUBLIC_URL": "https://rehab.example.org"})


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    return screenshots_folder(tmp_path_factory, "kit-link-shots")


def add_phone_kit(server, shots, name: str) -> str:
    """Adds a kit on a new patient's page at 1280 px; the kit box's words."""
    patient = server.client("alice").patient(f"Patient of {name}")
    with page_at(1280) as page:
        sign_in_as(page, server.url, "alice")
        page.goto(f"{server.url}/patients/{patient['id']}")
        page.fill("#device-name", "Maria's phone")
        page.click("#add-device button[type=submit]")
        sync_api.expect(page.locator("#kit-link")).to_be_visible()
        page.locator("#kit-link").screenshot(path=str(shots / f"{name}.png"))
        return page.locator("#kit-link").inner_text()


def test_a_link_naming_this_computer_says_a_phone_cannot_open_it(local, shots):
    said = add_phone_kit(local, shots, "local")
    print("\n" + said)
    assert "127.0.0.1" in said
    assert "a phone cannot open it" in said and "ARMTRACK_PUBLIC_URL" in said


def test_a_public_address_gets_no_such_notice(public, shots):
    said = add_phone_kit(public, shots, "public")
    print("\n" + said)
    assert "https://rehab.example.org/kit#token=" in said
    assert "a phone cannot open it" not in said and "not https" not in said
