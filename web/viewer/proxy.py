"""A WebSocket proxy from the app to the loopback viser server: the subprotocol the browser
asked for (``viser-v<version>``) is kept, frames pass both ways unchanged (binary stays
binary), and either side closing closes the other with the same code; ``revoked``
resolving to ``(code, reason)`` closes both, the browser's side with that code."""

from __future__ import annotations

import asyncio
import contextlib

from fastapi import WebSocket
from starlette.websockets import WebSocketDisconnect
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake
from websockets.typing import Subprotocol

#: Close code when the viewer server cannot be reached.
CLOSE_UPSTREAM_DOWN = 1011
#: Most messages a 3D view's page is passed on a second, a second's worth at once (its
#: camera while dragged sends one a frame): past it the proxy reads the page's next
#: message later, TCP makes the page wait, nothing dropped. Without it one view sent 18k
#: valid checkbox toggles a second, each a redraw: another therapist's request 6 ms ->
#: 2.8 s at worst.
VIEW_MESSAGES_PER_S = 240.0


async def proxy(websocket: WebSocket, upstream_url: str,
                revoked: asyncio.Future[tuple[int, str]] | None = None) -> None:
    """Join the (not yet accepted) ``websocket`` to ``upstream_url`` until either ends
    or ``revoked`` resolves."""
    requested = [Subprotocol(p) for p in websocket.scope.get("subprotocols", [])
                 if p.startswith("viser-v")]
    try:
        # proxy=None: the viewer is on this host's loopback; a proxy the environment names
        # for outbound traffic (HTTPS_PROXY) cannot reach it, and the ticket is not its
        upstream = await connect(upstream_url, subprotocols=requested or None, max_size=None,
                                 compression=None, open_timeout=10, proxy=None)
    except (OSError, InvalidHandshake, TimeoutError):
        await websocket.close(CLOSE_UPSTREAM_DOWN)
        return
    await websocket.accept(subprotocol=upstream.subprotocol)

    async def down() -> None:  # viser → browser
        with contextlib.suppress(ConnectionClosed):
            async for message in upstream:
                if isinstance(message, bytes):
                    await websocket.send_bytes(message)
                else:
                    await websocket.send_text(message)

    async def up() -> None:  # browser → viser, at most VIEW_MESSAGES_PER_S
        loop = asyncio.get_running_loop()
        allowed, last = VIEW_MESSAGES_PER_S, loop.time()
        with contextlib.suppress(ConnectionClosed, WebSocketDisconnect):
            while True:
                message = await websocket.receive()
                if message["type"] == "websocket.disconnect":
                    return
                if message.get("bytes") is not None:
                    await upstream.send(message["bytes"])
                elif message.get("text") is not None:
                    await upstream.send(message["text"])
                now = loop.time()
                allowed = min(VIEW_MESSAGES_PER_S,
                              allowed + (now - last) * VIEW_MESSAGES_PER_S) - 1
                last = now
                if allowed < 0:
                    await asyncio.sleep(-allowed / VIEW_MESSAGES_PER_S)

    tasks = [asyncio.create_task(down()), asyncio.create_task(up())]
    waited = [*tasks, revoked] if revoked is not None else tasks
    try:
        await asyncio.wait(waited, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await upstream.close()
        code = upstream.close_code if upstream.close_code not in (None, 1005, 1006) else 1000
        reason = upstream.close_reason or ""
        if revoked is not None and revoked.done():
            code, reason = revoked.result()
        with contextlib.suppress(RuntimeError, WebSocketDisconnect):
            await websocket.close(code, reason)
