"""Text that a spreadsheet would take as a formula (OWASP, "CSV injection"), made inert
for the CSV files the server writes: a cell of its own (``spreadsheet_text``), and a
recording's ``#`` header line, which a spreadsheet splits at its commas and semicolons
(``header_text``)."""

from __future__ import annotations

import re

#: A text cell starting with one of these is a formula to a spreadsheet; tab and carriage
#: return too, since some spreadsheets skip them first.
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")

#: A part of a line a spreadsheet makes a cell of: what follows a comma (the CSV's
#: separator) or a semicolon (Excel's in many locales) up to the next.
_SPLIT_CELL = re.compile(r"(?<=[,;])[^,;]*")
#: A plain decimal number (a cell a spreadsheet reads as a number, not a formula).
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")


def spreadsheet_text(value: object) -> object:
    """A text cell that a spreadsheet shows as text: one that would start a formula gets a
    leading apostrophe (OWASP). Numbers stay numbers (a negative angle is ``-12.5``)."""
    if isinstance(value, str) and value.startswith(FORMULA_START):
        return "'" + value
    return value


def header_text(value: str) -> str:
    """``value`` as written on a ``#`` line of a CSV file (a recording's ``key: value``):
    the line's first cell starts with ``#``, but a spreadsheet makes a cell of each part
    after a comma or semicolon; such a part that would start a formula, once its spaces
    and quotes are skipped, gets a leading apostrophe. Numbers (``0.1, -0.2``) and other
    text are kept as they are."""
    def inert(match: re.Match) -> str:
        cell = match.group(0)
        bare = cell.lstrip(' "')
        if not bare.startswith(FORMULA_START) or _NUMBER.fullmatch(bare.rstrip(' "')):
            return cell
        return "'" + cell
    return _SPLIT_CELL.sub(inert, value)
