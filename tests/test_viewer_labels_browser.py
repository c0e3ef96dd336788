"""The 3D view's angle labels read on a phone (390 px): the page shows the 600 px view
scaled down to its box (viewer_fit.js) and tells the server by how much, so the label
text drawn by viser reads at least 11 px on the screen (8.2 px before: 12 px × 1.2 ×
0.57), while a laptop's (1366 px, the view shown whole) stays 14.4 px.

Measured from pixels in real headless chromium, the live page of a real server with a
kit streaming: in the view's screenshot, the ink width of the elbow label's first words
("Elbow flexion", ``words_width``) at 390 px against the same words at 1366 px (14.4 px
there by viser's 12 px × 1.2): text width is proportional to its size, and ~80 px of
width measures it finer than ~10 px of ink height."""

from __future__ import annotations

import io
import itertools
import math
import re
import time
from pathlib import Path

import numpy as np
import pytest
from browser_helpers import sign_in_as
from server_support import ServerProcess
from test_layout_browser import long_exercise
from test_pages_browser import (  # noqa: F401
    KitThread,
    browser_context,
    expect_viewer_canvas,
    page,
    shots,
    sync_api,
)

pytestmark = pytest.mark.slow
expect = sync_api.expect
#: viser's label text at 1366 px (the view shown whole): 12 px × LABEL_SCALE 1.2 [px].
LAPTOP_LABEL_PX = 14.4


def words_width(png: bytes) -> tuple[int, int]:
    """The ink width [px] of the elbow label's first two words ("Elbow flexion", the same
    whatever the angle) in a view's screenshot, and the height of its text rows [px].

    The label's text rows: the tallest block of rows, in the lower 60 % of the view (below
    the panel and the notices), with at least 8 changes between dark grey ink and
    anything else along them. Ink: grey and darker than 170 of 255 (the label's
    antialiased strokes); the label's own glyphs are the pieces of ink (8-connected) that
    lie within those rows (0.35 × their height above or below at most) and are at least
    half as tall as them. What lies behind the label is not counted: a grid line or the
    arm's edge running through the rows reaches beyond them, and the lone grey pixel a
    grid line leaves at the label's edge is too short (it read 41 px instead of 78 where
    it lay left of "Elbow", tests/fixtures/viewer/labels-390-stray-ink.png). In those rows
    the label is the leftmost glyph (it hangs below its point on the arm); its words end
    where a gap of at least 0.35 × the rows' height has no glyph ink (a space)."""
    from PIL import Image
    from scipy import ndimage

    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    grey = rgb.max(axis=2) - rgb.min(axis=2) < 40
    dark = (rgb.max(axis=2) < 110) & grey
    top = int(0.4 * len(dark))
    dark[:top] = False
    changes = np.abs(np.diff(dark.astype(int), axis=1)).sum(axis=1)
    rows = np.flatnonzero(changes >= 8)
    if len(rows) == 0:
        return 0, 0
    runs = np.split(rows, np.flatnonzero(np.diff(rows) > 2) + 1)
    band = max(runs, key=len)
    lo, hi = int(band[0]), int(band[-1])
    height = hi - lo + 1
    margin = math.ceil(0.35 * height)
    ink = (rgb.max(axis=2) < 170) & grey
    pieces, _ = ndimage.label(ink, structure=np.ones((3, 3), dtype=int))
    glyphs = np.zeros_like(ink)
    for number, (rows_of, cols_of) in enumerate(ndimage.find_objects(pieces), start=1):
        if (rows_of.start >= lo - margin and rows_of.stop - 1 <= hi + margin
                and rows_of.stop - rows_of.start >= height / 2):
            glyphs[rows_of, cols_of] |= pieces[rows_of, cols_of] == number
    cols = np.flatnonzero(glyphs[lo:hi + 1].any(axis=0))
    ends = [int(a) for a, b in itertools.pairwise(cols) if b - a - 1 >= margin]
    if len(ends) < 2:
        return 0, height
    return ends[1] - int(cols[0]) + 1, height


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("labels"))
    server.create_user("alice")
    server.start()
    try:
        yield server
    finally:
        server.stop()


def label_on_screen(page, shots, server, width: int, height: int) -> int:  # noqa: F811
    """The ink width [px] of the elbow label's "Elbow flexion" in the live view opened at
    ``width`` (``words_width``), a kit of a new patient streaming meanwhile."""
    api = server.client("alice")
    patient = api.patient(f"Label Reader {width}", side="right", height_m=1.70)
    device = api.device(patient["id"], "live kit")
    kit = KitThread(long_exercise(), server.ws_url, device["token"])
    try:
        page.set_viewport_size({"width": width, "height": height})
        sign_in_as(page, server.url, "alice")
        page.goto(f"{server.url}/patients/{patient['id']}")
        page.locator("text=Open the live view").click(timeout=30_000)
        page.wait_for_url(re.compile(r".*/sessions/\d+$"))
        expect_viewer_canvas(page, shots, f"labels-{width}")
        elbow = page.locator("#angles-table tr[data-angle=elbow_flexion] td.pct")
        deadline = time.monotonic() + 60  # the elbow's arc and label once it moved 10°
        while time.monotonic() < deadline and not elbow.inner_text().strip():
            time.sleep(0.5)
        page.wait_for_timeout(4000)  # software WebGL on a busy machine: let frames come
        view = page.locator("#viewer")
        png = view.screenshot(timeout=90_000)
    finally:
        kit.cut()
    (shots / f"labels-view-{width}.png").write_bytes(png)
    width_px, rows_px = words_width(png)
    print(f"\nat {width} px: 'Elbow flexion' {width_px} px wide (text rows {rows_px} px high)")
    return width_px


def test_the_label_is_measured_from_its_own_glyphs():
    """A view at 390 px where a grid line left one grey pixel in the label's rows, 4 px
    left of "Elbow" (taken while the arm moved): the label is measured, not the line."""
    png = (Path(__file__).parent / "fixtures" / "viewer" / "labels-390-stray-ink.png"
           ).read_bytes()
    assert words_width(png) == (78, 9)


def test_the_angle_labels_read_on_a_phone(server, page, shots):  # noqa: F811
    phone = label_on_screen(page, shots, server, 390, 844)
    laptop = label_on_screen(page, shots, server, 1366, 900)
    assert laptop > 0 and phone > 0, (laptop, phone)
    phone_px = LAPTOP_LABEL_PX * phone / laptop
    print(f"the label reads {phone_px:.1f} px on the phone ('Elbow flexion' {phone} px wide; "
          f"{laptop} px for {LAPTOP_LABEL_PX} px at 1366)")
    assert phone_px >= 11.0, f"the label reads {phone_px:.1f} px at 390 px"
