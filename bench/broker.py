"""Benchmark: which broker carries live poses between server instances. Run by hand:
``python bench/broker.py [--rate 3000] [--seconds 5]``. Not a test.

Starts ``redis-server`` and ``nats-server`` (Debian's packages) on free loopback ports,
each with one publisher and one subscriber connection in this process (asyncio clients:
``redis.asyncio`` and ``nats-py``, ``pip install nats-py``), and sends pose-sized JSON
updates (a pose of ``server/live/worker.py``'s shape, ~1.3 kB, serialised with orjson as
the hub does) over one channel per patient:

* latency: publish → receive [ms], p50/p99/max, at ``--rate`` messages per second spread
  over ``--patients`` channels (3000/s = 100 watched patients × 30 poses/s), paced;
* throughput: messages per second received when ``--burst`` messages are published as
  fast as the client can (the ceiling of one connection, Python side included).

Both sides run in one Python process, so the client's own CPU is part of every figure; on
the 2-core box other work shows too (the load average is printed).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import shutil
import socket
import subprocess
import tempfile
import time

import numpy as np
import orjson


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def pose(i: int) -> dict:
    from armtrack.estimator.arm.joints import REPORTED_ANGLES, SEGMENTS
    rng = np.random.default_rng(i)
    return {"kind": "pose", "session_id": 1, "t": 12.34,
            "angles_deg": {k: float(rng.normal()) for k in REPORTED_ANGLES},
            "positions_m": {k: rng.normal(size=3).tolist() for k in ("shoulder", "elbow",
                                                                     "wrist", "hand")},
            "segments_q": {s: rng.normal(size=4).tolist() for s in SEGMENTS},
            "rom_deg": {k: {"min": -10.0, "max": 95.5, "range": 105.5} for k in REPORTED_ANGLES},
            "estimates": 1234, "warnings": [], "latency_s": 0.004}


def wait_port(port: int, timeout: float = 10) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise RuntimeError(f"nothing listens on {port}")


class Redis:
    name = "redis"

    def __init__(self, tmp: str):
        self.port = free_port()
        self.process = subprocess.Popen(
            ["redis-server", "--port", str(self.port), "--bind", "127.0.0.1", "--save", "",
             "--appendonly", "no", "--dir", tmp], stdout=subprocess.DEVNULL)
        wait_port(self.port)

    async def connect(self, on_message, channels):
        import redis.asyncio as redis
        self.pub = redis.Redis(port=self.port)
        self.sub_client = redis.Redis(port=self.port)
        self.pubsub = self.sub_client.pubsub()
        await self.pubsub.subscribe(*channels)

        async def reader():
            async for message in self.pubsub.listen():
                if message["type"] == "message":
                    on_message(message["data"])
        self.task = asyncio.create_task(reader())

        self.pending: list[tuple[str, bytes]] = []
        self.wake = asyncio.Event()
        self.sender = asyncio.create_task(self.send())

    async def send(self):
        """As the hub sends: what queued while the last round trip was out goes in one
        pipeline (one write, one read) — redis-py awaits each reply otherwise."""
        while True:
            await self.wake.wait()
            self.wake.clear()
            batch, self.pending = self.pending, []
            async with self.pub.pipeline(transaction=False) as pipe:
                for channel, data in batch:
                    pipe.publish(channel, data)
                await pipe.execute()

    async def publish(self, channel, data):
        self.pending.append((channel, data))
        self.wake.set()
        await asyncio.sleep(0) if len(self.pending) < 1000 else await asyncio.sleep(0.001)

    async def close(self):
        self.sender.cancel()
        self.task.cancel()
        await self.pubsub.aclose()
        await self.pub.aclose()
        await self.sub_client.aclose()
        self.process.terminate()
        self.process.wait()


class Nats:
    name = "nats"

    def __init__(self, tmp: str):
        self.port = free_port()
        self.process = subprocess.Popen(
            ["nats-server", "-a", "127.0.0.1", "-p", str(self.port)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wait_port(self.port)

    async def connect(self, on_message, channels):
        import nats
        self.pub = await nats.connect(f"nats://127.0.0.1:{self.port}")
        self.sub_client = await nats.connect(f"nats://127.0.0.1:{self.port}")

        async def handler(msg):
            on_message(msg.data)
        for channel in channels:
            await self.sub_client.subscribe(channel, cb=handler)
        await self.sub_client.flush()

    async def publish(self, channel, data):
        await self.pub.publish(channel, data)  # buffered; flushed by the client's task
        await asyncio.sleep(0) if self.pub.pending_data_size < 1 << 20 else \
            await asyncio.sleep(0.001)

    async def close(self):
        await self.pub.drain()
        await self.sub_client.drain()
        self.process.terminate()
        self.process.wait()


async def measure(broker, args) -> dict:
    channels = [f"armtrack.live.{p}" for p in range(args.patients)]
    template = pose(0)
    latencies: list[float] = []
    received = [0]

    def on_message(data: bytes) -> None:
        sent = orjson.loads(data)["sent"]
        latencies.append(time.perf_counter() - sent)
        received[0] += 1

    await broker.connect(on_message, channels)
    size = len(orjson.dumps({**template, "sent": 0.0}))
    # paced: --rate messages/s over all channels
    interval = 1.0 / args.rate
    n = int(args.rate * args.seconds)
    start = time.perf_counter()
    for i in range(n):
        due = start + i * interval
        delay = due - time.perf_counter()
        if delay > 0:
            await asyncio.sleep(delay)
        await broker.publish(channels[i % len(channels)],
                             orjson.dumps({**template, "sent": time.perf_counter()}))
    deadline = time.perf_counter() + 5
    while received[0] < n and time.perf_counter() < deadline:
        await asyncio.sleep(0.01)
    paced = np.array(latencies) * 1000
    lost_paced = n - received[0]
    # burst: as fast as possible
    latencies.clear()
    received[0] = 0
    t0 = time.perf_counter()
    for i in range(args.burst):
        await broker.publish(channels[i % len(channels)],
                             orjson.dumps({**template, "sent": time.perf_counter()}))
    deadline = time.perf_counter() + 30
    while received[0] < args.burst and time.perf_counter() < deadline:
        await asyncio.sleep(0.001)
    burst_s = time.perf_counter() - t0
    await broker.close()
    return {"broker": broker.name, "bytes": size,
            "p50": float(np.percentile(paced, 50)), "p99": float(np.percentile(paced, 99)),
            "max": float(paced.max()), "lost": lost_paced,
            "burst_per_s": received[0] / burst_s, "burst_lost": args.burst - received[0]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate", type=float, default=3000.0, help="paced messages/s")
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--patients", type=int, default=100, help="channels")
    parser.add_argument("--burst", type=int, default=50000)
    parser.add_argument("--only", choices=["redis", "nats"])
    args = parser.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.2f}; {args.rate:g} msg/s paced over "
          f"{args.patients} channels for {args.seconds:g} s, burst {args.burst}")
    print(f"{'broker':>6} {'bytes':>6} {'p50 ms':>7} {'p99 ms':>7} {'max ms':>7} {'lost':>5} "
          f"{'burst msg/s':>12} {'lost':>5}")
    with tempfile.TemporaryDirectory() as tmp:
        for kind in (Redis, Nats):
            if args.only and kind.name != args.only:
                continue
            binary = "redis-server" if kind is Redis else "nats-server"
            if shutil.which(binary) is None:
                print(f"{kind.name}: no {binary} (apt-get install {binary})")
                continue
            r = asyncio.run(measure(kind(tmp), args))
            print(f"{r['broker']:>6} {r['bytes']:>6} {r['p50']:>7.2f} {r['p99']:>7.2f} "
                  f"{r['max']:>7.2f} {r['lost']:>5} {r['burst_per_s']:>12.0f} "
                  f"{r['burst_lost']:>5}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
