"""The stream protocol (``spec/ingest.md``) against a real ``armtrack serve`` process,
spoken by a bare WebSocket client: tokens, hello, every kind of refusal (each names its
``seq`` and what is wrong, is refused whole and uses up its number), seq order, acks,
``status``, ``bye``, resume, the server killed with SIGKILL mid-stream, and one patient's
bad stream beside another's good one. What is stored is read back over REST
(``recording.csv`` and the session's ``samples``) and compared bit for bit."""

from __future__ import annotations

import asyncio
import json
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from armtrack.estimator.recording import Recording, parse_recording
from armtrack.estimator.simulation import SimulationConfig, simulate
from armtrack.server.emulator import KitEmulator
from server_support import ServerProcess
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

MiB = 1 << 20
SENSOR = "forearm"
ROWS = 10  # rows per message of good()
HELLO = {"type": "hello", "protocol": 1, "device": "test-kit", "side": "right",
         "sensors": [SENSOR], "rate_hz": 100, "nine_axis": True, "resume": None}


# -- the server, shared by the module ----------------------------------------------------

@pytest.fixture(scope="module")
def srv(module_server):
    """The module's server (conftest's ``module_server``)."""
    return module_server


@pytest.fixture(scope="module")
def api(srv):
    return srv.client("alice")


@pytest.fixture(scope="module")
def patient(api) -> dict:
    return api.patient("Kit tester")


@pytest.fixture(scope="module")
def token(api, patient) -> str:
    return api.device(patient["id"])["token"]


def new_token(api, name: str = "Other") -> tuple[dict, dict]:
    """A fresh patient and a device of theirs ({"id", "token"})."""
    patient = api.patient(name)
    return patient, api.device(patient["id"])


def run(coroutine, timeout: float = 60):
    async def bounded():
        async with asyncio.timeout(timeout):
            return await coroutine
    return asyncio.run(bounded())


# -- messages ------------------------------------------------------------------------------

def rows(seq: int, n: int = ROWS, nine_axis: bool = True) -> list[list[Any]]:
    """n rows of message ``seq``: times seq/10 + i/100 s (so messages follow each other),
    random values with all 17 digits, in range; the same for the same seq."""
    rng = np.random.default_rng(seq)
    t = seq / 10 + np.arange(n) / 100
    table = np.hstack([t[:, None], rng.uniform(-20, 20, (n, 3)), rng.uniform(-5, 5, (n, 3)),
                       rng.uniform(-60, 60, (n, 3))]).tolist()
    if not nine_axis:
        for row in table:
            row[7:] = [None, None, None]
    return table


def good(seq: int, nine_axis: bool = True, sensor: str = SENSOR) -> dict[str, Any]:
    return {"type": "samples", "seq": seq, "sensor": sensor, "rows": rows(seq,
                                                                          nine_axis=nine_axis)}


def text(message: dict[str, Any]) -> str:
    return json.dumps(message, allow_nan=False, separators=(",", ":"))


# -- a bare device connection --------------------------------------------------------------

class Kit:
    """One device connection: sends what it is told; checks the shape of every ``ack``
    and ``error`` it gets and keeps the highest ack."""

    def __init__(self, ws: ClientConnection):
        self.ws = ws
        self.acked = -1
        self.ack_times: list[float] = []
        self.before_close: list[dict] = []

    @classmethod
    async def open(cls, server: ServerProcess, token: str | None, *,
                   query: bool = False) -> Kit:
        url, headers = server.ws_url, {}
        if token is not None and query:
            url += f"?token={token}"
        elif token is not None:
            headers["Authorization"] = f"Bearer {token}"
        return cls(await connect(url, additional_headers=headers, max_size=None,
                                 open_timeout=10))

    async def send(self, message: dict[str, Any] | str | bytes) -> None:
        await self.ws.send(message if isinstance(message, str | bytes) else text(message))

    async def send_too_big(self, message: str) -> None:
        """Send a message the server refuses by its size: the server may close (1009) while
        the frame is still being written, so a broken pipe on this send is expected; the
        close code is then read with :meth:`closed`."""
        try:
            await self.send(message)
        except ConnectionClosed:
            pass

    async def raw(self, timeout: float = 5.0) -> dict[str, Any]:
        message = json.loads(await asyncio.wait_for(self.ws.recv(), timeout))
        if message.get("type") == "ack":
            assert set(message) == {"type", "seq"}, message
            assert type(message["seq"]) is int and message["seq"] >= self.acked, message
            self.acked = message["seq"]
            self.ack_times.append(time.monotonic())
        elif message.get("type") == "error":
            assert set(message) == {"type", "seq", "reason"}, message
            assert message["seq"] is None or type(message["seq"]) is int, message
            assert isinstance(message["reason"], str) and message["reason"], message
        return message

    async def next(self, timeout: float = 5.0) -> dict[str, Any]:
        """The next message that is not an ack."""
        while True:
            message = await self.raw(timeout)
            if message["type"] != "ack":
                return message

    async def error(self, timeout: float = 5.0) -> dict[str, Any]:
        message = await self.next(timeout)
        assert message["type"] == "error", message
        return message

    async def ack(self, seq: int, timeout: float = 5.0) -> None:
        """Wait for an ack covering ``seq``; anything but acks on the way fails."""
        deadline = time.monotonic() + timeout
        while self.acked < seq:
            message = await self.raw(max(deadline - time.monotonic(), 0.01))
            assert message["type"] == "ack", message

    async def hello(self, **changes: Any) -> dict[str, Any]:
        await self.send({**HELLO, **changes})
        ready = await self.raw()
        assert ready["type"] == "ready", ready
        assert set(ready) == {"type", "stream", "session", "next_seq"}, ready
        assert isinstance(ready["stream"], str) and type(ready["session"]) is int
        assert type(ready["next_seq"]) is int
        return ready

    async def closed(self, timeout: float = 5.0) -> int | None:
        """Read until the server closes; the close code (messages on the way are kept)."""
        try:
            while True:
                self.before_close.append(await self.raw(timeout))
        except ConnectionClosed:
            pass
        return self.ws.close_code

    async def bye(self) -> None:
        """``bye``: everything is acked, then the server closes with 1000."""
        await self.send({"type": "bye"})
        assert await self.closed() == 1000, self.before_close
        assert all(m["type"] == "ack" for m in self.before_close), self.before_close

    def drop(self) -> None:
        """Lose the connection: no close frame, as when a kit walks out of range."""
        self.ws.transport.abort()


def words_in(reason: str, *words: str) -> None:
    for word in words:
        assert word.lower() in reason.lower(), (word, reason)


# -- what is stored --------------------------------------------------------------------

def export(api, session_id: int) -> Recording:
    answer = api.http.get(f"/api/sessions/{session_id}/recording.csv")
    assert answer.status_code == 200, answer.text
    return parse_recording(answer.content)


def assert_stored(api, session_id: int, messages: list[dict[str, Any]],
                  nine_axis: bool = True) -> None:
    """The session holds exactly the rows of ``messages``, in order, bit for bit."""
    table = np.array([row for m in messages for row in m["rows"]], dtype=np.float64)
    assert api.session(session_id)["samples"] == len(table)
    got = export(api, session_id).sensors[SENSOR]
    stored = np.column_stack([got.t, got.acc, got.gyr,
                              got.mag if nine_axis else np.full((len(got.t), 3), np.nan)])
    if not nine_axis:
        assert got.mag is None
    assert stored.shape == table.shape
    assert np.array_equal(stored.view(np.int64), table.view(np.int64))


def wait_status(api, session_id: int, status: str, timeout: float = 5.0) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        session = api.session(session_id)
        if session["status"] == status or time.monotonic() > deadline:
            assert session["status"] == status, session
            return session
        time.sleep(0.05)


# -- tokens ----------------------------------------------------------------------------

@pytest.mark.parametrize("how", ["header", "query", "none", "empty-bearer"])
def test_a_wrong_token_closes_4401_before_any_data(srv, token, how):
    async def go():
        if how == "none":
            kit = await Kit.open(srv, None)
        elif how == "empty-bearer":
            kit = Kit(await connect(srv.ws_url, additional_headers={"Authorization": "Bearer "}))
        else:
            kit = await Kit.open(srv, token[::-1], query=how == "query")
        # nothing sent: the server closes on its own, having read nothing
        code = await kit.closed()
        assert code == 4401 and kit.before_close == []
        return kit.ws.close_reason
    reason = run(go())
    words_in(reason, "token")


def test_the_token_may_come_as_a_query_parameter(srv, api, token):
    async def go():
        kit = await Kit.open(srv, token, query=True)
        ready = await kit.hello()
        assert ready["next_seq"] == 0
        await kit.send(good(0))
        await kit.ack(0)
        await kit.bye()
        return ready["session"]
    session = run(go())
    assert_stored(api, session, [good(0)])


def test_revoking_a_device_closes_its_open_stream_with_4401_at_once(srv, api):
    device = new_token(api, "Revoked")[1]

    async def go():
        kit = await Kit.open(srv, device["token"])
        ready = await kit.hello()
        await kit.send(good(0))
        await kit.ack(0)
        started = time.monotonic()
        answer = await asyncio.to_thread(api.http.delete, f"/api/devices/{device['id']}")
        assert answer.status_code < 300, answer.text
        assert await kit.closed(timeout=2) == 4401, kit.before_close
        assert time.monotonic() - started < 2
        # the token no longer works, as header or query, before any data
        for query in (False, True):
            again = await Kit.open(srv, device["token"], query=query)
            assert await again.closed() == 4401 and again.before_close == []
        return ready["session"]
    session = run(go())
    # what was acked is stored; the session waits for a resume that cannot come
    wait_status(api, session, "interrupted")
    assert_stored(api, session, [good(0)])


# -- hello -------------------------------------------------------------------------------

@pytest.mark.parametrize("protocol", [2, 0, "1", 1.5, True, None])
def test_a_wrong_protocol_version_closes_4400(srv, api, protocol):
    patient, device = new_token(api, "Version")

    async def go():
        kit = await Kit.open(srv, device["token"])
        await kit.send({**HELLO, "protocol": protocol})
        error = await kit.error()
        assert error["seq"] is None
        words_in(error["reason"], "protocol", "1")
        assert await kit.closed() == 4400
    run(go())
    assert api.http.get(f"/api/patients/{patient['id']}/sessions").json() == []


@pytest.mark.parametrize("first, words", [
    (text(good(0)), ["hello", "samples"]),
    (text({"type": "bye"}), ["hello", "bye"]),
    ("{not json", ["malformed JSON"]),
    ("[1, 2]", ["object"]),
    (text({**HELLO, "sensors": ["forearm", "foot"]}), ["sensor", "foot"]),
    (text({**HELLO, "sensors": []}), ["sensors"]),
    (text({**HELLO, "side": "up"}), ["side", "up"]),
    (text({k: v for k, v in HELLO.items() if k != "nine_axis"}), ["nine_axis"]),
    # docs/extensions/gyro-delay.md: 0 to 0.05 s, a JSON number
    (text({**HELLO, "gyro_delay_s": -0.001}), ["gyro_delay_s", "-0.001"]),
    (text({**HELLO, "gyro_delay_s": 0.06}), ["gyro_delay_s", "0.06"]),
    (text({**HELLO, "gyro_delay_s": "0.0065"}), ["gyro_delay_s", "0.0065"]),
    (text({**HELLO, "gyro_delay_s": True}), ["gyro_delay_s", "True"]),
], ids=["samples", "bye", "malformed", "not-an-object", "unknown-sensor", "no-sensors",
        "bad-side", "no-nine-axis", "delay-negative", "delay-too-long", "delay-text",
        "delay-bool"])
def test_a_first_message_that_is_not_a_good_hello_is_refused(srv, api, first, words):
    patient, device = new_token(api, "Hello")

    async def go():
        kit = await Kit.open(srv, device["token"])
        await kit.send(first)
        error = await kit.error()
        assert error["seq"] is None
        words_in(error["reason"], *words)
        assert await kit.closed() == 4400
    run(go())
    assert api.http.get(f"/api/patients/{patient['id']}/sessions").json() == []


# -- refusals: each names its seq and what is wrong, is never stored, uses up its number --

@dataclass(frozen=True)
class Bad:
    id: str
    message: str | bytes  # sent as message 1 (after a good message 0)
    seq: int | None  # the seq the error names; when 1 the number is used up
    words: tuple[str, ...]
    nine_axis: bool = True


def bad(changes: dict[str, Any] | None = None, drop: str | None = None,
        row: tuple[int, int, Any] | None = None, nine_axis: bool = True,
        raw: tuple[str, str] | None = None) -> str:
    """Message 1 (a good one) with ``changes``, a key dropped, one value of one row set,
    or a piece of its JSON text replaced."""
    message = {**good(1, nine_axis), **(changes or {})}
    if drop:
        del message[drop]
    if row:
        i, column, value = row
        message["rows"][i][column] = value
    encoded = json.dumps(message, separators=(",", ":"))
    if raw:
        assert raw[0] in encoded
        encoded = encoded.replace(raw[0], raw[1], 1)
    return encoded


def _value(i: int, column: int) -> str:
    return repr(rows(1)[i][column])


def _sample_with(nine_axis: bool = True, **columns: float) -> list[list[float | None]]:
    table = rows(1, nine_axis=nine_axis)
    names = ("t", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz")
    for name, value in columns.items():
        table[0][names.index(name)] = value
    return table


BAD = [
    # seq
    Bad("seq-string", bad({"seq": "1"}), None, ("seq",)),
    Bad("seq-bool", bad({"seq": True}), None, ("seq",)),
    Bad("seq-float", bad({"seq": 1.0}), None, ("seq",)),
    Bad("seq-negative", bad({"seq": -1}), None, ("seq",)),
    Bad("seq-missing", bad(drop="seq"), None, ("seq",)),
    # rows
    Bad("rows-string", bad({"rows": "0.1,1,2"}), 1, ("rows",)),
    Bad("rows-object", bad({"rows": {"t": 0.1}}), 1, ("rows",)),
    Bad("rows-missing", bad(drop="rows"), 1, ("rows",)),
    Bad("rows-empty", bad({"rows": []}), 1, ("rows", "1 to 1000")),
    Bad("rows-1001", bad({"rows": [rows(1, 1)[0]] * 1001}), 1, ("rows", "1000")),
    Bad("row-not-a-list", bad({"rows": [*rows(1, 2), 0.5]}), 1, ("row", "list")),
    Bad("row-an-object", bad({"rows": [{"t": 0.1}]}), 1, ("row", "list")),
    Bad("row-of-9", bad({"rows": [rows(1, 1)[0][:9]]}), 1, ("row", "10")),
    Bad("row-of-11", bad({"rows": [rows(1, 1)[0] + [1.0]]}), 1, ("row", "10")),
    Bad("value-string", bad(row=(3, 2, "9.81")), 1, ("number", "str")),
    Bad("value-bool", bad(row=(3, 4, True)), 1, ("number", "true/false")),
    Bad("value-list", bad(row=(3, 4, [1.0])), 1, ("number", "list")),
    Bad("null-accelerometer", bad(row=(2, 2, None)), 1, ("row 2", "ay", "null")),
    Bad("null-time", bad(row=(0, 0, None)), 1, ("row 0", "t", "null")),
    # numbers JSON does not allow, and numbers too large for a float64
    Bad("NaN", bad(raw=(_value(4, 5), "NaN")), 1, ("NaN",)),
    Bad("Infinity", bad(raw=(_value(4, 1), "Infinity")), 1, ("Infinity",)),
    Bad("-Infinity", bad(raw=(_value(4, 8), "-Infinity")), 1, ("Infinity",)),
    Bad("NaN-time", bad(raw=(_value(0, 0), "NaN")), 1, ("NaN",)),
    Bad("1e400", bad(raw=(_value(4, 1), "1e400")), 1, ("too large",)),
    Bad("10**400", bad(raw=(_value(4, 1), "1" + "0" * 400)), 1, ("too large",)),
    # out of range: the norm of each vector
    Bad("acc-over-160", bad({"rows": _sample_with(ax=160.001, ay=0.0, az=0.0)}), 1,
        ("row 0", "|a|", "physical range", "160")),
    Bad("acc-norm-over-160", bad({"rows": _sample_with(ax=-100.0, ay=100.0, az=-100.0)}), 1,
        ("|a|", "160")),
    Bad("gyr-over-35", bad({"rows": _sample_with(gx=0.0, gy=0.0, gz=-35.001)}), 1,
        ("|g|", "physical range", "35")),
    Bad("mag-over-5000", bad({"rows": _sample_with(mx=3000.0, my=-3000.0, mz=3000.0)}), 1,
        ("|m|", "physical range", "5000")),
    # magnetometer against the hello's nine_axis
    Bad("9-axis-null-mag", bad(row=(5, 8, None)), 1, ("9-axis", "mx my mz", "numbers")),
    Bad("9-axis-all-null-mag", bad({"rows": rows(1, nine_axis=False)}), 1, ("9-axis",)),
    Bad("6-axis-numbers", bad(nine_axis=True), 1, ("6-axis", "null"), nine_axis=False),
    Bad("6-axis-one-number", bad(nine_axis=False, row=(7, 9, 12.5)), 1, ("6-axis", "null"),
        nine_axis=False),
    Bad("6-axis-range", bad({"rows": _sample_with(False, gz=40.0)}, nine_axis=False), 1,
        ("|g|",), nine_axis=False),
    # sensors
    Bad("sensor-unknown", bad({"sensor": "foot"}), 1, ("sensor", "foot", "hello")),
    Bad("sensor-not-in-hello", bad({"sensor": "hand"}), 1, ("sensor", "hand", "hello")),
    Bad("sensor-missing", bad(drop="sensor"), 1, ("sensor",)),
    # time going backwards, within the message and after message 0 (t ≤ 0.09)
    Bad("t-backwards-within", bad(row=(6, 0, 0.145)), 1, ("row 6", "backwards", SENSOR)),
    Bad("t-backwards-across", bad({"rows": rows(0, 5)}), 1,
        ("backwards", SENSOR, "0.09")),
    # marks share the count and the rules
    Bad("mark-label", text({"type": "mark", "seq": 1, "t": 0.1, "label": "stretch"}), 1,
        ("label", "stretch")),
    Bad("mark-t-string", text({"type": "mark", "seq": 1, "t": "0.1", "label": "npose"}), 1,
        ("t",)),
    Bad("mark-t-NaN", '{"type":"mark","seq":1,"t":NaN,"label":"npose"}', 1, ("t", "NaN")),
    # not a message of the protocol: no seq to name, none used up
    Bad("malformed-JSON", '{"type":"samples","seq":1,', None, ("malformed JSON",)),
    Bad("binary-not-UTF-8", b'{"type":"samples","seq":1,"sensor":"\xff"}', None,
        ("malformed JSON",)),
    Bad("not-an-object", "[1, 2, 3]", None, ("object",)),
    Bad("no-type", text({"seq": 1, "sensor": SENSOR, "rows": rows(1)}), None, ("type",)),
    Bad("unknown-type", text({**good(1), "type": "sample"}), None, ("unknown", "sample")),
    Bad("second-hello", text(HELLO), None, ("hello",)),
]


@pytest.mark.parametrize("case", BAD, ids=[c.id for c in BAD])
def test_a_bad_message_is_refused_whole_with_its_seq_and_the_stream_goes_on(srv, api, token,
                                                                           case):
    async def go():
        kit = await Kit.open(srv, token)
        ready = await kit.hello(nine_axis=case.nine_axis)
        await kit.send(good(0, case.nine_axis))
        await kit.ack(0)
        await kit.send(case.message)
        error = await kit.error()
        assert error["seq"] == case.seq, error
        words_in(error["reason"], *case.words)
        if case.seq == 1:
            await kit.ack(1)  # handled: refused, so the kit drops it
        nxt = 2 if case.seq == 1 else 1  # a refused message uses up its number
        await kit.send(good(nxt, case.nine_axis))
        await kit.ack(nxt)
        await kit.bye()
        return ready["session"], nxt
    session, nxt = run(go())
    assert_stored(api, session, [good(0, case.nine_axis), good(nxt, case.nine_axis)],
                  case.nine_axis)


def test_values_at_the_limits_and_a_6_axis_stream_are_stored_exactly(srv, api, token):
    edge = rows(0, 4)
    edge[0][1:10] = [160.0, 0.0, 0.0, 0.0, -35.0, 0.0, 0.0, 0.0, 5000.0]
    edge[1][1:10] = [0.0, 0.0, -160.0, 35.0, 0.0, 0.0, -5000.0, 0.0, 0.0]
    edge[2][0] = edge[1][0]  # t may repeat
    edge[3][1:4] = [5e-324, -0.0, 1e-300]  # subnormal, signed zero
    nine = [{"type": "samples", "seq": 0, "sensor": SENSOR, "rows": edge}, good(1), good(2)]
    six = [good(0, False), good(1, False)]

    async def go(messages, nine_axis):
        kit = await Kit.open(srv, token)
        ready = await kit.hello(nine_axis=nine_axis)
        for m in messages:
            await kit.send(m)
        await kit.ack(len(messages) - 1)
        await kit.bye()
        return ready["session"]
    assert_stored(api, run(go(nine, True)), nine)
    assert_stored(api, run(go(six, False)), six, nine_axis=False)


def test_a_refused_message_does_not_move_the_clock_on(srv, api, token):
    """A refused message is not stored in part: its times do not count for the check of
    time going backwards."""
    future = rows(50)
    future[3][5] = 99.0  # out of range, with times 5.0… s

    async def go():
        kit = await Kit.open(srv, token)
        ready = await kit.hello()
        await kit.send(good(0))
        await kit.send({"type": "samples", "seq": 1, "sensor": SENSOR, "rows": future})
        error = await kit.error()
        assert error["seq"] == 1
        words_in(error["reason"], "row 3", "|g|")
        await kit.send(good(2))  # times 0.2… s: after message 0, before the refused one
        await kit.ack(2)
        await kit.bye()
        return ready["session"]
    assert_stored(api, run(go()), [good(0), good(2)])


# -- seq order ---------------------------------------------------------------------------

def test_a_duplicate_is_dropped_and_acked_again_and_a_gap_is_refused(srv, api, token):
    async def go():
        kit = await Kit.open(srv, token)
        ready = await kit.hello()
        for seq in range(3):
            await kit.send(good(seq))
        await kit.ack(2)
        acks = len(kit.ack_times)
        # a duplicate (different content: it must not be stored) is acked again
        await kit.send({**good(1), "rows": rows(7)})
        message = await kit.raw()
        assert message == {"type": "ack", "seq": 2}
        assert len(kit.ack_times) == acks + 1
        # a gap: refused, naming the expected seq, the number not used up
        await kit.send(good(5))
        error = await kit.error()
        assert error["seq"] == 5
        words_in(error["reason"], "expected 3")
        await kit.send(good(4))
        error = await kit.error()
        assert error["seq"] == 4
        words_in(error["reason"], "expected 3")
        # a seq far beyond 64 bits (found by the fuzzing): refused, named back exactly
        # (the error was never sent: the server's JSON encoder refused the integer)
        await kit.send({**good(3), "seq": 10**400})
        error = await kit.error()
        assert error["seq"] == 10**400
        words_in(error["reason"], "expected 3")
        for seq in (3, 4, 5):
            await kit.send(good(seq))
        await kit.ack(5)
        # duplicates of a refused message and of an old one: no error
        await kit.send(good(0))
        await kit.send(good(5))
        await kit.send(good(6))
        await kit.ack(6)
        await kit.bye()
        return ready["session"]
    assert_stored(api, run(go()), [good(seq) for seq in range(7)])


def test_marks_share_the_seq_count_with_samples(srv, api, token):
    async def go():
        kit = await Kit.open(srv, token)
        ready = await kit.hello()
        await kit.send({"type": "mark", "seq": 0, "t": 0.0, "label": "exercise:elbow_flexion"})
        await kit.send(good(1))
        await kit.send(good(2))
        await kit.send({"type": "mark", "seq": 3, "t": 0.25, "label": "end:exercise:elbow_flexion"})
        await kit.send({"type": "mark", "seq": 3, "t": 0.26, "label": "npose"})  # duplicate
        await kit.send(good(4))
        await kit.ack(4)
        await kit.bye()
        return ready["session"]
    session = run(go())
    assert_stored(api, session, [good(1), good(2), good(4)])
    marks = [(m.t, m.label) for m in export(api, session).marks]
    assert marks == [(0.0, "exercise:elbow_flexion"), (0.25, "end:exercise:elbow_flexion")]


# -- flood -------------------------------------------------------------------------------

def test_more_than_50_refused_messages_in_10_s_close_with_4429(srv, api, token):
    async def go():
        kit = await Kit.open(srv, token)
        ready = await kit.hello()
        for i in range(50):
            await kit.send("{broken" if i % 2 else text(good(i // 2 + 1)))  # gaps and junk
            error = await kit.error()
            words_in(error["reason"], "malformed JSON" if i % 2 else "expected 0")
        await kit.send(good(0))  # 50 refusals: still open
        await kit.ack(0)
        await kit.send("{broken")  # the 51st
        assert await kit.closed() == 4429
        errors = [m for m in kit.before_close if m["type"] == "error"]
        assert len(errors) == 1
        words_in(kit.ws.close_reason, "50", "10 s")
        return ready
    ready = run(go())
    session = wait_status(api, ready["session"], "interrupted")
    assert session["samples"] == ROWS
    assert_stored(api, ready["session"], [good(0)])


# -- size --------------------------------------------------------------------------------

def padded(message: dict[str, Any], size: int, pad: str = " ") -> str:
    """The message's JSON padded with whitespace (or a string field of ``pad``) to
    exactly ``size`` UTF-8 bytes."""
    body = text(message)
    if pad == " ":
        result = body[:-1] + " " * (size - len(body.encode())) + "}"
    else:
        head = body[:-1] + ',"note":"'
        n = (size - len(head.encode()) - 2) // len(pad.encode())
        result = head + pad * n + '"}'
        result = result[:-2] + " " * (size - len(result.encode())) + '"}'
    assert len(result.encode()) == size
    return result


@pytest.mark.parametrize("pad", [" ", "é"], ids=["ascii", "two-byte-characters"])
def test_a_message_over_1_MiB_closes_with_1009(srv, api, token, pad):
    async def go():
        kit = await Kit.open(srv, token)
        ready = await kit.hello()
        await kit.send(padded(good(0), MiB, pad))  # exactly 1 MiB: taken
        await kit.ack(0)
        await kit.send_too_big(padded(good(1), MiB + 1, pad))
        assert await kit.closed() == 1009
        return ready["session"]
    session = run(go())
    wait_status(api, session, "interrupted")
    assert_stored(api, session, [good(0)])


# -- status ------------------------------------------------------------------------------

def test_status_is_shown_live_not_stored_and_uses_no_seq(srv, api, patient, token):
    async def go():
        live = await connect(f"ws://127.0.0.1:{srv.port}/ws/live?patient={patient['id']}",
                             additional_headers={"Authorization": f"Bearer {api.token}"})
        kit = await Kit.open(srv, token)
        ready = await kit.hello()
        await kit.send({"type": "status", "sensor": SENSOR, "battery": 0.82, "rssi_dbm": -61})
        async with asyncio.timeout(5):
            while (update := json.loads(await live.recv())).get("kind") != "status":
                pass
        assert update["sensor"] == SENSOR and update["battery"] == 0.82
        assert update["rssi_dbm"] == -61
        await live.close()
        for status, words in (({"sensor": "hand", "battery": 0.5}, ("sensor", "hand")),
                              ({"sensor": SENSOR, "battery": 1.5}, ("battery", "1.5")),
                              ({"sensor": SENSOR, "battery": True}, ("battery",)),
                              ({"sensor": SENSOR, "rssi_dbm": "-61"}, ("rssi_dbm",))):
            await kit.send({"type": "status", **status})
            error = await kit.error()
            assert error["seq"] is None
            words_in(error["reason"], "status", *words)
        await kit.send({"type": "status", "sensor": SENSOR})  # nothing to report: fine
        await kit.send(good(0))  # status used no seq
        await kit.ack(0)
        await kit.bye()
        return ready["session"]
    assert_stored(api, run(go()), [good(0)])


# -- bye ---------------------------------------------------------------------------------

def test_bye_stores_everything_closes_the_session_and_the_socket_with_1000(srv, api, token):
    async def go():
        kit = await Kit.open(srv, token)
        ready = await kit.hello()
        for seq in range(5):
            await kit.send(good(seq))
        await kit.send({"type": "bye"})  # before any ack: everything is stored first
        assert await kit.closed() == 1000
        assert kit.acked == 4 and {m["type"] for m in kit.before_close} == {"ack"}
        session = await asyncio.to_thread(api.session, ready["session"])
        assert session["status"] == "closed" and session["ended_at"] is not None
        # a closed session is not resumed
        again = await Kit.open(srv, token)
        await again.send({**HELLO, "resume": ready["stream"]})
        error = await again.error()
        assert error["seq"] is None
        words_in(error["reason"], "closed", "resume")
        assert await again.closed() == 4400
        return ready["session"]
    assert_stored(api, run(go()), [good(seq) for seq in range(5)])


# -- resume ------------------------------------------------------------------------------

def test_a_resumed_stream_continues_from_the_first_unstored_seq(srv, api, token):
    sent = [good(seq) for seq in range(12)]

    async def go():
        kit = await Kit.open(srv, token)
        ready = await kit.hello()
        stream, session = ready["stream"], ready["session"]
        for m in sent[:5]:
            await kit.send(m)
        await kit.ack(4)
        kit.drop()
        await asyncio.to_thread(wait_status, api, session, "interrupted")

        kit = await Kit.open(srv, token)
        again = await kit.hello(resume=stream)
        assert again == {"type": "ready", "stream": stream, "session": session, "next_seq": 5}
        assert (await asyncio.to_thread(api.session, session))["status"] == "live"
        for m in sent[5:8]:
            await kit.send(m)
        kit.drop()  # unacked: stored or not, the server says which
        await asyncio.sleep(0.2)

        kit = await Kit.open(srv, token, query=True)
        again = await kit.hello(resume=stream)
        first_unstored = again["next_seq"]
        assert 5 <= first_unstored <= 8 and again["stream"] == stream
        await asyncio.to_thread(assert_stored, api, session, sent[:first_unstored])
        # the kit sends again all it has no ack for: the stored ones are duplicates
        for m in sent[5:]:
            await kit.send(m)
        await kit.ack(11)
        await kit.bye()
        return session
    session = run(go())
    assert_stored(api, session, sent)
    assert api.session(session)["status"] == "closed"


def test_a_resume_replaces_a_connection_still_open(srv, api, token):
    async def go():
        old = await Kit.open(srv, token)
        ready = await old.hello()
        for seq in range(3):
            await old.send(good(seq))
        await old.ack(2)
        await old.send(good(3))
        kit = await Kit.open(srv, token)
        again = await kit.hello(resume=ready["stream"])
        # message 3 was handled by the old connection or not: either way, told
        assert again["next_seq"] in (3, 4) and again["session"] == ready["session"]
        assert await old.closed() == 1001
        await asyncio.sleep(0.3)  # the old connection's end is over: still live
        status = (await asyncio.to_thread(api.session, ready["session"]))["status"]
        assert status == "live"
        for seq in range(again["next_seq"], 5):
            await kit.send(good(seq))
        await kit.ack(4)
        await kit.bye()
        return ready["session"]
    session = run(go())
    assert_stored(api, session, [good(seq) for seq in range(5)])


@pytest.mark.parametrize("whose", ["unknown", "other-patient", "other-sensors"])
def test_resuming_a_stream_that_is_not_yours_or_not_there_is_refused(srv, api, token, whose):
    async def go():
        if whose == "unknown":
            stream, words, hello = "0" * 24, ("no stream", "0" * 24), {}
        else:
            other = token
            if whose == "other-patient":
                other = new_token(api, "Someone else")[1]["token"]
            first = await Kit.open(srv, other)
            stream = (await first.hello(sensors=["forearm", "hand"]))["stream"]
            first.drop()
            if whose == "other-patient":
                words, hello = ("no stream", stream), {"sensors": ["forearm", "hand"]}
            else:
                words, hello = ("same side and sensors",), {}
        kit = await Kit.open(srv, token)
        await kit.send({**HELLO, **hello, "resume": stream})
        error = await kit.error()
        assert error["seq"] is None
        words_in(error["reason"], *words)
        assert await kit.closed() == 4400
    run(go())


# -- the server killed -------------------------------------------------------------------

@pytest.fixture
def killable(srv):
    """The module's server, for a test that kills it: running again afterwards."""
    try:
        yield srv
    finally:
        if srv.process is None or srv.process.poll() is not None:
            srv.start()


def test_a_server_killed_mid_stream_keeps_all_it_acked_and_the_kit_resumes(killable, api):
    """SIGKILL while a kit streams: everything acked is stored, the session is
    interrupted; after a restart the kit resumes at the first unstored seq and the
    recording ends exactly as sent, without a duplicate."""
    device = new_token(api, "Killed")[1]
    sent = [good(seq) for seq in range(300)]

    async def stream():
        kit = await Kit.open(killable, device["token"])
        ready = await kit.hello()

        async def send():
            for m in sent:
                await kit.send(m)
                await asyncio.sleep(0.003)

        sender = asyncio.create_task(send())
        await kit.ack(60, timeout=20)
        await asyncio.to_thread(killable.kill)
        with pytest.raises((ConnectionClosed, TimeoutError)):
            while True:
                await kit.raw(timeout=5)
        sender.cancel()
        await asyncio.gather(sender, return_exceptions=True)
        assert kit.acked < len(sent) - 1, "the kill came too late to test anything"
        return ready, kit.acked

    ready, acked = run(stream())
    killable.start()
    session = api.session(ready["session"])
    assert session["status"] == "interrupted"
    stored = session["samples"] // ROWS
    assert session["samples"] == stored * ROWS and stored > acked
    assert_stored(api, ready["session"], sent[:stored])

    async def resume():
        kit = await Kit.open(killable, device["token"])
        again = await kit.hello(resume=ready["stream"])
        assert again == {"type": "ready", "stream": ready["stream"],
                         "session": ready["session"], "next_seq": stored}
        for m in sent[acked + 1:]:  # all that was never acked, stored or not
            await kit.send(m)
        await kit.ack(len(sent) - 1, timeout=20)
        await kit.bye()
    run(resume())
    assert_stored(api, ready["session"], sent)
    assert api.session(ready["session"])["status"] == "closed"


# -- one patient's bad stream beside another's ---------------------------------------------

def test_a_bad_stream_does_not_disturb_another_patients_stream(srv, api):
    """While one patient's kit floods refusals, sends a message over 1 MiB and breaks the
    protocol again and again, another patient's kit streams a whole session: nothing lost,
    nothing refused, no reconnect, and its acks keep coming at least once a second."""
    recording = simulate(SimulationConfig(repetitions=1, rate_hz=50, seed=3)).recording
    steady_device = new_token(api, "Steady")[1]
    noisy_device = new_token(api, "Noisy")[1]
    ack_times: list[float] = []

    async def steady(finished: asyncio.Event):
        kit = KitEmulator(recording, srv.ws_url, steady_device["token"], speed=6,
                          rows_per_message=5,
                          on_ack=lambda seq, stats: ack_times.append(time.monotonic()))
        try:
            return await kit.run()
        finally:
            finished.set()

    async def noisy(finished: asyncio.Event) -> dict[int | str | None, int]:
        closes: dict[int | str | None, int] = {}
        rounds = 0
        while not finished.is_set():
            kit = await Kit.open(srv, noisy_device["token"])
            rounds += 1
            try:
                await kit.send(HELLO)
                answer = await kit.raw()
                if answer["type"] == "error":  # the dropped streams not yet seen to end
                    assert "streams open" in answer["reason"], answer  # (a loaded machine):
                    assert await kit.closed(timeout=10) == 4429  # a fifth is refused,
                    closes["streams open"] = closes.get("streams open", 0) + 1  # apart
                    continue
                assert answer["type"] == "ready", answer
                if rounds % 3 == 1:  # a flood of refusals
                    for seq in range(60):
                        await kit.send({**good(seq), "sensor": "foot"})
                elif rounds % 3 == 2:  # a message over 1 MiB
                    await kit.send(good(0))
                    await kit.send_too_big(padded(good(1), MiB + 100))
                else:  # a second hello, junk, a gap, then gone without a word
                    await kit.send(HELLO)
                    await kit.send(b"\x00\x01 binary junk")
                    await kit.send(good(9))
                    await asyncio.sleep(0.05)
                    kit.drop()
                    continue
            except ConnectionClosed:
                # Closed while sending: on a loaded machine the server closes on the
                # errors before the last one is sent.
                pass
            code = await kit.closed(timeout=10)
            closes[code] = closes.get(code, 0) + 1
        return closes

    async def both():
        finished = asyncio.Event()
        return await asyncio.gather(steady(finished), noisy(finished))

    stats, closes = run(both(), timeout=60)
    assert closes.get(4429, 0) >= 1 and closes.get(1009, 0) >= 1, closes
    assert stats.acked == stats.total and stats.refused == 0 and not stats.errors
    assert stats.reconnects == 0
    assert np.diff(ack_times).max() < 1.0
    assert stats.latency_percentiles((99,))[99] < 1.0
    stored = export(api, stats.session)
    for name, s in recording.sensors.items():
        got = stored.sensors[name]
        for column in ("t", "acc", "gyr", "mag"):
            assert np.array_equal(getattr(got, column).view(np.int64),
                                  getattr(s, column).view(np.int64)), (name, column)
    assert stored.calibration == recording.calibration
    session = api.settled(stats.session)  # (the emulator closes right after its bye)
    assert session["samples"] == sum(len(s) for s in recording.sensors.values())
    assert session["status"] == "closed"
