"""A kit link opened on a phone that holds another kit's (attack, session of 2026-12-04):
the page took the new token silently, so whoever sent the patient a `/kit#token=…` link
could make their phone stream into a kit the sender controls (another patient's record,
or the sender's own). Now the page asks, in plain words at 390 px, naming both kits as
the server tells them for their tokens (the patient's first name, the kit's name), and
keeps the phone's kit unless the patient says to change. A link that does not work tells
nothing and replaces nothing; a phone without a kit takes its first link as before.
Real server, chromium at 390 px."""

from __future__ import annotations

import secrets

import pytest
from browser_helpers import need_browser, screenshots_folder
from server_support import server_fixture
from test_phone_kit_errors_browser import fits, phone  # noqa: F401 (phone: a fixture)

sync_api = need_browser()

server = server_fixture("kit-switch-server", "alice")

TOKEN_KEY = "localStorage.getItem('armtrack.kit.token')"


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    return screenshots_folder(tmp_path_factory, "kit-switch-shots")


def test_another_kits_link_asks_first_and_no_keeps_the_phones_kit(server, phone, shots):  # noqa: F811 (phone: imported)
    api = server.client("alice")
    anna = api.patient("Anna Berg")
    mine = api.device(anna["id"], "Anna's phone")["token"]
    other = api.patient("Mallory Kent")
    theirs = api.device(other["id"], "spare kit")["token"]

    phone.goto(f"{server.url}/kit#token={mine}")  # no kit yet: taken as it comes
    sync_api.expect(phone.locator("#start")).to_be_visible()
    assert phone.evaluate(TOKEN_KEY) == mine

    phone.goto(f"{server.url}/kit#token={theirs}")  # a link someone sent
    sync_api.expect(phone.locator("#replace-kit")).to_be_visible(timeout=20_000)
    said = phone.locator("#screen").inner_text()
    print("\n" + said)
    phone.screenshot(path=str(shots / "switch-ask.png"), full_page=True)
    assert "token" not in phone.url
    assert "Anna" in said and "Anna's phone" in said  # the kit it holds
    assert "Mallory" in said and "spare kit" in said  # the kit of the link
    assert "Berg" not in said and "Kent" not in said  # first names only
    assert phone.evaluate(TOKEN_KEY) == mine, "replaced before the patient said so"
    fits(phone)
    for button in ("#keep-kit", "#replace-kit"):
        box = phone.locator(button).bounding_box()
        assert box["x"] >= 0 and box["x"] + box["width"] <= 390 and box["height"] >= 44

    phone.click("#keep-kit")
    sync_api.expect(phone.locator("#start")).to_be_visible()
    assert phone.evaluate(TOKEN_KEY) == mine
    phone.reload()  # and it stays so
    sync_api.expect(phone.locator("#start")).to_be_visible()
    assert phone.evaluate(TOKEN_KEY) == mine
    assert api.http.get(f"/api/patients/{other['id']}/sessions").json() == []


def test_another_kits_link_replaces_the_kit_when_the_patient_says_so(server, phone, shots):  # noqa: F811 (phone: imported)
    api = server.client("alice")
    old = api.device(api.patient("Ruth Old")["id"], "old phone")["token"]
    new = api.device(api.patient("Ruth New")["id"], "new phone")["token"]
    phone.goto(f"{server.url}/kit#token={old}")
    sync_api.expect(phone.locator("#start")).to_be_visible()
    phone.goto(f"{server.url}/kit#token={new}")
    phone.click("#replace-kit")
    sync_api.expect(phone.locator("#start")).to_be_visible()
    phone.screenshot(path=str(shots / "switch-replaced.png"))
    assert phone.evaluate(TOKEN_KEY) == new


def test_a_link_that_does_not_work_tells_nothing_and_keeps_the_kit(server, phone, shots):  # noqa: F811 (phone: imported)
    api = server.client("alice")
    mine = api.device(api.patient("Olga Held")["id"], "Olga's phone")["token"]
    phone.goto(f"{server.url}/kit#token={mine}")
    sync_api.expect(phone.locator("#start")).to_be_visible()
    unknown = "dev_" + secrets.token_urlsafe(32)  # well-shaped, no kit's
    phone.goto(f"{server.url}/kit#token={unknown}")
    sync_api.expect(phone.locator("h1")).to_have_text("This link no longer works")
    said = phone.locator("#screen").inner_text()
    print("\n" + said)
    phone.screenshot(path=str(shots / "switch-dead-link.png"))
    assert "kept" in said or "stays" in said
    assert phone.evaluate(TOKEN_KEY) == mine
    fits(phone)
    phone.goto(f"{server.url}/kit")  # the home-screen icon: the phone's kit still works
    sync_api.expect(phone.locator("#start")).to_be_visible()
