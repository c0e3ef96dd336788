"""Helpers of the browser tests: Debian's headless chromium driven by Playwright (the
launch prologue every browser test file shares) and the dashboard's sign-in (the page
fixtures are in test_pages_browser, the phone kit's in test_phone_kit_browser)."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
from pathlib import Path

import pytest
from server_support import PASSWORD

#: Debian's chromium (``ARMTRACK_CHROMIUM`` chooses another).
CHROMIUM = os.environ.get("ARMTRACK_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
#: Headless, no sandbox (root in CI), nothing fetched from outside.
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def need_browser():
    """``playwright.sync_api``, or a skip naming what is missing (chromium, Playwright):
    at a module's top it skips the module, in a fixture the tests that take it."""
    if not Path(CHROMIUM).is_file():
        pytest.skip(f"needs Debian's chromium at {CHROMIUM} (apt-get install -y chromium; "
                    ".ci/run installs it)", allow_module_level=True)
    return pytest.importorskip("playwright.sync_api",
                               reason="needs Playwright: pip install -e '.[test]'")


@contextlib.contextmanager
def chromium(playwright, width: int, height: int = 900, *, phone: bool = False,
             args: list[str] = ARGS, **options):
    """A headless chromium with a fresh profile of its own (storage, service workers),
    its window ``width`` × ``height`` px; ``phone``: touch and a mobile viewport. The
    profile is removed once the browser is closed."""
    profile = tempfile.mkdtemp(prefix="armtrack-chromium-")
    context = playwright.chromium.launch_persistent_context(
        profile, executable_path=CHROMIUM, args=args, headless=True,
        viewport={"width": width, "height": height}, has_touch=phone, is_mobile=phone,
        **options)
    try:
        yield context
    finally:
        context.close()
        shutil.rmtree(profile, ignore_errors=True)


@contextlib.contextmanager
def page_at(width: int):
    """The first tab of a chromium of its own, ``width`` px wide (touch and a mobile
    viewport below 500 px: a phone)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright, chromium(playwright, width,
                                                   phone=width < 500) as context:
        yield first_page(context)


def dismissed_question(page, button) -> list[str]:
    """Click ``button``, answer the confirm it opens with Cancel; the question(s) asked
    (empty when none came within 0.5 s)."""
    questions: list[str] = []

    def dismiss(dialog):
        questions.append(dialog.message)
        dialog.dismiss()

    page.once("dialog", dismiss)
    button.click()
    page.wait_for_timeout(500)
    return questions


def first_page(context, timeout_ms: float = 30_000):
    """The persistent context's first tab (opened if none), with ``timeout_ms``."""
    page = context.pages[0] if context.pages else context.new_page()
    page.set_default_timeout(timeout_ms)
    return page


def screenshots_folder(tmp_path_factory, name: str = "screenshots") -> Path:
    """``ARMTRACK_SCREENSHOTS``, else a new temporary folder ``name``; printed."""
    folder = Path(os.environ.get("ARMTRACK_SCREENSHOTS") or tmp_path_factory.mktemp(name))
    folder.mkdir(parents=True, exist_ok=True)
    print(f"\nscreenshots: {folder}")
    return folder


def sign_in_as(page, base: str, name: str, password: str = PASSWORD) -> None:
    """Sign in on the sign-in page and land on the patients' list."""
    page.goto(base + "/signin")
    page.fill("#username", name)
    page.fill("#password", password)
    page.click("#submit")
    page.wait_for_url(re.compile(r".*/patients$"))
