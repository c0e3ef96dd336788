"""The sensor-kit emulator's messages and bookkeeping (spec/ingest.md), without a server."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from armtrack.estimator.errors import InvalidArgument
from armtrack.estimator.recording import Mark, Pose, Recording, SensorStream
from armtrack.server.cli import main
from armtrack.server.emulator import (
    KitEmulator,
    KitError,
    MessagePlan,
    Outbox,
    encode,
    hello_message,
)

URL = "ws://127.0.0.1:1/ws/ingest"


def _stream(t, rng, nine_axis=True) -> SensorStream:
    n = len(t)
    return SensorStream(t, rng.normal(0, 3, (n, 3)), rng.normal(0, 1, (n, 3)),
                        rng.normal(0, 40, (n, 3)) if nine_axis else None)


def _recording(nine_axis=True, marks=True) -> Recording:
    """Upper arm at 100 Hz from 0, forearm at 40 Hz from 0.013 s, 1.5 s long."""
    rng = np.random.default_rng(7)
    return Recording(
        side="left",
        sensors={"forearm": _stream(0.013 + np.arange(60) / 40, rng, nine_axis),
                 "upper_arm": _stream(np.arange(150) / 100, rng, nine_axis)},
        height_m=1.7,
        calibration=(Pose("npose", 0.0, 0.3), Pose("tpose", 0.5, 0.8)) if marks else (),
        marks=(Mark(0.9, "exercise:elbow_flexion"), Mark(1.2, "end:exercise:elbow_flexion"))
        if marks else (),
        rate_hz=100.0,
    )


def _messages(plan: MessagePlan) -> list[dict]:
    """Every message as the server would parse it."""
    return [json.loads(plan.encode(seq)) for seq in range(len(plan))]


def _send_time(message: dict) -> float:
    return message["t"] if message["type"] == "mark" else message["rows"][-1][0]


def test_hello_says_what_the_kit_is():
    recording = _recording()
    assert hello_message(recording, "kit-17") == {
        "type": "hello", "protocol": 1, "device": "kit-17", "side": "left",
        "sensors": ["upper_arm", "forearm"],  # the recording's (SENSOR_NAMES) order
        "rate_hz": 100.0, "nine_axis": True, "resume": None}
    hello = hello_message(_recording(nine_axis=False), "kit-17", resume="abc", rate_hz=50)
    assert (hello["nine_axis"], hello["resume"], hello["rate_hz"]) == (False, "abc", 50.0)


def test_hello_rate_from_the_samples_without_rate_hz():
    rng = np.random.default_rng(1)
    recording = Recording(side="right", sensors={"hand": _stream(np.arange(20) / 50, rng)},
                          height_m=1.8)
    assert hello_message(recording, "k")["rate_hz"] == pytest.approx(50.0)


def test_seq_counts_samples_and_marks_together():
    messages = _messages(MessagePlan(_recording(), rows_per_message=4))
    assert [m["seq"] for m in messages] == list(range(len(messages)))
    assert {m["type"] for m in messages} == {"samples", "mark"}
    marks = [m for m in messages if m["type"] == "mark"]
    assert [(m["t"], m["label"]) for m in marks] == [
        (0.0, "npose"), (0.3, "end:npose"), (0.5, "tpose"), (0.8, "end:tpose"),
        (0.9, "exercise:elbow_flexion"), (1.2, "end:exercise:elbow_flexion")]


@pytest.mark.parametrize("rows_per_message", [1, 4, 10, 1000])
def test_rows_are_chunked_per_sensor_and_complete(rows_per_message):
    recording = _recording()
    plan = MessagePlan(recording, rows_per_message)
    messages = _messages(plan)
    assert plan.total_rows == 210
    for name, stream in recording.sensors.items():
        mine = [m for m in messages if m["type"] == "samples" and m["sensor"] == name]
        sizes = [len(m["rows"]) for m in mine]
        assert all(s == rows_per_message for s in sizes[:-1])
        assert 1 <= sizes[-1] <= rows_per_message
        assert [plan.rows(m["seq"]) for m in mine] == sizes
        rows = np.array([r for m in mine for r in m["rows"]])
        expected = np.hstack([stream.t[:, None], stream.acc, stream.gyr, stream.mag])
        assert np.array_equal(rows, expected)


def test_sensors_interleave_and_marks_go_when_their_time_passes():
    plan = MessagePlan(_recording(), rows_per_message=4)
    messages = _messages(plan)
    times = [_send_time(m) for m in messages]
    assert times == sorted(times)
    assert np.array_equal(plan.times, times)
    # both sensors are spread over the whole stream, not one after the other
    first = {m["sensor"]: m["seq"] for m in reversed(messages) if m["type"] == "samples"}
    assert max(first.values()) < 5
    for mark in (m for m in messages if m["type"] == "mark"):
        before = [_send_time(m) for m in messages[:mark["seq"]] if m["type"] == "samples"]
        after = [_send_time(m) for m in messages[mark["seq"]:] if m["type"] == "samples"]
        assert all(t <= mark["t"] for t in before)
        assert all(t > mark["t"] for t in after)
    assert plan.start_time == 0.0


def test_six_axis_magnetometer_is_null():
    plan = MessagePlan(_recording(nine_axis=False), rows_per_message=7)
    text = plan.encode(1)
    assert '"samples"' in text and "NaN" not in text and "null,null,null]" in text
    for message in _messages(plan):
        if message["type"] == "samples":
            assert all(len(r) == 10 and r[7:] == [None, None, None] for r in message["rows"])
            assert all(isinstance(v, float) for r in message["rows"] for v in r[:7])


def test_floats_read_back_as_the_same_float64():
    rng = np.random.default_rng(3)
    bits = rng.integers(0, 2**63, size=(400, 10), dtype=np.int64)
    values = bits.view(np.float64)
    values = values[np.isfinite(values).all(axis=1)][:200]
    values[:, 0] = np.sort(rng.uniform(0, 10, len(values)))
    values[0, 1:] = [0.1, -0.0, 5e-324, 1.7976931348623157e308, 1 / 3, 9.81, 2.0**-1074,
                     123456789.123456789, -1e-300]
    recording = Recording(side="right", height_m=1.8, sensors={"hand": SensorStream(
        values[:, 0], values[:, 1:4], values[:, 4:7], values[:, 7:10])})
    plan = MessagePlan(recording, rows_per_message=1000)
    back = np.array(json.loads(plan.encode(0))["rows"], dtype=np.float64)
    assert np.array_equal(back.view(np.int64), values.view(np.int64))  # bit for bit, -0.0 too


def test_non_finite_numbers_and_bad_settings_are_refused():
    rng = np.random.default_rng(5)
    acc = rng.normal(size=(5, 3))
    acc[3, 1] = math.nan
    bad = Recording(side="right", height_m=1.8, sensors={"hand": SensorStream(
        np.arange(5.0), acc, np.zeros((5, 3)), np.zeros((5, 3)))})
    with pytest.raises(InvalidArgument, match="hand row 3"):
        MessagePlan(bad)
    with pytest.raises(ValueError):
        encode({"t": math.inf})
    for rows in (0, 1001):
        with pytest.raises(InvalidArgument, match="rows_per_message"):
            MessagePlan(_recording(), rows)
    mixed = Recording(side="right", height_m=1.8, sensors={
        "hand": _stream(np.arange(3.0), rng), "forearm": _stream(np.arange(3.0), rng, False)})
    with pytest.raises(InvalidArgument, match="all 9-axis or all 6-axis"):
        MessagePlan(mixed)


def test_emulator_settings_are_checked_before_connecting():
    kit = KitEmulator(_recording(), URL, "token", rows_per_message=5, speed=10)
    assert kit.stats.total == len(kit.plan) and kit.stream is None and not kit.done
    assert kit.hello["device"] == "armtrack-emulator"
    assert kit.due(0) == -math.inf  # no clock before ready
    with pytest.raises(InvalidArgument, match="ws:// or wss://"):
        KitEmulator(_recording(), "http://127.0.0.1/ws/ingest", "token")
    with pytest.raises(InvalidArgument, match="speed"):
        KitEmulator(_recording(), URL, "token", speed=-1)


def _outbox(n: int) -> Outbox:
    outbox = Outbox()
    for seq in range(n):
        outbox.sent(seq, f'{{"seq":{seq}}}', rows=10, now=float(seq))
    return outbox


def test_ack_drops_everything_up_to_its_seq():
    outbox = _outbox(6)
    assert (outbox.stats.sent, outbox.stats.rows_sent, len(outbox)) == (6, 60, 6)
    assert outbox.ack(2, now=10.0) == 3
    assert list(outbox.pending) == [3, 4, 5]
    assert outbox.stats.latencies_s == [10.0, 9.0, 8.0]
    assert outbox.ack(1, now=11.0) == 0  # a repeated, older ack changes nothing
    assert outbox.ack(5, now=12.0) == 3 and not outbox.pending
    assert (outbox.stats.acked, outbox.stats.rows_acked) == (6, 60)
    with pytest.raises(KitError, match="acked seq 6"):
        outbox.ack(6, now=13.0)
    with pytest.raises(ValueError, match="in order"):
        outbox.sent(9, "{}", 0, 0.0)


def test_error_drops_the_message_it_names():
    outbox = _outbox(4)
    assert outbox.refuse(2, "acc out of range")
    assert list(outbox.pending) == [0, 1, 3]
    assert not outbox.refuse(2, "again")  # already dropped: only recorded
    assert not outbox.refuse(None, "something without a seq")
    assert outbox.stats.refused == 1
    assert [e["seq"] for e in outbox.stats.errors] == [2, 2, None]
    outbox.ack(3, now=5.0)
    assert outbox.stats.acked == 3 and not outbox.pending


def test_resume_resends_from_the_servers_next_seq():
    outbox = _outbox(8)
    outbox.ack(1, now=8.0)
    # the server stored 2..3 without acking them yet: next_seq 4
    assert outbox.resume(4) == [4, 5, 6, 7]
    assert outbox.stats.acked == 4 and len(outbox.stats.latencies_s) == 2
    outbox.resent(4, now=20.0)
    assert outbox.stats.resent == 1 and outbox.pending[4].sent_at == 20.0
    outbox.ack(4, now=21.0)
    assert outbox.stats.latencies_s[-1] == 1.0
    # 5 refused, which used up its number: the server goes on at 6
    outbox.refuse(5, "bad")
    assert outbox.resume(6) == [6, 7]
    outbox.ack(7, now=22.0)
    assert outbox.stats.latencies_s[-2:] == [16.0, 15.0]
    assert (outbox.stats.acked, outbox.stats.refused) == (7, 1)
    assert outbox.resume(8) == []


def test_resume_refuses_a_server_that_forgot_or_invented_messages():
    outbox = _outbox(5)
    outbox.ack(2, now=6.0)
    with pytest.raises(KitError, match="already handled"):
        outbox.resume(2)
    with pytest.raises(KitError, match="beyond"):
        outbox.resume(6)
    assert outbox.resume(5) == [] and outbox.stats.acked == 5


def test_stream_command_needs_a_token(monkeypatch, capsys):
    monkeypatch.delenv("ARMTRACK_TOKEN", raising=False)
    assert main(["stream", "--exercise", "still", "--url", URL]) == 2
    assert "device token" in capsys.readouterr().err
