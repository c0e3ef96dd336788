"""viser's client page and the policy it is served with.

viser (1.1) ships its client as one self-contained ``index.html``: an inline *loader*
script inflates a WebAssembly zstd decoder, decodes the page's payload (attribute
``data-p``: base-88 text of a zstd frame holding ``data-ss`` bytes of CSS, then
``data-cs`` bytes of JavaScript) and runs the JavaScript as a second inline script
(``<script type="module">`` with that text). The bundle starts web workers from
``blob:`` URLs and draws with WebGL; it talks to the server over a WebSocket on the
page's own origin.

The policy allows exactly that, computed from the installed viser's file at start-up
(never hard-coded, so an upgrade of viser cannot silently break the view or widen the
policy): the two inline scripts by their SHA-256 hashes, ``'wasm-unsafe-eval'`` for the
decoder (compiling WebAssembly, not ``eval``), workers from ``blob:``, connections to
the page's origin only (CSP 3's ``'self'`` covers ``ws:``/``wss:`` to the same host),
no frames, no plugins, no forms, no ``<base>``, framed only by our own pages. No
``'unsafe-inline'`` or ``'unsafe-eval'`` for scripts: an injected ``<script>``, event
handler attribute or ``srcdoc`` frame does not run. Styles stay ``'unsafe-inline'``
(Mantine and Emotion inject style elements at run time); CSS cannot run script.

When the page is not of that shape (another viser), only its literal inline scripts are
hashed; the view may then fail to draw, which the browser tests catch, but the policy
never loosens.
"""

from __future__ import annotations

import base64
import gzip
import hashlib
import html
import logging
import re
from functools import cache
from pathlib import Path

import viser

log = logging.getLogger(__name__)

#: The alphabet of viser's base-88 payload (``index.html``'s loader ``A``).
_ALPHABET = ("!#$%()*+,-./0123456789:;=?@ABCDEFGHIJKLMNOPQRSTUVWXYZ[\\]^_"
             "abcdefghijklmnopqrstuvwxyz{|}~")
_INLINE_SCRIPT = re.compile(rb"<script(?![^>]*\bsrc=)([^>]*)>(.*?)</script>", re.S)
_ATTRIBUTE = re.compile(rb'\b(data-p|data-ss|data-cs)="([^"]*)"')


def _page_path() -> Path:
    return Path(viser.__file__).parent / "client" / "build" / "index.html"


@cache
def client_page() -> tuple[bytes, bytes]:
    """viser's client page (one self-contained file), plain and gzipped."""
    page = _page_path().read_bytes()
    return page, gzip.compress(page, 6)


def _sha256(text: bytes) -> str:
    return "'sha256-" + base64.b64encode(hashlib.sha256(text).digest()).decode() + "'"


def _base88(text: str) -> bytes:
    """viser's loader's ``de``: groups of 5 characters → 4 bytes big-endian; a last group
    of r characters → r − 1 bytes."""
    index = {c: i for i, c in enumerate(_ALPHABET)}
    out = bytearray()
    whole = len(text) - len(text) % 5
    for i in range(0, whole, 5):
        value = 0
        for c in text[i:i + 5]:
            value = value * 88 + index[c]
        out += (value & 0xFFFFFFFF).to_bytes(4, "big")
    rest = len(text) % 5
    if rest:
        value = 0
        for c in text[whole:]:
            value = value * 88 + index[c]
        out += (value % 256 ** (rest - 1)).to_bytes(rest - 1, "big")
    return bytes(out)


def _payload_script(attributes: bytes) -> bytes | None:
    """The JavaScript the loader runs as an inline module, as the browser hashes it (the
    UTF-8 of its text), or None when the script carries no payload."""
    found = {k.decode(): v.decode() for k, v in _ATTRIBUTE.findall(attributes)}
    if not {"data-p", "data-ss", "data-cs"} <= found.keys():
        return None
    import zstandard  # viser's own dependency

    css, code = int(found["data-ss"]), int(found["data-cs"])
    frame = _base88(html.unescape(found["data-p"]))
    data = zstandard.ZstdDecompressor().decompress(frame, max_output_size=css + code)
    return data[css:css + code].decode("utf-8", "replace").encode("utf-8")


@cache
def script_hashes() -> tuple[str, ...]:
    """The SHA-256 sources of every script viser's page runs inline."""
    hashes = []
    for attributes, body in _INLINE_SCRIPT.findall(_page_path().read_bytes()):
        hashes.append(_sha256(body))
        try:
            module = _payload_script(attributes)
        except Exception:  # any surprise in viser's format: say so, keep the policy
            log.warning("viser's client page has a payload this server cannot read; the "
                        "3D view may not draw under its policy", exc_info=True)
            module = None
        if module is not None:
            hashes.append(_sha256(module))
    return tuple(hashes)


@cache
def viewer_csp() -> str:
    """The Content-Security-Policy of viser's page (module docstring)."""
    return ("default-src 'none'; script-src 'self' " + " ".join(script_hashes())
            + " 'wasm-unsafe-eval'; worker-src blob:; style-src 'self' 'unsafe-inline'; "
            "img-src 'self' data: blob:; font-src 'self' data:; "
            "connect-src 'self' data: blob:; manifest-src 'self'; media-src 'none'; "
            "frame-src 'none'; child-src blob:; object-src 'none'; base-uri 'none'; "
            "form-action 'none'; frame-ancestors 'self'")
