"""The live hub across server instances: updates go through Redis pub/sub
(``ARMTRACK_BROKER_URL``, e.g. ``redis://127.0.0.1:6379/0``; ``pip install '.[scale]'``).

Each instance publishes every update of the kits connected to it on the channel
``armtrack:live:<patient id>``, and subscribes to the channel of a patient only while one
of its own viewers (``/ws/live``, the 3D view) watches that patient, so an instance
receives only what its therapists watch. Its own updates reach its own viewers directly,
as with the in-process :class:`LiveHub`, and are skipped when they come back from the
broker (each message names the instance that sent it).

Sending never blocks ingest: ``publish`` queues the update; one task sends what queued
while the previous round trip was out in one pipeline. Live updates are best effort, as
in one process: if the broker is slow or away, the oldest queued updates are dropped (the
stored data are not concerned) and the hub reconnects. A relayed update carries
``published_at``: the sending instance's wall time of ``publish`` [s since the epoch].

An erase (``forget_session``, ``forget_patient``) goes to every instance, watched there
or not, on the channel ``armtrack:live:forget`` that each instance reads from its start:
an instance whose therapist watched the patient holds the session's last pose as the
patient's latest, and a 3D view opened there later would draw the erased arm. It is
queued behind the erased session's poses on the same connection, so none of them
arrives after it.

Why Redis and not NATS: ``bench/broker.py`` (README "Scaling out") measured both equal
within this machine's noise for pose-sized messages (p50 ~0.4 ms, p99 3–12 ms, ~12 000
messages/s through one Python connection with the ``hiredis`` parser); Redis is Debian's
``redis-server`` with the asyncio client of ``redis-py``, and nothing more is needed.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from collections.abc import Mapping
from typing import Any

import orjson

from .encoded import EncodedPose
from .hub import LiveHub, Subscription

log = logging.getLogger("armtrack.live")

CHANNEL_PREFIX = "armtrack:live:"
#: Every instance's channel: erased sessions and patients whose last pose goes.
FORGET_CHANNEL = CHANNEL_PREFIX + "forget"
#: Most updates queued for the broker before the oldest are dropped.
MAX_QUEUED = 20000
RECONNECT_S = 1.0


class RedisHub(LiveHub):
    """A :class:`LiveHub` whose updates also travel between instances through Redis."""

    def __init__(self, url: str) -> None:
        super().__init__()
        self.url = url
        self.instance = secrets.token_hex(8).encode()
        self._queue: list[tuple[str, bytes]] = []
        self._wake = asyncio.Event()
        self._control: asyncio.Queue[tuple[str, str]] = asyncio.Queue()
        self._tasks: list[asyncio.Task] = []
        self._redis = None
        self._pubsub = None
        self.sent = self.received = self.dropped = 0

    async def start(self) -> None:
        import redis.asyncio as redis

        self._redis = redis.Redis.from_url(self.url)
        self._pubsub = self._redis.pubsub(ignore_subscribe_messages=True)
        # every instance hears of erasures (and so reading never ends for want of channels)
        await self._pubsub.subscribe(FORGET_CHANNEL)
        self._tasks = [asyncio.create_task(self._send(), name="armtrack-broker-send"),
                       asyncio.create_task(self._read(), name="armtrack-broker-read"),
                       asyncio.create_task(self._subscriptions(), name="armtrack-broker-sub")]

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        with contextlib.suppress(Exception):
            if self._pubsub is not None:
                await self._pubsub.aclose()
            if self._redis is not None:
                await self._redis.aclose()

    # -- the hub's interface ------------------------------------------------------------
    def subscribe(self, patient_id: int) -> Subscription:
        first = patient_id not in self._subscribers
        subscription = super().subscribe(patient_id)
        if first:
            self._control.put_nowait(("subscribe", f"{CHANNEL_PREFIX}{patient_id}"))
        return subscription

    def unsubscribe(self, subscription: Subscription) -> None:
        super().unsubscribe(subscription)
        if subscription.patient_id not in self._subscribers:
            self._control.put_nowait(("unsubscribe",
                                      f"{CHANNEL_PREFIX}{subscription.patient_id}"))

    def publish(self, patient_id: int, update: Mapping[str, Any]) -> None:
        super().publish(patient_id, update)  # this instance's viewers
        if isinstance(update, EncodedPose):
            data = update.with_field("published_at", time.time()).text
        else:
            data = orjson.dumps({**update, "published_at": time.time()},
                                option=orjson.OPT_SERIALIZE_NUMPY)
        self._enqueue(f"{CHANNEL_PREFIX}{patient_id}", data)

    def forget_session(self, session_id: int) -> None:
        super().forget_session(session_id)
        self._enqueue(FORGET_CHANNEL, orjson.dumps({"session_id": session_id}))

    def forget_patient(self, patient_id: int) -> None:
        super().forget_patient(patient_id)
        self._enqueue(FORGET_CHANNEL, orjson.dumps({"patient_id": patient_id}))

    def _enqueue(self, channel: str, data: bytes) -> None:
        """``data`` for ``channel``, named as this instance's, sent by ``_send``."""
        self._queue.append((channel, self.instance + b" " + data))
        if len(self._queue) > MAX_QUEUED:
            del self._queue[:len(self._queue) - MAX_QUEUED]
            self.dropped += 1
        self._wake.set()

    # -- the tasks ----------------------------------------------------------------------
    async def _send(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            batch, self._queue = self._queue, []
            if not batch:
                continue
            try:
                async with self._redis.pipeline(transaction=False) as pipe:
                    for channel, data in batch:
                        pipe.publish(channel, data)
                    await pipe.execute()
                self.sent += len(batch)
            except Exception as exc:  # live is best effort: these are gone
                self.dropped += len(batch)
                log.warning("broker: %d live updates not sent (%s)", len(batch), exc)
                await asyncio.sleep(RECONNECT_S)

    async def _subscriptions(self) -> None:
        while True:
            action, channel = await self._control.get()
            while True:
                try:
                    if action == "subscribe":
                        # only if still watched here (an unsubscribe may have followed)
                        if int(channel.rsplit(":", 1)[1]) in self._subscribers:
                            await self._pubsub.subscribe(channel)
                    elif int(channel.rsplit(":", 1)[1]) not in self._subscribers:
                        await self._pubsub.unsubscribe(channel)
                    break
                except Exception as exc:
                    log.warning("broker: %s %s failed (%s); retrying", action, channel, exc)
                    await asyncio.sleep(RECONNECT_S)

    async def _read(self) -> None:
        while True:
            try:
                message = await self._pubsub.get_message(timeout=None)
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # redis-py reconnects and subscribes again
                log.warning("broker: reading failed (%s); reconnecting", exc)
                await asyncio.sleep(RECONNECT_S)
                continue
            if message is None or message.get("type") != "message":
                continue
            sender, _, data = message["data"].partition(b" ")
            if sender == self.instance:
                continue  # delivered here already
            channel = message["channel"]
            if isinstance(channel, bytes):
                channel = channel.decode()
            if channel == FORGET_CHANNEL:
                self._forget(data)
                continue
            try:
                patient_id = int(channel.rsplit(":", 1)[1])
                update = orjson.loads(data)
            except (ValueError, orjson.JSONDecodeError):
                continue
            self.received += 1
            LiveHub.publish(self, patient_id, update)


    def _forget(self, data: bytes) -> None:
        """Another instance's erase: its session's or patient's last pose goes here too."""
        try:
            erased = orjson.loads(data)
            if "session_id" in erased:
                LiveHub.forget_session(self, int(erased["session_id"]))
            else:
                LiveHub.forget_patient(self, int(erased["patient_id"]))
        except (ValueError, TypeError, KeyError, orjson.JSONDecodeError):
            log.warning("broker: an erasure not understood: %r", data[:200])


def make_hub(broker_url: str | None) -> LiveHub:
    """The in-process hub, or the broker's when ``broker_url`` is set."""
    if not broker_url:
        return LiveHub()
    if not broker_url.startswith(("redis://", "rediss://", "unix://")):
        scheme = broker_url.partition("://")[0] + "://" if "://" in broker_url else "no scheme"
        # the URL is not echoed: it may hold a password
        raise ValueError(f"ARMTRACK_BROKER_URL: a redis://, rediss:// or unix:// URL is "
                         f"needed, not one of {scheme[:20]!r}")
    return RedisHub(broker_url)
