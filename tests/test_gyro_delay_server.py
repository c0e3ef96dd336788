"""A kit that declares its gyroscope's delay (``docs/extensions/gyro-delay.md``) to a real
server (uvicorn, a real WebSocket kit, a real database): the hello's ``gyro_delay_s`` is
kept with the session, and its live estimates, its estimates after close, ``armtrack
reprocess`` and ``armtrack estimate`` of its exported recording all use it; an uploaded
file's header likewise."""

import asyncio
import json
import time

import httpx
import numpy as np
import pytest
from armtrack.estimator.arm import REPORTED_ANGLES
from armtrack.estimator.pipeline import run_recording
from armtrack.estimator.recording import parse_recording
from armtrack.estimator.simulation import SimulationConfig, simulate
from test_kit_gyro_bias_memory import LiveFeed, exported, stored_angles, stream

pytestmark = pytest.mark.both_databases

DELAY_S = 0.0065  # BROAD's gyroscope: 0.65 samples behind its accelerometer at 100 Hz
#: A 6-axis kit whose gyroscopes lag by DELAY_S; its file does not say so, its hello does.
KIT = SimulationConfig(exercise="elbow_flexion", seed=2, nine_axis=False, gyro_delay_s=DELAY_S)


@pytest.fixture(scope="module")
def alice(module_server):
    return module_server.client("alice")


class Reached:
    """The ``live`` feed waited on until it has shown an estimate at ``t`` [s] (a loaded
    machine's live estimation lags the stream by many seconds)."""

    def __init__(self, live: LiveFeed, t: float, timeout: float = 180.0):
        self.live, self.t, self.timeout = live, t, timeout

    def wait_until(self, _end: float) -> None:
        deadline = time.monotonic() + self.timeout
        while not (self.live.trail_t and self.live.trail_t[-1] >= self.t):
            assert time.monotonic() < deadline, f"the live feed did not reach {self.t} s"
            time.sleep(0.1)


def elbow(estimates) -> np.ndarray:
    return np.rad2deg(estimates.angles["elbow_flexion"])


def test_a_kit_declaring_its_delay_is_estimated_with_it_live_after_close_and_reprocessed(
        module_server, alice):
    server = module_server
    sim = simulate(KIT)
    patient = alice.patient("Late gyroscope")
    kit = alice.device(patient["id"])
    with LiveFeed(server, alice, patient["id"]) as live:
        session = alice.wait_processed(stream(server, kit["token"], sim.recording,
                                              Reached(live, 25.0), {"gyro_delay_s": DELAY_S}))
    assert session["processed"] and session["metadata"]["gyro_delay_s"] == "0.0065"
    assert server.sql("SELECT gyro_delay_s FROM sessions WHERE id = :s",
                      s=session["id"]) == [(DELAY_S,)]
    # the exported recording carries the declaration back (armtrack estimate uses it)
    csv = alice.http.get(f"/api/sessions/{session['id']}/recording.csv").content
    assert b"\n# gyro_delay_s: 0.0065\n" in csv
    recording = exported(alice, session["id"])
    assert recording.gyro_delay_s == DELAY_S
    declared = run_recording(recording).finish()
    plain = run_recording(parse_recording(csv.replace(b"# gyro_delay_s: 0.0065\n", b""))
                          ).finish()
    table = stored_angles(alice, session["id"])
    np.testing.assert_allclose(table["t"], declared.t, atol=1e-6)
    np.testing.assert_allclose(table["elbow_flexion"], elbow(declared), atol=1e-3)
    truth = np.interp(declared.t, sim.truth.t, np.rad2deg(sim.truth.angles["elbow_flexion"]))
    scored = declared.t > 10.5

    def rmse(values):
        return float(np.sqrt(np.mean((values - truth)[scored] ** 2)))
    print(f"elbow flexion RMSE, 0.65-sample late gyroscope: stored {rmse(elbow(declared)):.3f}° "
          f"(declared), {rmse(elbow(plain)):.3f}° had it not been declared")
    assert rmse(elbow(declared)) < 0.5 * rmse(elbow(plain))
    # the live estimates took it too
    index = REPORTED_ANGLES.index("elbow_flexion")
    live_t = np.array(live.trail_t)
    live_deg = np.array([row[index] for row in live.trail_deg])
    later = live_t > 12.0
    off_declared = np.abs(live_deg - np.interp(live_t, declared.t, elbow(declared)))
    off_plain = np.abs(live_deg - np.interp(live_t, plain.t, elbow(plain)))
    print(f"live feed: {later.sum()} estimates after 12 s within {off_declared[later].max():.4f}° "
          f"of the stored ones, up to {off_plain[later].max():.3f}° from undeclared ones")
    assert later.sum() >= 20  # (its poses are rate-limited)
    assert off_declared[later].max() <= 0.011 and off_plain[later].max() > 0.1
    # armtrack reprocess agrees
    done = server.armtrack("reprocess", str(session["id"]))
    assert done.returncode == 0, done.stderr
    np.testing.assert_allclose(stored_angles(alice, session["id"])["elbow_flexion"],
                               elbow(declared), atol=1e-3)


def test_an_uploaded_file_declaring_its_delay_keeps_it(module_server, alice):
    sim = simulate(SimulationConfig(**{**KIT.__dict__, "declare_gyro_delay": True}))
    from armtrack.estimator.recording import format_recording
    data = format_recording(sim.recording)
    assert b"# gyro_delay_s: 0.0065\n" in data
    patient = alice.patient("Uploaded late gyroscope")
    kit = alice.device(patient["id"])
    answer = httpx.post(f"{module_server.url}/api/recordings", timeout=120,
                        headers={"Authorization": f"Bearer {kit['token']}"},
                        files={"file": ("kit.csv", data)})
    assert answer.status_code in (200, 201), answer.text
    session = alice.wait_processed(answer.json()["id"])
    assert session["metadata"]["gyro_delay_s"] == "0.0065"
    again = exported(alice, session["id"])
    assert again.gyro_delay_s == DELAY_S
    expected = run_recording(parse_recording(data)).finish()
    np.testing.assert_allclose(stored_angles(alice, session["id"])["elbow_flexion"],
                               elbow(expected), atol=1e-3)


def test_a_kit_without_the_field_is_as_before(module_server, alice):
    sim = simulate(SimulationConfig(exercise="elbow_flexion", seed=2, nine_axis=False))
    patient = alice.patient("In step")
    kit = alice.device(patient["id"])
    session = alice.wait_processed(stream(module_server, kit["token"], sim.recording))
    assert "gyro_delay_s" not in session["metadata"]
    csv = alice.http.get(f"/api/sessions/{session['id']}/recording.csv").content
    assert b"gyro_delay_s" not in csv
    assert module_server.sql("SELECT gyro_delay_s FROM sessions WHERE id = :s",
                             s=session["id"]) == [(None,)]


def test_a_resumed_or_continued_stream_cannot_change_the_sessions_delay(module_server, alice):
    from websockets.asyncio.client import connect
    patient = alice.patient("Resumed late gyroscope")
    kit = alice.device(patient["id"])
    headers = {"Authorization": f"Bearer {kit['token']}"}
    hello = {"type": "hello", "protocol": 1, "device": "kit", "side": "right",
             "sensors": ["forearm"], "rate_hz": 100, "nine_axis": False, "resume": None}

    async def first_answer(message: dict) -> dict:
        async with connect(module_server.ws_url, additional_headers=headers) as ws:
            await ws.send(json.dumps(message))
            return json.loads(await ws.recv())

    async def go() -> None:
        ready = await first_answer({**hello, "gyro_delay_s": DELAY_S})
        assert ready["type"] == "ready", ready
        for change in ({"resume": ready["stream"]},
                       {"session": ready["session"]}):
            refused = await first_answer({**hello, **change, "gyro_delay_s": 0.001})
            assert refused["type"] == "error" and "gyro_delay_s" in refused["reason"], refused
        again = await first_answer({**hello, "resume": ready["stream"], "gyro_delay_s": DELAY_S})
        assert again["type"] == "ready" and again["session"] == ready["session"], again
        silent = await first_answer({**hello, "resume": ready["stream"]})  # not repeated
        assert silent["type"] == "ready" and silent["session"] == ready["session"], silent
        return ready["session"]

    session = asyncio.run(go())
    assert module_server.sql("SELECT gyro_delay_s FROM sessions WHERE id = :s",
                             s=session) == [(DELAY_S,)]


def test_a_refused_resume_or_continuation_leaves_the_running_stream_alone(module_server, alice):
    """A hello that resumes or continues a session but declares another delay (or other
    sensors) is refused: the connection streaming that session goes on, acked, and the
    session stays live (before, the refused hello first closed it, 1001 "replaced")."""
    from websockets.asyncio.client import connect
    patient = alice.patient("Streaming while refused")
    kit = alice.device(patient["id"])
    headers = {"Authorization": f"Bearer {kit['token']}"}
    hello = {"type": "hello", "protocol": 1, "device": "kit", "side": "right",
             "sensors": ["forearm"], "rate_hz": 50, "nine_axis": False, "resume": None}
    rows = [[i / 50, 0.0, 0.0, 9.81, 0.0, 0.0, 0.0, None, None, None] for i in range(50)]

    async def acked(ws, seq: int) -> None:
        await ws.send(json.dumps({"type": "samples", "seq": seq, "sensor": "forearm",
                                  "rows": [[r[0] + seq, *r[1:]] for r in rows]}))
        while (answer := json.loads(await asyncio.wait_for(ws.recv(), 30))) != {
                "type": "ack", "seq": seq}:
            assert answer["type"] != "error", answer

    async def go() -> tuple[int, list]:
        refusals = []
        async with connect(module_server.ws_url, additional_headers=headers) as ws:
            await ws.send(json.dumps({**hello, "gyro_delay_s": DELAY_S}))
            ready = json.loads(await ws.recv())
            await acked(ws, 0)
            for n, change in enumerate(({"resume": ready["stream"], "gyro_delay_s": 0.001},
                                        {"session": ready["session"], "gyro_delay_s": 0.001},
                                        {"resume": ready["stream"], "sensors": ["hand"]},
                                        {"session": ready["session"], "side": "left"})):
                async with connect(module_server.ws_url, additional_headers=headers) as other:
                    await other.send(json.dumps({**hello, **change}))
                    refused = json.loads(await other.recv())
                    refusals.append(refused["reason"])
                    assert refused["type"] == "error", refused
                await acked(ws, n + 1)  # the running stream goes on
            return ready["session"], refusals

    session, refusals = asyncio.run(go())
    print("refused:", *refusals, sep="\n  ")
    assert "gyro_delay_s" in refusals[0] and "gyro_delay_s" in refusals[1]
    assert "sensors" in refusals[2] and "side" in refusals[3]
    assert module_server.sql("SELECT COUNT(*) FROM streams WHERE session_id = :s",
                             s=session) == [(1,)]  # no stream made for a refused hello


def test_reprocess_with_a_filter_that_cannot_take_the_delay_keeps_the_estimates(
        module_server, alice):
    """``armtrack reprocess --filter ekf`` of a session whose kit declared a delay (ekf
    cannot take one), or with a filter that does not exist, is refused naming what is
    wrong, exit 2, and the session keeps its estimates (before: they were deleted and the
    session showed a processing error)."""
    sim = simulate(SimulationConfig(**{**KIT.__dict__, "declare_gyro_delay": True}))
    from armtrack.estimator.recording import format_recording
    patient = alice.patient("Reprocessed late gyroscope")
    answer = alice.http.post("/api/recordings", timeout=120,
                             data={"patient_id": str(patient["id"])},
                             files={"file": ("kit.csv", format_recording(sim.recording))})
    assert answer.status_code in (200, 201), answer.text
    session = alice.wait_processed(answer.json()["id"])
    assert session["processed"], session
    before = stored_angles(alice, session["id"])
    for filter_name, named in (("ekf", "gyro_delay_s"), ("qfc", "qfc")):
        done = module_server.armtrack("reprocess", str(session["id"]), "--filter", filter_name)
        print(f"--filter {filter_name}: exit {done.returncode}: {done.stderr.strip()}")
        assert done.returncode == 2 and named in done.stderr, (done.returncode, done.stderr)
        after = alice.session(session["id"])
        assert after["processed"] and after["processing_error"] is None, after
        np.testing.assert_array_equal(stored_angles(alice, session["id"])["elbow_flexion"],
                                      before["elbow_flexion"])


def test_armtrack_stream_of_a_file_declaring_its_delay_declares_it(module_server, alice,
                                                                   tmp_path):
    """``armtrack stream REC.csv`` (the kit emulator, docs/kit-builder.md) of a file whose
    header declares ``gyro_delay_s`` says so in its hello: the streamed session keeps the
    delay and is estimated as the file's upload is (before, the hello left it out and the
    session was estimated as in step)."""
    from armtrack.estimator.recording import format_recording
    sim = simulate(SimulationConfig(**{**KIT.__dict__, "declare_gyro_delay": True}))
    path = tmp_path / "late.csv"
    path.write_bytes(format_recording(sim.recording))
    patient = alice.patient("Streamed file, late gyroscope")
    kit = alice.device(patient["id"])
    from server_support import armtrack
    done = armtrack("stream", str(path), "--url", module_server.ws_url,
                    "--token", kit["token"], "--speed", "0", "--quiet", timeout=300)
    assert done.returncode == 0, done.stderr
    sessions = alice.http.get(f"/api/patients/{patient['id']}/sessions").json()
    assert len(sessions) == 1, sessions
    assert module_server.sql("SELECT gyro_delay_s FROM sessions WHERE id = :s",
                             s=sessions[0]["id"]) == [(DELAY_S,)]
    session = alice.wait_processed(sessions[0]["id"], timeout=300)
    assert session["metadata"]["gyro_delay_s"] == "0.0065", session["metadata"]


def test_a_resume_declaring_a_delay_the_session_never_had_says_so(module_server, alice):
    """The refusal of a resume declaring a delay in a session whose kit declared none says
    that none was declared (before: "differs from the session's (0.0 s, declared when it
    began)", a declaration the kit never made)."""
    from websockets.asyncio.client import connect
    patient = alice.patient("Delay declared late")
    kit = alice.device(patient["id"])
    headers = {"Authorization": f"Bearer {kit['token']}"}
    hello = {"type": "hello", "protocol": 1, "device": "kit", "side": "right",
             "sensors": ["forearm"], "rate_hz": 50, "nine_axis": False, "resume": None}

    async def go() -> str:
        async with connect(module_server.ws_url, additional_headers=headers) as ws:
            await ws.send(json.dumps(hello))
            ready = json.loads(await ws.recv())
        async with connect(module_server.ws_url, additional_headers=headers) as ws:
            await ws.send(json.dumps({**hello, "resume": ready["stream"],
                                      "gyro_delay_s": 0.002}))
            return json.loads(await ws.recv())["reason"]

    reason = asyncio.run(go())
    print(reason)
    assert "gyro_delay_s 0.002" in reason and "declared none" in reason, reason
    assert "declared when it began" not in reason, reason


def test_a_closed_sessions_resume_is_told_it_is_closed_whatever_its_kit(module_server, alice):
    """A resume of a closed session is refused as closed (closed-session/1: with
    ``next_seq``, the kit sends the rest as a new session) even when its hello names other
    sensors or another delay: the kit's checks come after, as they did before they moved
    ahead of the running connection's close."""
    from websockets.asyncio.client import connect
    patient = alice.patient("Closed, then resumed otherwise")
    kit = alice.device(patient["id"])
    headers = {"Authorization": f"Bearer {kit['token']}"}
    hello = {"type": "hello", "protocol": 1, "device": "kit", "side": "right",
             "sensors": ["forearm"], "rate_hz": 50, "nine_axis": False, "resume": None,
             "extensions": ["closed-session/1"]}

    async def go() -> list[dict]:
        async with connect(module_server.ws_url, additional_headers=headers) as ws:
            await ws.send(json.dumps(hello))
            ready = json.loads(await ws.recv())
        closed = await asyncio.to_thread(
            alice.http.post, f"/api/sessions/{ready['session']}/close?wait=false")
        assert closed.status_code == 202, closed.text
        answers = []
        for change in ({"sensors": ["hand"]}, {"gyro_delay_s": 0.002}):
            async with connect(module_server.ws_url, additional_headers=headers) as ws:
                await ws.send(json.dumps({**hello, "resume": ready["stream"], **change}))
                answers.append(json.loads(await ws.recv()))
        return answers

    for answer in asyncio.run(go()):
        assert answer["type"] == "error" and "closed" in answer["reason"], answer
        assert answer.get("next_seq") == 0, answer
