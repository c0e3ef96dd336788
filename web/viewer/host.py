"""The app's one viser server, bound to the loopback, and who each of its clients is.

A client arrives through the proxy (``routes``) with ``?ticket=`` in its WebSocket URL.
Before anything is sent to it, the gate takes the ticket (``GrantBook.take_ticket``); a
client without a valid ticket is closed with 4403 and gets nothing. A client with one gets
its own scene for the grant's patient, live or a stored session, once viser counts it
connected (after its first camera message); its driver runs on the app's event loop until
it leaves.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import logging
import math
import threading
from concurrent.futures import Future
from typing import Any
from urllib.parse import parse_qs, urlsplit

import viser
from armtrack.server.db import models
from armtrack.server.live.access import holds
from armtrack.server.live.streams import stream_receiving
from viser import _messages

from .grants import GRANT_TTL_S, Grant, GrantBook
from .live import LiveDriver
from .replay import ReplayDriver, load_session
from .view import ClientView

log = logging.getLogger("armtrack.viewer")

#: Close code for a viewer without a valid grant.
CLOSE_NO_GRANT = 4403


class ViewerError(RuntimeError):
    """The viewer cannot do what was asked (also: viser's internals are not as expected)."""


def client_connection(server: viser.ViserServer, client_id: int) -> Any:
    """The raw ``websockets`` connection of a viser client. viser has no public API for it;
    this reads its internals (viser 1.1: ``_websock_server._live_connections``)."""
    try:
        return server._websock_server._live_connections[client_id]
    except (AttributeError, KeyError) as exc:
        raise ViewerError(
            f"cannot find viser client {client_id}'s connection: viser {viser.__version__}'s "
            "internals differ from 1.1's (_websock_server._live_connections)") from exc


def request_path(server: viser.ViserServer, client_id: int) -> str:
    """The request path and query of a viser client's WebSocket handshake."""
    try:
        return str(client_connection(server, client_id).request.path)
    except AttributeError as exc:
        raise ViewerError(f"viser client {client_id}'s connection has no request path "
                          f"(viser {viser.__version__})") from exc


def on_websocket_open(server: viser.ViserServer, callback) -> None:
    """Run ``callback(connection)`` (async, on viser's loop) when a WebSocket opens, before
    viser sends it anything (viser 1.1's ``_websock_server.on_client_connect``)."""
    try:
        server._websock_server.on_client_connect(callback)
    except AttributeError as exc:
        raise ViewerError(f"viser {viser.__version__} has no _websock_server to gate "
                          "connections on") from exc


@contextlib.contextmanager
def _viser_prints_to_log():
    """viser 1.1 prints its banner and "Server stopped" with ``rich.print`` whatever
    ``verbose`` says (``verbose=False`` only quiets its per-connection lines): send what it
    prints meanwhile to the debug log instead of the server's stdout."""
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        yield
    for line in printed.getvalue().splitlines():
        if line.strip():
            log.debug("viser: %s", line.rstrip())


def refuse_share_tunnel(server: viser.ViserServer) -> None:
    """Take away viser's answer to a client's ``ShareUrlRequest`` (its "Share" button,
    hidden here but handled all the same): it asks https://share.viser.studio for a public
    address and opens tunnels from there to this loopback server, forking a process for
    them. Any therapist's 3D view could send it; a clinic's server never shares its viewer
    with the internet (viser 1.1's ``_websock_server.unregister_handler``)."""
    try:
        for message in (_messages.ShareUrlRequest, _messages.ShareUrlDisconnect):
            server._websock_server.unregister_handler(message)
    except (AttributeError, AssertionError, KeyError) as exc:
        raise ViewerError(f"cannot take away viser {viser.__version__}'s share-URL handler: "
                          "its internals differ from 1.1's") from exc


def refuse_form_relay(server: viser.ViserServer) -> None:
    """Take away viser's answer to a client's ``GuiFormDirtyMessage``: it passes the
    message on to every other client through its broadcast buffer, which keeps it for
    good (a new ``uuid`` each time is a new message) and replays it to every client
    that connects later. Any therapist's 3D view could send them, up to 1 MiB each:
    the server kept twice what was sent (48 MB sent: +100 MB, and on) and another
    therapist's view opened later received them. armtrack's views have no forms (viser
    1.1's ``_websock_server.unregister_handler``; each client's own handler sends to
    nobody: the message is never sent back to its sender)."""
    try:
        server._websock_server.unregister_handler(_messages.GuiFormDirtyMessage)
    except (AttributeError, AssertionError, KeyError) as exc:
        raise ViewerError(f"cannot take away viser {viser.__version__}'s form-dirty relay: "
                          "its internals differ from 1.1's") from exc


def valid_update(handle: Any, updates: Any) -> bool:
    """Whether a client's ``GuiUpdateMessage`` for ``handle`` (one of its view's inputs)
    is what viser's page sends: its ``value`` alone, of the input's kind (a button's or
    checkbox's a bool, a dropdown's one of its options, a slider's a finite number within
    its range)."""
    if not isinstance(updates, dict) or list(updates) != ["value"]:
        return False
    value, current = updates["value"], handle._impl.value
    if handle._impl.is_button or isinstance(current, bool):
        return isinstance(value, bool)
    if isinstance(current, str):
        return isinstance(value, str) and value in tuple(getattr(handle, "options", ()))
    if isinstance(current, int | float):
        low, high = getattr(handle, "min", None), getattr(handle, "max", None)
        return (isinstance(value, int | float) and not isinstance(value, bool)
                and math.isfinite(value) and low is not None and high is not None
                and low <= value <= high)
    return False


def accept_valid_updates(client: viser.ClientHandle) -> None:
    """Let through only ``valid_update``s of ``client``'s inputs; others are ignored,
    the first of each client named in the log. viser takes any property with any value
    (``update_cb``, the input's callbacks, too), then calls armtrack's callbacks, whose
    errors it prints with their traceback: one 3D view wrote 9.7 MB of them into the
    server's log in 3 s. Called before the view's inputs exist (viser 1.1's per-client
    ``gui._websock_interface`` and ``_handle_gui_updates``)."""
    gui = client.gui
    try:
        interface, original = gui._websock_interface, gui._handle_gui_updates
        inputs = gui._gui_input_handle_from_uuid
        interface.unregister_handler(_messages.GuiUpdateMessage, original)
    except (AttributeError, AssertionError, ValueError) as exc:
        raise ViewerError(f"cannot check viser {viser.__version__}'s GUI updates: its "
                          "internals differ from 1.1's") from exc
    named = [False]

    async def checked(client_id: int, message: _messages.GuiUpdateMessage) -> None:
        handle = inputs.get(message.uuid)
        if handle is not None and valid_update(handle, message.updates):
            await original(client_id, message)
        elif handle is not None and not named[0]:
            named[0] = True
            log.warning("3D view client %s sent a value its view's inputs do not take; "
                        "ignored (and any more it sends)", client_id)
    interface.register_handler(_messages.GuiUpdateMessage, checked)


def quiet_viser_server(port: int = 0) -> viser.ViserServer:
    """A ``ViserServer`` on 127.0.0.1:``port`` (0: any free one) that prints nothing."""
    with _viser_prints_to_log():
        return viser.ViserServer(host="127.0.0.1", port=port, verbose=False)


def stop_quietly(server: viser.ViserServer) -> None:
    """Stop ``server`` without its "Server stopped" line on stdout."""
    with _viser_prints_to_log():
        server.stop()


class ViewerHost:
    """One ``ViserServer`` on 127.0.0.1:``port`` (0: any free port) for the app whose
    ``services`` (database, live hub) it draws from; grants last ``grant_s`` [s]."""

    def __init__(self, services: Any, port: int = 0, grant_s: float = GRANT_TTL_S):
        self.services = services
        self.requested_port = port
        self.grants = GrantBook(grant_s)
        self.server: viser.ViserServer | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._pending: dict[int, Grant] = {}  # client id → grant, from the gate to connect
        self._drivers: dict[int, Future] = {}
        self._lock = threading.Lock()

    @property
    def port(self) -> int:
        if self.server is None:
            raise ViewerError("the viewer is not started")
        return self.server.get_port()

    def upstream_url(self, ticket: str) -> str:
        """Where the proxy connects for a claimed grant's ``ticket``."""
        return f"ws://127.0.0.1:{self.port}/?ticket={ticket}"

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        await self._loop.run_in_executor(None, self._start_server)

    def _start_server(self) -> None:
        server = quiet_viser_server(self.requested_port)
        self.server = server
        refuse_share_tunnel(server)
        refuse_form_relay(server)
        on_websocket_open(server, self._gate)
        server.on_client_connect(self._connect)
        server.on_client_disconnect(self._disconnect)
        log.info("viewer on 127.0.0.1:%s", server.get_port())

    async def stop(self) -> None:
        with self._lock:
            drivers, self._drivers = list(self._drivers.values()), {}
        for future in drivers:
            future.cancel()
        if self.server is not None:
            await asyncio.get_running_loop().run_in_executor(None, stop_quietly, self.server)
            self.server = None

    async def _gate(self, connection) -> None:
        """On viser's loop, before viser sends the client anything."""
        assert self.server is not None
        client_id = connection.client_id
        try:
            query = parse_qs(urlsplit(request_path(self.server, client_id)).query)
            tickets = query.get("ticket", [])
            grant = self.grants.take_ticket(tickets[0]) if len(tickets) == 1 else None
        except ViewerError:
            log.exception("viewer gate")
            grant = None
        if grant is None:
            await client_connection(self.server, client_id).close(CLOSE_NO_GRANT,
                                                                  "no valid viewer grant")
            return
        with self._lock:
            self._pending[client_id] = grant

    def _connect(self, client: viser.ClientHandle) -> None:
        """On viser's thread pool, when the client counts as connected."""
        with self._lock:
            grant = self._pending.pop(client.client_id, None)
        if grant is None:
            self._close(client.client_id, "no valid viewer grant")
            return
        try:
            accept_valid_updates(client)  # before its inputs exist
            driver = self._build(client, grant)
        except Exception:
            log.exception("viewer of patient %s", grant.patient_id)
            self._close(client.client_id, "the viewer failed")
            return
        if driver is None:
            return
        assert self._loop is not None and self.server is not None
        future = asyncio.run_coroutine_threadsafe(driver.run(), self._loop)
        future.add_done_callback(_log_failure)
        with self._lock:
            self._drivers[client.client_id] = future
        if client.client_id not in self.server.get_clients():  # it left meanwhile
            self._disconnect(client)

    def _disconnect(self, client: viser.ClientHandle) -> None:
        with self._lock:
            self._pending.pop(client.client_id, None)
            future = self._drivers.pop(client.client_id, None)
        if future is not None:
            future.cancel()

    def _close(self, client_id: int, reason: str) -> None:
        assert self.server is not None
        try:
            connection = client_connection(self.server, client_id)
        except ViewerError:
            return  # already gone
        asyncio.run_coroutine_threadsafe(connection.close(CLOSE_NO_GRANT, reason),
                                         self.server.get_event_loop())

    def _build(self, client: viser.ClientHandle, grant: Grant) -> LiveDriver | ReplayDriver | None:
        """The client's view and its driver (on viser's thread pool: may read the database)."""
        services = self.services
        with services.db() as db:
            patient = db.get(models.Patient, grant.patient_id)
            therapist = db.get(models.Therapist, grant.therapist_id)
            if patient is None or therapist is None or not holds(therapist, patient):
                raise ViewerError(f"patient {grant.patient_id} is not the grant's therapist's")
            if grant.live:
                view = ClientView(client, heading=f"{patient.name} · live",
                                  height_m=patient.height_m, side=patient.side, live=True,
                                  display_scale=grant.display_scale)
                patient_id = patient.id
                return LiveDriver(view, services.hub, patient_id,
                                  dict(services.sensor_status.get(patient_id, {})),
                                  receiving=lambda: stream_receiving(services, patient_id))
            session = db.get(models.Session, grant.session_id)
            if session is None or session.patient_id != patient.id:
                raise ViewerError(f"session {grant.session_id} is not patient {patient.id}'s")
            view = ClientView(client, heading=f"{patient.name} · session {session.id}",
                              height_m=session.height_m or patient.height_m, side=session.side,
                              live=False, display_scale=grant.display_scale)
            data = load_session(db, session.id)
        if data is None:
            view.panels.show_status([f"Replay · session {session.id} has no estimates yet"
                                     + (f": {session.processing_error}"
                                        if session.processing_error else "")])
            return None
        return ReplayDriver(view, data)


def _log_failure(future: Future) -> None:
    if not future.cancelled() and future.exception() is not None:
        log.error("viewer driver failed", exc_info=future.exception())
