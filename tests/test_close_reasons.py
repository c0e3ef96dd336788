"""Security review (review7's finding 3): a refusal's close reason was the first 123 bytes
of its ``error`` (a close frame holds no more), so a long one reached the kit cut mid-word
— and the phone kit shows a 4400's reason to its patient. Every close reason the server
sends is now a whole, short sentence within 123 bytes: the reason itself when it fits,
else its close code's short sentence (the whole explanation is in the ``error`` message
sent just before). Checked on every close reason written in the server's code, with ids
and limits at their largest, and on a real server."""

from __future__ import annotations

import ast
import asyncio
import json
from pathlib import Path

import pytest
from armtrack.server.ingest import protocol
from armtrack.server.live.slots import FeedSlots
from test_security_ingest import kit
from websockets.exceptions import ConnectionClosed

ROOT = Path(__file__).resolve().parents[1]
#: The largest value a close reason's placeholder takes (ids and limits are 32-bit).
LARGEST = "2147483647"


def ends_properly(reason: str) -> bool:
    """Whole words, nothing left open: no trailing space, comma, colon, hyphen or
    ellipsis, brackets and quotes balanced."""
    return (bool(reason) and reason == reason.strip()
            and reason[-1] not in ",;:-(…'\"" and reason.count("(") == reason.count(")")
            and reason.count("'") % 2 == 0 and reason.count('"') % 2 == 0)


def fits(reason: str) -> bool:
    return len(reason.encode("utf-8")) <= protocol.CLOSE_REASON_BYTES


def _text(node: ast.expr) -> str | None:
    """A string literal's text, an f-string's with each placeholder at ``LARGEST``."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(v.value if isinstance(v, ast.Constant) else LARGEST
                       for v in node.values)
    return None


def written_close_reasons() -> list[tuple[str, str]]:
    """(where, reason) of every close reason written in the server's code: the second
    argument of ``….close(code, reason)`` and ``end_session_streams(id, reason)``, and
    the reason of a ``(CLOSE_…, reason)`` pair (``live/access.py``'s)."""
    found = []
    for path in sorted([*(ROOT / "server").rglob("*.py"), *(ROOT / "web").rglob("*.py")]):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            reason = None
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr in ("close", "end_session_streams")
                    and len(node.args) == 2):
                reason = _text(node.args[1])
            elif (isinstance(node, ast.Tuple) and len(node.elts) == 2
                  and isinstance(node.elts[0], ast.Name)
                  and node.elts[0].id.startswith("CLOSE_")):
                reason = _text(node.elts[1])
            if reason is not None:
                found.append((f"{path.relative_to(ROOT)}:{node.lineno}", reason))
    return found


def test_every_close_reason_in_the_code_is_whole_and_fits():
    reasons = [*written_close_reasons(),
               *(("SHORT_CLOSE_REASONS", r) for r in protocol.SHORT_CLOSE_REASONS.values()),
               ("SHORT_CLOSE_REASON", protocol.SHORT_CLOSE_REASON),
               ("FeedSlots.close_reason", FeedSlots(2**31 - 1).close_reason())]
    print(f"{len(reasons)} close reasons, longest "
          f"{max(len(r.encode()) for _, r in reasons)} bytes")
    assert len(reasons) > 15  # the scan found the server's closes
    bad = [(where, r) for where, r in reasons if not (fits(r) and ends_properly(r))]
    assert bad == []


def test_a_reason_too_long_for_a_close_frame_gives_its_codes_whole_sentence():
    long = "hello: " + "a refusal that goes on " * 10
    assert protocol.close_reason(long, protocol.CLOSE_BAD_PROTOCOL) \
        == protocol.SHORT_CLOSE_REASONS[protocol.CLOSE_BAD_PROTOCOL]
    assert protocol.close_reason(long, protocol.CLOSE_TOO_MANY_ERRORS) \
        == protocol.SHORT_CLOSE_REASONS[protocol.CLOSE_TOO_MANY_ERRORS]
    assert protocol.close_reason(long, 1001) == protocol.SHORT_CLOSE_REASON
    assert protocol.close_reason("short enough", 4400) == "short enough"
    exact = "é" * (protocol.CLOSE_REASON_BYTES // 2)  # 122 bytes: fits
    assert protocol.close_reason(exact, 4400) == exact


@pytest.mark.parametrize("hello", [
    {"side": "€" * 100},  # a refusal echoing the kit's wide characters
    {"sensors": ["forearm", "forearm"]},
    {"rate_hz": 1e9},
    {"sensors": ["forearm", "wrist_strap"]},  # its error lists the sensors there are
])
def test_a_refused_hello_closes_with_a_whole_reason(module_server, hello):
    alice = module_server.client("alice")
    token = alice.device(alice.patient("Refused hellos")["id"])["token"]

    async def scenario():
        ws, error = await kit(module_server, token, **hello)
        with pytest.raises(ConnectionClosed) as closed:
            await asyncio.wait_for(ws.recv(), 10)
        return error, closed.value.rcvd

    error, close = asyncio.run(scenario())
    print(json.dumps(error)[:100], "→", close.code, repr(close.reason))
    assert error["type"] == "error" and error["reason"].startswith("hello:"), error
    assert close.code == 4400
    assert fits(close.reason) and ends_properly(close.reason), close.reason
    if fits(error["reason"]):
        assert close.reason == error["reason"]
    else:
        assert close.reason == protocol.SHORT_CLOSE_REASONS[4400]
