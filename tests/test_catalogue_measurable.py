"""Only what a kit measures is offered (issue 22, the catalogue and the phone kit): the
catalogue put "Turn the arm out and in" (shoulder rotation) on a forearm phone, which
does not measure it (``estimator/arm/coverage.py``: the shoulder's angles need the upper
arm's sensor). Now each exercise names the segment that measures its angle; the kit's
device-today read says for each exercise which phone segments measure it and, for the
others, why not in a sentence; the program editor's catalogue, asked for a patient, says
whether the patient's kits (the sensors their sessions streamed with) measure each one.
With a real server, a real WebSocket kit (the emulator) and a real database file."""

from __future__ import annotations

import asyncio

import httpx
import pytest
from armtrack.estimator.arm.coverage import ANGLES_OF_SENSOR, measured_angles
from armtrack.estimator.simulation import SimulationConfig, simulate
from armtrack.server.emulator import KitEmulator
from armtrack.server.programs import catalogue
from server_support import ServerProcess


def test_each_exercise_names_the_segment_whose_sensor_measures_its_angle():
    wrong = {e.name: (e.sensor, e.angle) for e in catalogue.CATALOGUE.values()
             if e.angle not in ANGLES_OF_SENSOR.get(e.sensor, ())}
    assert not wrong, f"an exercise names a sensor that does not measure its angle: {wrong}"


def test_what_a_phone_measures_where_it_is_worn_and_why_not():
    forearm = [e.name for e in catalogue.CATALOGUE.values()
               if catalogue.measurable(e, ("forearm",))]
    upper_arm = [e.name for e in catalogue.CATALOGUE.values()
                 if catalogue.measurable(e, ("upper_arm",))]
    assert forearm == ["elbow_flexion", "pronation"]
    assert upper_arm == ["shoulder_flexion", "shoulder_abduction", "shoulder_rotation",
                         "reach"]
    assert set(measured_angles(("forearm",))) == {"elbow_flexion", "forearm_pronation"}
    rotation = catalogue.CATALOGUE["shoulder_rotation"]
    assert catalogue.phone_segments(rotation) == ["upper_arm"]
    assert catalogue.why_not(rotation, ("forearm",)) == (
        "Turn the arm out and in: counted on the shoulder's rotation, which needs a sensor "
        "on the upper arm; a sensor on the forearm alone does not measure it.")
    wrist = catalogue.CATALOGUE["wrist_flexion"]
    assert catalogue.phone_segments(wrist) == []  # no single phone: a hand sensor
    assert "needs a sensor on the hand" in catalogue.why_not(wrist, ("forearm", "upper_arm"))
    assert "sensors on the forearm and upper arm do not measure it" in catalogue.why_not(
        wrist, ("forearm", "upper_arm"))


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    process = ServerProcess(tmp_path_factory.mktemp("measurable"))
    process.create_user("alice")
    process.create_user("bob")
    process.start(timeout=180)
    yield process
    process.stop()


def _stream_forearm_phone(server, token: str) -> int:
    sim = simulate(SimulationConfig(exercise="elbow_flexion", sensors=("forearm",),
                                    rate_hz=60.0, nine_axis=False, seed=2, repetitions=2))
    kit = KitEmulator(sim.recording, server.ws_url, token, speed=0, rows_per_message=60)
    return asyncio.run(kit.run()).session


def test_the_editor_and_the_kit_offer_only_what_the_kit_measures(server):
    alice = server.client("alice")
    patient = alice.patient("Forearm phone")
    device = alice.device(patient["id"], "Ada's phone")
    url = f"/api/programs/catalogue?patient_id={patient['id']}"

    # no kit has streamed yet: nothing is known, every exercise offered
    before = alice.http.get(url).json()
    assert {e["measurable"] for e in before} == {None}
    session = _stream_forearm_phone(server, device["token"])
    alice.wait_processed(session, timeout=120)

    answer = alice.http.get(url)
    assert answer.status_code == 200, answer.text
    by_name = {e["name"]: e for e in answer.json()}
    offered = [n for n, e in by_name.items() if e["measurable"]]
    assert offered == ["elbow_flexion", "pronation"]
    assert by_name["shoulder_rotation"]["measurable"] is False
    assert by_name["shoulder_rotation"]["why_not"] == (
        "Turn the arm out and in: counted on the shoulder's rotation, which needs a sensor "
        "on the upper arm; a sensor on the forearm alone does not measure it.")
    assert "needs a sensor on the hand" in by_name["wrist_flexion"]["why_not"]
    assert by_name["elbow_flexion"]["why_not"] is None
    # without a patient: the catalogue as before; another therapist's patient: 404
    plain = alice.http.get("/api/programs/catalogue").json()
    assert {e["measurable"] for e in plain} == {None}
    assert server.client("bob").http.get(url).status_code == 404

    # the kit's list: a program with the shoulder's rotation and the elbow
    made = alice.http.post(f"/api/patients/{patient['id']}/programs", json={
        "name": "Shoulder and elbow", "start_date": "2020-01-01", "exercises": [
            {"exercise": "shoulder_rotation", "sets": 1, "repetitions": 8, "days_per_week": 3},
            {"exercise": "elbow_flexion", "sets": 2, "repetitions": 10, "days_per_week": 5}]})
    assert made.status_code == 201, made.text
    today = httpx.get(server.url + "/api/device/today",
                      headers={"Authorization": f"Bearer {device['token']}"}).json()
    assert today["source"] == "program" and today["program"]["name"] == "Shoulder and elbow"
    rotation, elbow = today["exercises"]
    assert (rotation["name"], rotation["sensor"], rotation["measured_by"]) == (
        "shoulder_rotation", "upper_arm", ["upper_arm"])
    assert rotation["not_measured"] == {"forearm": by_name["shoulder_rotation"]["why_not"]}
    assert (elbow["measured_by"], elbow["not_measured"]) == (["forearm"], {
        "upper_arm": "Bend the elbow: counted on the elbow's bend, which needs a sensor on "
                     "the forearm; a sensor on the upper arm alone does not measure it."})
    assert (elbow["sets"], elbow["repetitions"], elbow["target"]["from"]) == (2, 10,
                                                                              "catalogue")
