"""The phone kit's server side (issue 19): the device-scoped read of today's exercises,
the ``feedback`` extension of the ingest socket and the angles a session measures — with
a real server, a real WebSocket client and a simulated phone on the forearm."""

from __future__ import annotations

import asyncio
import json
import time
from dataclasses import replace

import httpx
import pytest
from armtrack.estimator.arm.coverage import assumptions, measured_angles
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.recording import Mark
from armtrack.estimator.simulation import ImuErrors, SimulationConfig, simulate
from armtrack.server.emulator import MessagePlan, hello_message
from armtrack.server.ingest.feedback import Band, RepetitionCounter
from armtrack.server.programs.catalogue import CATALOGUE, DEFAULT_SESSION
from server_support import ServerProcess
from websockets.asyncio.client import connect

PUBLIC_URL = "https://rehab.example.org"


@pytest.fixture(scope="module")
def module_server(tmp_path_factory):
    """One server for the module, therapist ``alice`` (a patient start-up allowance: the
    test machine is shared)."""
    process = ServerProcess(tmp_path_factory.mktemp("server"),
                            {"ARMTRACK_PUBLIC_URL": PUBLIC_URL})
    process.create_user("alice")
    process.start(timeout=180)
    yield process
    process.stop()


def _phone_recording(exercise: str, sensor: str, seed: int = 1):
    """A phone-like simulated session (6-axis, 60 Hz) with its exercise marked."""
    config = SimulationConfig(exercise=exercise, sensors=(sensor,), rate_hz=60.0,
                              nine_axis=False, seed=seed, jitter_s=0.003,
                              errors=ImuErrors(gyro_noise=0.01, acc_noise=0.1),
                              gyro_bias_max=0.02, mount_axial_deg=30.0)
    sim = simulate(config)
    end = float(sim.recording.sensors[sensor].t[-1]) - 0.5
    marks = (Mark(10.5, f"exercise:{exercise}"), Mark(end, f"end:exercise:{exercise}"))
    return replace(sim.recording, marks=marks), sim


def test_catalogue_names_angles_the_kinematics_contract_knows():
    from armtrack.estimator.arm.joints import REPORTED_ANGLES
    for entry in CATALOGUE.values():
        assert entry.angle in REPORTED_ANGLES
        assert entry.rest_deg < entry.target_deg
    # what a single phone guides by default, it measures
    for sensor, names in DEFAULT_SESSION.items():
        for name in names:
            assert CATALOGUE[name].sensor == sensor
            assert CATALOGUE[name].angle in measured_angles((sensor,)), name


def test_coverage_of_single_sensor_kits():
    assert measured_angles(("forearm",)) == ("elbow_flexion", "forearm_pronation")
    assert set(assumptions(("forearm",))) == {"trunk_still", "upper_arm_still"}
    assert measured_angles(("upper_arm",)) == ("shoulder_flexion", "shoulder_abduction",
                                               "shoulder_rotation", "shoulder_elevation")
    assert set(assumptions(("upper_arm",))) == {"trunk_still"}
    assert set(assumptions(("trunk", "upper_arm", "forearm"))) == set()


def test_the_live_counter_is_the_reports_rule_counted_once_back_at_rest():
    """Issue 22: the kit's counter is the report's rule (``count_repetitions`` of
    ``detect_repetitions``' excursions), applied as the estimates come: pronation,
    supination, a pronation that turns back without reaching rest (one turn), a wobble
    under 10° (none), a supination — each turn counted once back at rest; palm down and
    up is one repetition (docs/programs.md), so 4 turns are 2, the count going up with
    the first turn of each and ``unpaired`` saying a turn the other way is still due."""
    import numpy as np
    from armtrack.estimator.metrics import count_repetitions, detect_repetitions

    def excursion(peaks_deg, seconds=4.0):  # rest → peaks → rest, smooth, at 20 Hz
        knots = np.array([0.0, *peaks_deg, 0.0])
        x = np.linspace(0, len(knots) - 1, int(seconds * 20))
        i = np.minimum(x.astype(int), len(knots) - 2)
        f = 0.5 - 0.5 * np.cos(np.pi * (x - i))
        return np.concatenate([knots[i] + (knots[i + 1] - knots[i]) * f, np.zeros(30)])

    deg = np.concatenate([np.zeros(40), excursion([70]), excursion([-65]),
                          excursion([70, 35, 70], 6.0), excursion([6]), excursion([-70])])
    t = 0.05 * np.arange(deg.size)
    counter = RepetitionCounter(Band("forearm_pronation", -70.0, 70.0),
                                SegmentLengths.from_height(1.75))
    shown, unpaired = [], []
    for a in range(0, deg.size, 7):  # poses of 7 estimates
        counter.add(t[a:a + 7], deg[a:a + 7])
        shown.append(counter.recount())
        unpaired.append(counter.unpaired)
        reps = detect_repetitions(np.deg2rad(deg[:a + 7]), t[:a + 7])
        assert shown[-1] == count_repetitions(reps, True)  # the report's count so far
    peak = int(np.argmax(deg[:120]))  # at the first turn's peak: not yet counted
    assert shown[peak // 7] == 0
    turns = detect_repetitions(np.deg2rad(deg), t)
    print(f"turns {[r.direction for r in turns]}: counts shown {sorted(set(shown))}, "
          f"unpaired {unpaired[-1]}")
    assert len(turns) == 4 and shown[-1] == 2 == count_repetitions(turns, True)
    assert shown == sorted(shown)
    assert set(unpaired) == {0, 1} and unpaired[-1] == 0


def test_device_today_default_then_the_therapists_target(module_server):
    api = module_server.client("alice")
    patient = api.patient("Phone today", side="left")
    device = api.device(patient["id"], "phone")
    read = httpx.get(module_server.url + "/api/device/today",
                     headers={"Authorization": f"Bearer {device['token']}"})
    assert read.status_code == 200
    body = read.json()
    assert body["version"] == 1 and body["source"] == "default" and body["side"] == "left"
    names = [e["name"] for e in body["exercises"]]
    assert names == [*DEFAULT_SESSION["forearm"], *DEFAULT_SESSION["upper_arm"]]
    elbow = body["exercises"][0]
    assert elbow["target"] == {"min_deg": 0.0, "max_deg": 120.0, "from": "default"}
    assert elbow["sensor"] == "forearm" and elbow["instruction"] and elbow["picture"]
    assert read.headers["cache-control"] == "no-store"

    api.http.put(f"/api/patients/{patient['id']}/targets/elbow_flexion",
                 json={"min_deg": 10, "max_deg": 95}).raise_for_status()
    body = httpx.get(module_server.url + "/api/device/today",
                     headers={"Authorization": f"Bearer {device['token']}"}).json()
    assert body["exercises"][0]["target"] == {"min_deg": 10.0, "max_deg": 95.0,
                                              "from": "patient"}

    # no token, a therapist's token, a revoked device token: 401, naming what to do
    assert httpx.get(module_server.url + "/api/device/today").status_code == 401
    as_therapist = httpx.get(module_server.url + "/api/device/today",
                             headers={"Authorization": f"Bearer {api.token}"})
    assert as_therapist.status_code == 401
    api.http.delete(f"/api/devices/{device['id']}").raise_for_status()
    revoked = httpx.get(module_server.url + "/api/device/today",
                        headers={"Authorization": f"Bearer {device['token']}"})
    assert revoked.status_code == 401 and "revoked" in revoked.json()["detail"]


def test_a_hello_with_a_bad_extensions_list_is_refused(module_server):
    api = module_server.client("alice")
    device = api.device(api.patient("Bad ext")["id"])

    async def hello(extensions):
        async with connect(f"{module_server.ws_url}?token={device['token']}") as ws:
            await ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "p",
                                      "side": "right", "sensors": ["forearm"],
                                      "rate_hz": 60, "nine_axis": False, "resume": None,
                                      "extensions": extensions}))
            answer = json.loads(await ws.recv())
            if answer["type"] == "ready":
                await ws.send(json.dumps({"type": "bye"}))
            return answer

    bad = asyncio.run(hello("feedback/1"))
    assert bad["type"] == "error" and "extensions" in bad["reason"]
    unknown = asyncio.run(hello(["telepathy/3"]))  # known shape, unknown name: not spoken
    assert unknown["type"] == "ready" and unknown["extensions"] == []


@pytest.mark.slow
def test_feedback_follows_a_forearm_phone_and_counts_its_repetitions(module_server):
    """A forearm phone doing 5 elbow flexions (to 120°), streamed at 2× real time: the
    server's feedback names the exercise, gives the elbow angle in the band 0–120 and
    counts the 5 repetitions; an old-style hello (no extensions) gets no feedback and the
    same ready as before. The session records the angles the kit measures."""
    api = module_server.client("alice")
    patient = api.patient("Phone feedback")
    device = api.device(patient["id"], "phone")
    recording, _ = _phone_recording("elbow_flexion", "forearm")
    plan = MessagePlan(recording, rows_per_message=6)
    repetitions = 5  # the simulation's
    speed = 2.0  # a phone streams in real time; the live poses are counted per wall second

    async def stream(extensions):
        received = []
        hello = hello_message(recording, "phone")
        if extensions is not None:
            hello["extensions"] = extensions
        async with connect(f"{module_server.ws_url}?token={device['token']}") as ws:
            await ws.send(json.dumps(hello))
            ready = json.loads(await ws.recv())

            async def reader():
                async for raw in ws:
                    received.append(json.loads(raw))

            task = asyncio.create_task(reader())
            start, origin = time.monotonic(), plan.times[0]
            for seq in range(len(plan)):
                if extensions is not None and plan.times[seq] >= 10.4 > plan.times[seq - 1]:
                    # the live estimation (its own process) may start slowly on a busy
                    # machine: the exercise begins once the first feedback is in
                    for _ in range(1200):
                        if any(m["type"] == "feedback" for m in received):
                            break
                        await asyncio.sleep(0.1)
                    start, origin = time.monotonic(), plan.times[seq]
                due = start + (plan.times[seq] - origin) / speed
                await asyncio.sleep(max(0.0, due - time.monotonic()))
                await ws.send(plan.encode(seq))
            if extensions is not None:
                # bye closes the socket, and feedback the live estimation (its own process,
                # behind the stream on a busy machine) has not sent by then is lost: the
                # kit stays until the feedback has counted the exercise's repetitions (a
                # fixed 1 s after the last message guessed it had)
                for _ in range(600):
                    if any(m["type"] == "feedback" and m["exercise"] == "elbow_flexion"
                           and m["repetitions"] >= repetitions for m in received):
                        break
                    await asyncio.sleep(0.1)
            else:
                await asyncio.sleep(1.0)  # time for a feedback that must not come
            await ws.send(json.dumps({"type": "bye"}))
            await asyncio.wait_for(task, 30)
        return ready, received

    ready, received = asyncio.run(stream(["feedback/1"]))
    assert ready["extensions"] == ["feedback/1"]
    feedback = [m for m in received if m["type"] == "feedback"]
    assert feedback, [m["type"] for m in received][:20]
    during = [m for m in feedback if m["exercise"] == "elbow_flexion"]
    assert during and during[0]["angle"] == "elbow_flexion"
    assert during[0]["target"] == [0.0, 120.0]
    assert set(during[-1]["angles_deg"]) == {"elbow_flexion", "forearm_pronation"}
    peak = max(m["angle_deg"] for m in during)
    print(f"feedback messages {len(feedback)}, peak elbow {peak:.1f}°, "
          f"repetitions {during[-1]['repetitions']}")
    assert 110 < peak < 130
    assert during[-1]["repetitions"] == repetitions
    # rate-limited to 10 a second of wall time
    span = len(plan) and (plan.times[-1] - plan.times[0]) / speed
    assert len(feedback) <= 10 * span + 5

    session = api.session(ready["session"])
    assert session["measured_angles"] == ["elbow_flexion", "forearm_pronation"]
    assert set(session["assumptions"]) == {"trunk_still", "upper_arm_still"}

    old_ready, old_received = asyncio.run(stream(None))
    assert "extensions" not in old_ready
    assert not [m for m in old_received if m["type"] == "feedback"]


def test_a_new_kit_comes_with_its_link_and_qr_code(module_server):
    """The link is ARMTRACK_PUBLIC_URL's, the token in its fragment (never sent to a
    server), and the QR code an SVG data URI of it; the token works on the stream."""
    from urllib.parse import unquote

    import segno

    api = module_server.client("alice")
    device = api.device(api.patient("QR")["id"], "phone")
    assert device["kit_url"] == f"{PUBLIC_URL}/kit#token={device['token']}"
    assert device["kit_url_secure"] is True
    assert device["kit_qr"].startswith("data:image/svg+xml")
    svg = unquote(device["kit_qr"].split(",", 1)[1])
    assert svg.startswith("<svg") and "<script" not in svg
    # the same symbol segno makes of the link (its modules, not just its looks)
    expected = segno.make(device["kit_url"], error="m", micro=False)
    assert svg == unquote(expected.svg_data_uri(scale=4, border=4).split(",", 1)[1])
    # the list of devices never shows the token or the link again
    listed = api.http.get(f"/api/patients/{device['patient_id']}/devices").json()
    assert "kit_url" not in listed[0] and "token" not in listed[0]


def test_kit_links_say_when_phones_will_not_get_sensors():
    from armtrack.server.kit.link import kit_url, secure_enough

    assert kit_url("https://a.example/", "dev_x-y") == "https://a.example/kit#token=dev_x-y"
    assert secure_enough("https://a.example") and secure_enough("http://127.0.0.1:8000")
    assert not secure_enough("http://clinic.lan:8000")


def test_a_forearm_phone_warns_when_the_upper_arm_did_not_hang_still():
    """Forearm alone: elbow flexions give no warning; the arm raised sideways (shoulder
    abduction, which the forearm-only kit assumes does not happen) does."""
    from armtrack.estimator.metrics.assumptions import assumption_warnings
    from armtrack.estimator.pipeline import estimate_recording

    def warnings(exercise):
        recording, _ = _phone_recording(exercise, "forearm")
        estimates, calibration = estimate_recording(recording)
        return assumption_warnings(estimates.t, estimates.residuals, ("forearm",),
                                   calibration.final_time_s + 2.5)

    assert warnings("elbow_flexion") == []
    raised = warnings("shoulder_abduction")
    assert len(raised) == 1 and "upper arm hangs still" in raised[0]
