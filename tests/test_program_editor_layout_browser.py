"""The program editor's exercise row in Debian's headless chromium at 390 and 1280 px
against a real server: its fields pair up, none left alone on a line of the grid.

Before, at 390 px (two columns) "to (°)" sat alone on its own line, apart from "Target
from (°)", and the move and remove buttons wrapped into one column (at 1280 px too). Now
the target's two ends share a line, and every line holds a field spanning the row or two
fields or more.
Skips with the reason when chromium or Playwright is absent."""

from __future__ import annotations

import pytest
from browser_helpers import need_browser, page_at, sign_in_as

sync_api = need_browser()

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("width", [390, 1280])
def test_the_exercise_rows_fields_pair_up(module_server, width, tmp_path):
    api = module_server.client("alice")
    patient = api.patient(f"Editor Layout {width}")
    with page_at(width) as page:
        sign_in_as(page, module_server.url, "alice")
        page.goto(f"{module_server.url}/patients/{patient['id']}")
        page.click("#new-program")
        row = page.locator("#program-editor .exercise-row").first
        sync_api.expect(row).to_be_visible()
        page.wait_for_timeout(300)
        # each grid item: its words (a label's first line, or the buttons') and its box
        items = row.evaluate("""(row) => [...row.children].map((c) => {
            const box = c.getBoundingClientRect();
            return { text: (c.innerText || "").split("\\n")[0].trim(), top: box.top,
                     bottom: box.bottom, left: box.left, right: box.right };
        })""")
        inner = row.evaluate("""(row) => {
            const s = getComputedStyle(row), b = row.getBoundingClientRect();
            return [b.left + parseFloat(s.paddingLeft), b.right - parseFloat(s.paddingRight)];
        }""")
        page.locator("#programs").screenshot(path=str(tmp_path / f"editor-{width}.png"))
        # a line of the grid: the items whose boxes overlap in height (aligned at their
        # bottoms, a select and an input differ by a few px)
        lines: list[list[dict]] = []
        for item in sorted(items, key=lambda i: i["top"]):
            if lines and item["top"] < max(i["bottom"] for i in lines[-1]) - 2:
                lines[-1].append(item)
            else:
                lines.append([item])
        print(f"\n{width} px ({tmp_path}):")
        for line in lines:
            print(f"  {line[0]['top']:5.0f} px: " + " | ".join(i["text"] for i in line))
        for line in lines:
            alone = len(line) == 1 and line[0]["right"] - line[0]["left"] < 0.9 * (
                inner[1] - inner[0])
            assert not alone, f"{line[0]['text']!r} alone on its line at {width} px"
        buttons = row.locator("button").evaluate_all(
            "bs => bs.map((b) => Math.round(b.getBoundingClientRect().top))")
        print(f"  the buttons' tops: {buttons} px")
        assert len(set(buttons)) == 1, f"the move and remove buttons wrap at {width} px"
        by_text = {i["text"]: i for i in items}
        assert any(by_text["to (°)"] in line and by_text["Target from (°)"] in line
                   for line in lines)
