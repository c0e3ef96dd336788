"""Helpers of the dashboard's browser tests (the fixtures are in test_pages_browser)."""

from __future__ import annotations

import re

from server_support import PASSWORD


def sign_in_as(page, base: str, name: str, password: str = PASSWORD) -> None:
    """Sign in on the sign-in page and land on the patients' list."""
    page.goto(base + "/signin")
    page.fill("#username", name)
    page.fill("#password", password)
    page.click("#submit")
    page.wait_for_url(re.compile(r".*/patients$"))
