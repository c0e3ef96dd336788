"""What the server takes as text from users and kits: names, notes, a kit's device name.

Text must be valid Unicode that UTF-8 can hold (JSON's ``\\ud800`` escape gives a lone
surrogate, which every later encoding — SQLite, PostgreSQL, CSV, PDF, a JSON answer —
refuses: the routes that showed it answered 500 for good) and holds no control character
(U+0000–U+001F, U+007F–U+009F: PostgreSQL refuses NUL, and the others only break lines of
logs, CSV files and pages); a note may hold line breaks and tabs. A name (one-line text)
holds no direction control either (``DIRECTION``: U+202A–U+202E, U+2066–U+2069, U+200E,
U+200F, U+061C): "Anna\u202eevil" shows as "Annalive", so one patient could be made to
look like another ("Trojan Source"). Refused where it comes in, with the field named: 422
in REST, an ``error`` (close 4400) for a ``hello``. A name stored before that rule is read
back with each such character written out (``text_direction.shown``, in ``db.models.Name``).
"""

from __future__ import annotations

import logging
import math
import re
from typing import Annotated

from fastapi.encoders import jsonable_encoder
from fastapi.responses import JSONResponse
from pydantic import AfterValidator
from sqlalchemy.exc import OperationalError

from .db.errors import NOT_UPGRADED, database_words, lacks_schema, told_words
from .text_direction import _DIRECTION, DIRECTION

log = logging.getLogger("armtrack")

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")
_CONTROL_BUT_LINES = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")
def text_problem(text: str, *, lines: bool = False) -> str | None:
    """Why ``text`` is not acceptable text (words to follow "must be valid text: "), or
    None. ``lines``: line breaks and tabs are allowed (notes)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as exc:
        return (f"character {exc.start} is a lone surrogate (U+{ord(text[exc.start]):04X}), "
                "which is no character")
    found = (_CONTROL_BUT_LINES if lines else _CONTROL).search(text)
    if found:
        return f"character {found.start()} is a control character (U+{ord(found[0]):04X})"
    found = None if lines else _DIRECTION.search(text)
    if found:
        return (f"character {found.start()} is a direction control (U+{ord(found[0]):04X} "
                f"{DIRECTION[found[0]]}), which makes a name show in another order than it "
                "is written: remove it")
    return None


def _check(lines: bool):
    def check(text: str) -> str:
        problem = text_problem(text, lines=lines)
        if problem:
            raise ValueError(f"must be valid text: {problem}")
        return text
    return check


def _check_secret(text: str) -> str:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise ValueError("must be valid text: it holds a lone surrogate, which is no "
                         "character") from None
    return text


#: A name or other one-line text (no control characters, no direction controls).
Line = Annotated[str, AfterValidator(_check(lines=False))]
#: A note: line breaks and tabs allowed.
Note = Annotated[str, AfterValidator(_check(lines=True))]
#: A password: anything UTF-8 can hold.
Secret = Annotated[str, AfterValidator(_check_secret)]


#: How deep an error's echo of the input goes; deeper containers are shown as "…".
ECHO_DEPTH = 8


def printable(value, depth: int = 0):
    """``value`` (JSON-like: dicts, lists, strings, numbers) as a JSON answer can hold it,
    to echo a client's input in an error: a lone surrogate becomes U+FFFD, NaN and ±Infinity
    (Python's JSON reads them) their names as text, a container deeper than ``ECHO_DEPTH``
    "…" (one nested some hundreds deep overflowed the encoder's recursion). Anything else
    is left as it is (an error's context: ``jsonable_encoder`` writes it)."""
    if isinstance(value, str):
        return value.encode("utf-16", "surrogatepass").decode("utf-16", "replace")
    if isinstance(value, float) and not math.isfinite(value):
        return "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    if isinstance(value, dict | list | tuple) and depth >= ECHO_DEPTH:
        return "…"
    if isinstance(value, dict):
        return {printable(k): printable(v, depth + 1) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [printable(v, depth + 1) for v in value]
    return value


#: Words in a field's name that make its value a secret, never echoed (shown as ***).
SECRET_FIELDS = ("password", "token", "secret")


def _secret(name: object) -> bool:
    return isinstance(name, str) and any(word in name.lower() for word in SECRET_FIELDS)


def _hidden(value, depth: int = 0):
    """``value`` with the values of secret-named keys as ``***``, however deep."""
    if isinstance(value, dict) and depth < ECHO_DEPTH:
        return {k: "***" if _secret(k) else _hidden(v, depth + 1) for k, v in value.items()}
    if isinstance(value, list | tuple) and depth < ECHO_DEPTH:
        return [_hidden(v, depth + 1) for v in value]
    return value


def _without_secrets(error: dict) -> dict:
    """One error of a 422 whose echoed ``input`` keeps no password: the refused field's
    own value when its name is a secret's, and secret-named keys in a whole body."""
    if "input" not in error:
        return error
    loc = error.get("loc") or ()
    shown = "***" if loc and _secret(loc[-1]) else _hidden(error["input"])
    return {**error, "input": shown}


async def validation_error(request, exc) -> JSONResponse:
    """FastAPI's 422 answer, with the echoed input made encodable: a lone surrogate, a NaN
    or a deeply nested input in a body made the answer itself fail (a 500 instead of the
    422 naming the field). A password (a too-short new one, or a whole body with a
    misnamed field) is not echoed: ``***`` (it went back to whatever keeps response
    bodies: a proxy's log, the browser's)."""
    errors = [_without_secrets(e) for e in exc.errors()]
    return JSONResponse(status_code=422,
                        # again after the encoder: an error's context it wrote as text
                        content={"detail": printable(jsonable_encoder(printable(errors)))})


async def database_failed(request, exc) -> JSONResponse:
    """A request the database could not serve (SQLAlchemy's ``OperationalError`` or
    ``ProgrammingError``). A table or column not there (SQLite's "no such table", PostgreSQL's
    'column … does not exist': a database of another armtrack version, not upgraded):
    500 saying what to run (``NOT_UPGRADED``), since waiting will not mend it; any other
    ``OperationalError``: 503 "try again" (``database_unavailable``); any other
    ``ProgrammingError``: the server's fault, a plain 500 with its traceback in the log."""
    words = database_words(exc)
    if lacks_schema(words):
        log.error("%s %s: the database lacks what this armtrack needs (not upgraded?): %s",
                  request.method, request.url.path, words)
        services = getattr(getattr(getattr(request, "app", None), "state", None),
                           "services", None)
        if services is not None:  # /healthz asks the database again
            services.schema_suspect()
        return JSONResponse(status_code=500, content={
            "detail": f"The server cannot serve this: {NOT_UPGRADED}."})
    if not isinstance(exc, OperationalError):
        raise exc
    return await database_unavailable(request, exc)


async def database_unavailable(request, exc) -> JSONResponse:
    """503 in words for a request the database cannot serve just now (SQLAlchemy's
    ``OperationalError``: a full disk, a database locked past the busy timeout, PostgreSQL
    gone): what kind of failure and what to do, instead of a bare 500 "Internal Server
    Error"; the database's words in the log (``told_words``: PostgreSQL's name its host)."""
    log.warning("%s %s: the database failed: %s", request.method, request.url.path, exc)
    return JSONResponse(status_code=503, headers={"Retry-After": "60"}, content={
        "detail": f"The server cannot store or read this just now: {told_words(exc)}. "
                  f"Try again in a few minutes; if it lasts, tell the clinic's IT (the "
                  f"server's log says more)."})
