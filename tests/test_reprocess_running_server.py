"""``armtrack reprocess`` run by the clinic's IT while the server runs (operator.md: it takes
the server's ``--data-dir``/``--database-url``) marked every live session 'interrupted' —
the server's start-up step for sessions a previous run left live — though their kits were
streaming: the therapist's page said "The stream is interrupted" and offered to close a
session in progress until the kit's next commit. Only the server marks sessions on start
now. A real server, a kit connected and pausing (between exercises), the command run as
IT would."""

from __future__ import annotations

import asyncio
import json

import websockets
from server_support import server_fixture

server = server_fixture("reprocess-running", "alice")


def test_reprocess_leaves_the_running_servers_live_sessions_live(server):
    api = server.client("alice")
    patient = api.patient("Streaming")
    token = api.device(patient["id"], "kit")["token"]

    async def kit_pausing() -> tuple[int, str, str]:
        async with websockets.connect(f"{server.ws_url}?token={token}") as ws:
            await ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "kit",
                                      "sensors": ["forearm"], "rate_hz": 50,
                                      "side": "right", "nine_axis": False,
                                      "resume": None}))
            ready = json.loads(await ws.recv())
            rows = [[i / 50, 0, 0, 9.81, 0, 0, 0, None, None, None] for i in range(50)]
            await ws.send(json.dumps({"type": "samples", "seq": 0, "sensor": "forearm",
                                      "rows": rows}))
            while json.loads(await ws.recv()).get("type") != "ack":
                pass
            before = api.session(ready["session"])["status"]
            done = await asyncio.to_thread(server.armtrack, "reprocess", "999",
                                           timeout=180)
            print("\nreprocess:", done.returncode, done.stderr.strip())
            after = api.session(ready["session"])["status"]
            return ready["session"], before, after

    session, before, after = asyncio.run(kit_pausing())
    print(f"session {session}: {before} before the command, {after} after it")
    assert before == "live"
    assert after == "live", "the command marked a streaming session interrupted"
