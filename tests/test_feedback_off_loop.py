"""The kit feedback's repetition recount (``detect_repetitions`` on up to ~120 s of an
exercise's angle, 1.5-2.3 ms each, up to 10 a second per phone stream that asks for
``feedback/1``) is CPU work: it must not run on the event loop (the project's rule), or
every phone asking for feedback would hold up every kit's acks and every page.

A real uvicorn server (in this process, on its own thread, so that the test can see which
thread each recount runs on and probe its event loop's lag), the live estimation process,
real WebSocket clients: ``STREAMS`` simulated phones doing elbow flexions with an
exercise mark, each asking for feedback, at ``SPEED``× real time. Every recount must run
off the loop's thread, the counts must still reach the simulated repetitions, and each
stream's feedback messages must come in stream-time order. The loop's lag (a probe
sleeping 5 ms at a time on the server's loop) is printed."""

from __future__ import annotations

import asyncio
import json
import threading
import time

import pytest
from armtrack.server.emulator import MessagePlan, hello_message
from server_support import PASSWORD, Api, armtrack, free_port, send_paced
from test_feedback_resume import _simulation
from websockets.asyncio.client import connect

STREAMS = 4
SPEED = 4.0
REPS = 12
MARK_S = 10.5  # _simulation's exercise mark (the simulator's exercise starts at 11 s)


class ThreadServer:
    """``create_app`` under a real ``uvicorn.Server`` on a thread of this process."""

    def __init__(self, data_dir):
        import uvicorn
        from armtrack.server.app import create_app
        from armtrack.server.settings import Settings

        self.port = free_port()
        settings = Settings(data_dir=data_dir, port=self.port)
        self.server = uvicorn.Server(uvicorn.Config(
            create_app(settings), host="127.0.0.1", port=self.port, log_level="warning",
            ws_per_message_deflate=False))
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_until_complete,
                                       args=(self.server.serve(),), daemon=True)

    def start(self, timeout: float = 180.0) -> ThreadServer:
        self.thread.start()
        deadline = time.monotonic() + timeout
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("the in-process server did not start")
            time.sleep(0.1)
        return self

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(60)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def ws_url(self) -> str:
        return f"ws://127.0.0.1:{self.port}/ws/ingest"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    data_dir = tmp_path_factory.mktemp("feedback_off_loop")
    done = armtrack("create-user", "alice", "--password", PASSWORD, "--data-dir",
                    str(data_dir))
    assert done.returncode == 0, done.stderr
    process = ThreadServer(data_dir).start()
    yield process
    process.stop()


def test_feedback_recounts_run_off_the_event_loop(server, monkeypatch):
    from armtrack.server.ingest import feedback as feedback_module

    recounts: list[tuple[int, float]] = []  # (thread id, seconds)
    counting = feedback_module.detect_repetitions

    def watched(*args, **kwargs):
        start = time.perf_counter()
        try:
            return counting(*args, **kwargs)
        finally:
            recounts.append((threading.get_ident(), time.perf_counter() - start))

    monkeypatch.setattr(feedback_module, "detect_repetitions", watched)
    sim, recording = _simulation(seed=2, repetitions=REPS)
    truth = len(sim.truth.repetitions("elbow_flexion"))
    api = Api(server.url, "alice", PASSWORD)
    plan = MessagePlan(recording, rows_per_message=6)
    hello = {**hello_message(recording, "phone"), "extensions": ["feedback/1"]}
    urls = []
    for i in range(STREAMS):
        patient = api.patient(f"Phone {i}")
        urls.append(f"{server.ws_url}?token={api.device(patient['id'], 'phone')['token']}")
    lags: list[float] = []
    probing = threading.Event()

    async def probe():  # on the server's loop
        while not probing.is_set():
            start = time.perf_counter()
            await asyncio.sleep(0.005)
            lags.append(time.perf_counter() - start - 0.005)

    loop_thread = server.thread.ident
    probe_future = asyncio.run_coroutine_threadsafe(probe(), server.loop)
    feedback: list[list[dict]] = [[] for _ in range(STREAMS)]

    async def reader(ws, i: int):
        async for raw in ws:
            message = json.loads(raw)
            if message["type"] == "feedback":
                feedback[i].append(message)

    async def phone(i: int):
        async with connect(urls[i]) as ws:
            await ws.send(json.dumps(hello))
            ready = json.loads(await ws.recv())
            assert ready["type"] == "ready" and ready["extensions"] == ["feedback/1"]
            task = asyncio.create_task(reader(ws, i))
            await send_paced(ws, plan, SPEED, hold_at_s=MARK_S - 0.1,
                             until=lambda: bool(feedback[i]))
            await asyncio.sleep(2.0)  # the live side catches up with the end
            await ws.send(json.dumps({"type": "bye"}))
            await asyncio.wait_for(task, 60)

    async def run():
        await asyncio.gather(*(phone(i) for i in range(STREAMS)))

    try:
        asyncio.run(run())
    finally:
        probing.set()
        probe_future.result(10)
    on_loop = [s for ident, s in recounts if ident == loop_thread]
    counted = [max((m["repetitions"] for m in f if m["exercise"] == "elbow_flexion"),
                   default=0) for f in feedback]
    lags.sort()
    print(f"\n{STREAMS} phones asking for feedback at {SPEED:g}x: {len(recounts)} recounts "
          f"(median {1e3 * sorted(s for _, s in recounts)[len(recounts) // 2]:.2f} ms), "
          f"{len(on_loop)} on the event loop ({1e3 * sum(on_loop):.0f} ms); loop lag "
          f"median {1e3 * lags[len(lags) // 2]:.2f} ms, p99 "
          f"{1e3 * lags[int(0.99 * len(lags))]:.1f} ms, max {1e3 * lags[-1]:.1f} ms; "
          f"counts {counted} of {truth}")
    assert recounts, "no recount ran"
    assert not on_loop, f"{len(on_loop)} recounts ran on the event loop"
    assert counted == [truth] * STREAMS
    for messages in feedback:  # in stream-time order, as the kit shows them
        times = [m["t"] for m in messages]
        assert times == sorted(times)
