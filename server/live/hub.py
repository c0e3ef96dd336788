"""Publish/subscribe of live updates per patient. A slow viewer never holds anyone back:
each subscriber has a small queue and loses its oldest update when it is full.

This hub is in-process: one server instance. Several instances share theirs through a
broker (``broker.RedisHub``, when ``ARMTRACK_BROKER_URL`` is set)."""

from __future__ import annotations

import asyncio
from collections import defaultdict
from collections.abc import Mapping
from typing import Any

from .encoded import EncodedPose

#: Updates a subscriber may fall behind before its oldest are dropped.
QUEUE_SIZE = 64


class Subscription:
    def __init__(self, hub: LiveHub, patient_id: int):
        self.hub = hub
        self.patient_id = patient_id
        self.queue: asyncio.Queue[Mapping[str, Any] | None] = asyncio.Queue(QUEUE_SIZE)
        self.dropped = 0
        self.ended = False

    def put(self, update: Mapping[str, Any] | None) -> None:
        if self.ended:
            return
        if self.queue.full():
            self.queue.get_nowait()
            self.dropped += 1
        self.queue.put_nowait(update)

    def end(self) -> None:
        """No more updates (the feed's right is gone, or its viewer left): ``get`` answers
        None from now on, whatever is published after. (An end put in the queue like an
        update was pushed out by the next ``QUEUE_SIZE`` updates, a kit's flood of
        ``status``, before the feed's task read it: the feed stayed open for good.)"""
        if not self.ended:
            self.put(None)  # wakes a get waiting on the queue
            self.ended = True

    async def get(self) -> Mapping[str, Any] | None:
        """The next update; None once the subscriber's side put an end to it."""
        if self.ended:
            return None
        update = await self.queue.get()
        return None if self.ended else update

    def close(self) -> None:
        self.hub.unsubscribe(self)

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class LiveHub:
    """Updates (``{"kind": "pose" | "status" | "session", "patient_id", ...}``) by patient."""

    def __init__(self) -> None:
        self._subscribers: dict[int, set[Subscription]] = defaultdict(set)
        self.latest: dict[int, Mapping[str, Any]] = {}  # last pose per patient

    async def start(self) -> None:
        """Nothing to start in one process (a broker-backed hub connects here)."""

    async def stop(self) -> None:
        """Nothing to stop in one process."""

    def subscribe(self, patient_id: int) -> Subscription:
        subscription = Subscription(self, patient_id)
        self._subscribers[patient_id].add(subscription)
        return subscription

    def unsubscribe(self, subscription: Subscription) -> None:
        subscribers = self._subscribers.get(subscription.patient_id)
        if subscribers is not None:
            subscribers.discard(subscription)
            if not subscribers:
                del self._subscribers[subscription.patient_id]

    def forget_session(self, session_id: int) -> None:
        """An erased session's last pose is nobody's latest any more (a view opened later
        would draw it)."""
        for patient_id, pose in list(self.latest.items()):
            if pose.get("session_id") == session_id:
                del self.latest[patient_id]

    def forget_patient(self, patient_id: int) -> None:
        """An erased patient's last pose goes."""
        self.latest.pop(patient_id, None)

    def publish(self, patient_id: int, update: Mapping[str, Any]) -> None:
        """``update``: a dict, or a pose as ``EncodedPose`` (read as one)."""
        if isinstance(update, EncodedPose) or update.get("kind") == "pose":
            self.latest[patient_id] = update
        for subscription in tuple(self._subscribers.get(patient_id, ())):
            subscription.put(update)
