"""The Unicode characters that change the order text shows in (direction controls), and
how a name holding one is shown. Apart from ``plain_text`` so that the database models
(and ``armtrack create-user``, which loads them) need no web framework."""

from __future__ import annotations

import re

#: The characters that change the order text shows in, by their Unicode names.
DIRECTION = {
    "\u202a": "LEFT-TO-RIGHT EMBEDDING", "\u202b": "RIGHT-TO-LEFT EMBEDDING",
    "\u202c": "POP DIRECTIONAL FORMATTING", "\u202d": "LEFT-TO-RIGHT OVERRIDE",
    "\u202e": "RIGHT-TO-LEFT OVERRIDE", "\u2066": "LEFT-TO-RIGHT ISOLATE",
    "\u2067": "RIGHT-TO-LEFT ISOLATE", "\u2068": "FIRST STRONG ISOLATE",
    "\u2069": "POP DIRECTIONAL ISOLATE", "\u200e": "LEFT-TO-RIGHT MARK",
    "\u200f": "RIGHT-TO-LEFT MARK", "\u061c": "ARABIC LETTER MARK",
}
_DIRECTION = re.compile("[" + "".join(DIRECTION) + "]")


def shown(text: str | None) -> str | None:
    """``text`` with each direction control written out as ``[U+202E]``: how a name stored
    before they were refused is read back, so no page, report or export shows it
    reordered."""
    if not isinstance(text, str) or not _DIRECTION.search(text):  # None (or a kit's
        # metadata value of another type) as it is
        return text
    return _DIRECTION.sub(lambda m: f"[U+{ord(m[0]):04X}]", text)
