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

One change to the served page (``_served_page``): viser's bundle compiles its Gaussian
splat sorter (an Emscripten module, ``Sorter.wasm``) at load, whether or not a splat is
ever shown, and that module's embind glue builds its JavaScript invokers with
``Function(...)`` — ``eval``, refused by this policy (Chromium: "Evaluating a string as
JavaScript violates …", an uncaught error on every 3D view). armtrack shows no splats, so
the served payload loads the sorter when a splat first awaits it (never here; the splat
worker's source, which loads it the same way, too); the rest of the bundle is byte for
byte viser's. The one other ``eval`` in the bundle, viser's ``run_javascript``
(``Function(source)()``), armtrack never calls. Splats would need ``'unsafe-eval'`` in
this policy (their sorter's worker too), which it does not allow: docs/security.md.
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

import numpy as np
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
    """viser's client page as served (one self-contained file), plain and gzipped."""
    page = _served_page()
    return page, gzip.compress(page, 6)


#: viser's eager load of its splat sorter (minified): ``X=fetch(URL).then(e=>e.
#: arrayBuffer()).then(e=>MAKE({wasmBinary:e}))``, a promise made at load.
_EAGER_SORTER = re.compile(rb"=(fetch\([\w$]+\)\.then\(e=>e\.arrayBuffer\(\)\)"
                           rb"\.then\(e=>[\w$]+\(\{wasmBinary:e\}\)\))")


def _lazy_sorter(code: bytes) -> bytes | None:
    """viser's bundle with its splat sorter made on first ``await`` or ``then`` (a
    thenable that starts the same promise then), or None when the bundle has no such load.
    viser 1.1 has two: the page's, and the same in its splat worker's source (run only in
    that worker, which only splats start)."""
    if not _EAGER_SORTER.search(code):
        return None
    return _EAGER_SORTER.sub(rb"={then(_ok,_no){return(this.p??=\1).then(_ok,_no)}}", code)


@cache
def _served_page() -> bytes:
    """viser's page with its payload's sorter load made lazy (module docstring), or the
    page as it is (and a warning) when its shape is not the one known."""
    page = _page_path().read_bytes()
    for attributes, _body in _INLINE_SCRIPT.findall(page):
        found = {k.decode(): v.decode() for k, v in _ATTRIBUTE.findall(attributes)}
        if not {"data-p", "data-ss", "data-cs"} <= found.keys():
            continue
        try:
            import zstandard  # viser's own dependency

            css, code = int(found["data-ss"]), int(found["data-cs"])
            data = zstandard.ZstdDecompressor().decompress(
                _base88(html.unescape(found["data-p"])), max_output_size=css + code)
            lazy = _lazy_sorter(data[css:css + code])
        except Exception:
            lazy = None
        if lazy is None:
            log.warning("viser's client page: its splat sorter's load was not found; the "
                        "3D view may log an 'unsafe-eval' refusal (web/viewer/page.py)")
            return page
        frame = zstandard.ZstdCompressor(level=9).compress(data[:css] + lazy)
        changed = (attributes.replace(found["data-p"].encode(), _to_base88(frame))
                   .replace(f'data-cs="{code}"'.encode(), f'data-cs="{len(lazy)}"'.encode()))
        return page.replace(attributes, changed, 1)
    return page


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


def _to_base88(data: bytes) -> bytes:
    """The inverse of ``_base88``: 4 bytes → 5 characters; a last r bytes → r + 1."""
    digits = np.frombuffer(_ALPHABET.encode(), np.uint8)
    whole = len(data) - len(data) % 4
    values = np.frombuffer(data[:whole], ">u4").astype(np.uint64)
    groups = np.empty((len(values), 5), np.uint8)
    for j in range(4, -1, -1):
        groups[:, j] = values % 88
        values //= 88
    value, rest = int.from_bytes(data[whole:], "big"), len(data) - whole
    last = bytearray(rest + 1 if rest else 0)
    for j in range(len(last) - 1, -1, -1):
        value, last[j] = divmod(value, 88)
    return digits[groups].tobytes() + digits[np.frombuffer(bytes(last), np.uint8)].tobytes()


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
    for attributes, body in _INLINE_SCRIPT.findall(_served_page()):
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
