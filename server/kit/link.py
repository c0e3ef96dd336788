"""The link to the phone kit (``/kit``) that a therapist gives the patient with a new
device, and its QR code (``docs/extensions/kit-link.md``).

The device token travels in the URL *fragment* (``/kit#token=…``): a browser never sends
the fragment to a server, so the token reaches no server's or proxy's log. The address
is ``ARMTRACK_PUBLIC_URL`` (the https address phones reach the server by) when set, else
the address the therapist's browser used.
"""

from __future__ import annotations

from urllib.parse import quote, urlsplit

#: Hosts where a browser gives motion sensors to a plain-http page.
LOCAL_HOSTS = ("localhost", "127.0.0.1", "[::1]", "::1")


def kit_url(base: str, token: str) -> str:
    """``<base>/kit#token=<token>`` (``base`` without its trailing slash)."""
    return f"{base.rstrip('/')}/kit#token={quote(token, safe='')}"


def secure_enough(base: str) -> bool:
    """Whether phones get motion sensors, a service worker and Wake Lock at ``base``: https,
    or a local address (which a phone cannot reach anyway)."""
    parts = urlsplit(base)
    return parts.scheme == "https" or (parts.hostname or "") in LOCAL_HOSTS


def qr_svg_data_uri(text: str) -> str:
    """A QR code of ``text`` as an SVG ``data:`` URI (error correction M, 4 px modules)."""
    import segno  # only when a kit is added

    return segno.make(text, error="m", micro=False).svg_data_uri(scale=4, border=4)
