"""The server's listening socket, bound before the application starts so that a busy port
is told in words (which port, and ``--port``), not as uvicorn's raw ``[Errno 98]``."""

from __future__ import annotations

import errno
import socket


class CannotListen(Exception):
    """The address cannot be listened on; the message says why and what to do."""


def bind_socket(host: str, port: int, command: str = "serve") -> socket.socket:
    """A TCP socket bound to ``host:port`` (not yet listening: uvicorn does that), inherited
    by child processes as uvicorn expects. Raises :class:`CannotListen`."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)[0]
    except socket.gaierror as exc:
        raise CannotListen(f"cannot listen on {host!r}: {exc.strerror} (check --host or "
                           "ARMTRACK_HOST)") from None
    sock = socket.socket(family, kind, proto)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise CannotListen(
                f"port {port} on {host} is already in use (another `armtrack serve` or "
                f"`armtrack demo`?); stop it, or start this one on another port: "
                f"armtrack {command} --port {port + 1 if port < 65535 else 8001}") from None
        if exc.errno == errno.EACCES:
            raise CannotListen(f"not allowed to listen on port {port} (ports below 1024 "
                               f"need privileges); use --port 8000 or above") from None
        if exc.errno == errno.EADDRNOTAVAIL:
            raise CannotListen(f"{host} is not an address of this machine (check --host or "
                               "ARMTRACK_HOST)") from None
        raise CannotListen(f"cannot listen on {host}:{port}: {exc.strerror}") from None
    sock.set_inheritable(True)
    return sock
