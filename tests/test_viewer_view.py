"""The 3D view as the therapist meets it (issue 21): the camera frames the arm's whole
reach (the hand stays in the picture at 150° of flexion and at full abduction, whatever
the body height), the control panel starts minimised, its title names the stream's state
(not viser's own socket: never "Connected" while the kit's connection is lost), in-scene
labels and the replay's marks are in words.

The scene is driven in-process through a real viser server and a real WebSocket client
speaking viser's protocol (``test_viewer.watch``); the stream's state and the replay come
from a real armtrack server fed by the kit emulator."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
import viser
from armtrack.estimator.body import SegmentLengths
from armtrack.server.emulator import KitEmulator
from armtrack.web.viewer.rom import LABEL_SCALE, VISER_LABEL_PX
from armtrack.web.viewer.view import CAMERA_FOV_DEG, ClientView, framing_distance, reach_m
from test_live_motion import short_exercise
from test_viewer import grant, names, pose_from_angles, watch, ws_url

ELBOW_LABEL, FACING_LABEL = "/arm/thorax/rom/elbow_flexion/label", "/stance/facing/label"
#: The browser's view in ``test_viewer.CAMERA``: 800 × 600 px.
ASPECT = 800 / 600
#: Poses at the edge of the arm's reach.
REACHES = {
    "150° flexion": {"shoulder_flexion": 150.0},
    "full abduction": {"shoulder_abduction": 180.0},
    "90° abduction": {"shoulder_abduction": 90.0},
    "60° extension": {"shoulder_flexion": -60.0},
    "elbow bent up": {"shoulder_flexion": 170.0, "elbow_flexion": 30.0},
}


def in_view(camera, point: np.ndarray, aspect: float) -> tuple[float, float]:
    """Where ``point`` [m, world] falls in the camera's picture: normalised device
    coordinates (x, y), both in [-1, 1] when it is in the picture."""
    position, target = np.asarray(camera.position), np.asarray(camera.look_at)
    forward = (target - position) / np.linalg.norm(target - position)
    right = np.cross(forward, np.asarray(camera.up_direction, dtype=float))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    v = point - position
    depth = v @ forward
    assert depth > 0, "behind the camera"
    half = np.tan(camera.fov / 2)
    return float(v @ right / (depth * half * aspect)), float(v @ up / (depth * half))


def test_the_framing_distance_fits_the_reach_sphere():
    fov = np.radians(45.0)
    d = framing_distance(0.77, fov, 4 / 3)
    # the sphere's silhouette subtends the vertical field (the narrower) with the margin
    assert np.degrees(2 * np.arcsin(0.77 / d)) == pytest.approx(45.0 / 1.08, rel=0.02)
    # a portrait view: the horizontal field decides, so the camera goes further back
    assert framing_distance(0.77, fov, 0.5) > d


@pytest.mark.parametrize("height_m", [1.50, 1.75, 2.00])
def test_the_hand_stays_in_the_picture_at_the_edge_of_its_reach(height_m):
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    views: list[ClientView] = []
    server.on_client_connect(lambda client: views.append(
        ClientView(client, heading="Ada · live", height_m=height_m, side="right")))
    lengths = SegmentLengths.from_height(height_m)
    try:
        async def scenario():
            viewer = asyncio.create_task(watch(f"ws://127.0.0.1:{server.get_port()}/",
                                               seconds=2.5))
            while not views:
                await asyncio.sleep(0.05)
            await asyncio.sleep(0.3)  # the browser's camera message is in
            first = pose_from_angles({}, lengths, "right")
            await asyncio.to_thread(views[0].show, first)  # places the camera
            return await viewer

        messages = asyncio.run(scenario())
    finally:
        server.stop()
    view = views[0]
    camera = view.client.camera
    assert camera.fov == pytest.approx(np.radians(CAMERA_FOV_DEG))
    sent = [m for m in messages if m["type"] == "SetCameraPositionMessage"]
    assert sent and np.allclose(sent[-1]["position"], camera.position)  # the browser's too
    distance = np.linalg.norm(np.asarray(camera.position) - np.asarray(camera.look_at))
    assert distance == pytest.approx(framing_distance(reach_m(lengths),
                                                      np.radians(CAMERA_FOV_DEG), ASPECT))
    for name, angles in REACHES.items():
        pose = pose_from_angles(angles, lengths, "right")
        notch = view.arm.notch_world(pose)
        R = pose.R_world["thorax"]
        for point in ("hand", "wrist", "elbow"):
            x, y = in_view(camera, notch + R @ pose.p_thorax[point], ASPECT)
            print(f"{height_m} m, {name}: {point} at ({x:+.2f}, {y:+.2f})")
            assert abs(x) < 1 and abs(y) < 1, f"the {point} leaves the picture at {name}"
    # and the head is in the picture too, so the arm is seen against the body
    head = view.arm.notch_world(first := pose_from_angles({}, lengths, "right")) \
        + first.R_world["thorax"] @ np.array([-0.02, 0.118, 0.0]) * height_m
    assert all(abs(c) < 1 for c in in_view(camera, head, ASPECT))


def test_the_panel_starts_minimised_and_titled_by_what_it_holds():
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    views: list[ClientView] = []
    server.on_client_connect(lambda client: views.append(ClientView(
        client, heading="Ada · session 3", height_m=1.7, side="left", live=False)))
    try:
        messages = asyncio.run(watch(f"ws://127.0.0.1:{server.get_port()}/", seconds=1.5))
    finally:
        server.stop()
    assert any(m["type"] == "GuiSetPanelCollapsedMessage" and m["collapsed"]
               for m in messages), "the replay's panel did not start minimised"
    labels = [m["label"] for m in messages if m["type"] == "SetGuiPanelLabelMessage"
              and m["label"] is not None]  # (viser resets it to None as a client connects)
    assert labels == ["Replay controls"]
    # in-scene labels are legible and run away from the body (left arm: to the right)
    created = {m["name"]: m for m in messages if m["type"] == "LabelMessage"}
    elbow = created["/arm/thorax/rom/elbow_flexion/label"]["props"]
    assert elbow["font_screen_scale"] >= 1.2 and elbow["anchor"] == "center-left"
    assert elbow["text"] == "Elbow flexion"


# ---------------------------------------------------------------- a real server

def test_a_phone_sized_view_gets_labels_that_read_as_large(module_server):
    """A page that shows the view scaled down (a phone: 340 px of 600, 0.57) says so with
    its request; the server sizes that viewer's angle labels to read at least 12 px on its
    screen (the page's smallest print; they read 8.2 px before), "facing" as on a laptop;
    a view shown whole keeps its labels as they were; a scale out of range is refused,
    naming it."""
    api = module_server.client("alice")
    patient = api.patient("Phone View")

    def label_px(display_scale: float | None) -> dict[str, float]:
        body = {"patient_id": patient["id"]}
        if display_scale is not None:
            body["display_scale"] = display_scale
        answer = api.http.post("/api/viewer", json=body)
        assert answer.status_code == 200, answer.text
        messages = asyncio.run(watch(ws_url(module_server, answer.json()["url"]),
                                     until=lambda ms: ELBOW_LABEL in names(ms), seconds=15))
        shown = display_scale or 1.0
        return {m["name"]: m["props"]["font_screen_scale"] * VISER_LABEL_PX * shown
                for m in messages if m["type"] == "LabelMessage"}

    phone, laptop, unsaid = label_px(0.57), label_px(1.0), label_px(None)
    print(f"on screen [px]: elbow label at 0.57 {phone[ELBOW_LABEL]:.1f} "
          f"(at 1 {laptop[ELBOW_LABEL]:.1f}); facing at 0.57 {phone[FACING_LABEL]:.1f}")
    angles = [px for name, px in phone.items() if name != FACING_LABEL]
    assert len(angles) == 7 and min(angles) >= 12.0 - 1e-9, phone
    assert phone[FACING_LABEL] >= laptop[FACING_LABEL] - 1e-9  # as large as on a laptop
    assert laptop[ELBOW_LABEL] == unsaid[ELBOW_LABEL] == LABEL_SCALE * VISER_LABEL_PX
    assert laptop[FACING_LABEL] == unsaid[FACING_LABEL] == 0.7 * VISER_LABEL_PX
    for wrong in (0.0, 0.1, 1.5, "big"):
        answer = api.http.post("/api/viewer", json={"patient_id": patient["id"],
                                                    "display_scale": wrong})
        assert answer.status_code == 422 and "display_scale" in answer.text, answer.text


def _labels(messages: list[dict]) -> list[str]:
    """The panel's titles in the order sent, repeats left out."""
    out: list[str] = []
    for m in messages:
        if (m["type"] == "SetGuiPanelLabelMessage" and m["label"] is not None
                and (not out or out[-1] != m["label"])):
            out.append(m["label"])
    return out


@pytest.mark.slow
def test_the_chip_follows_the_stream_and_the_replay_marks_are_in_words(module_server):
    api = module_server.client("alice")
    patient = api.patient("Chip Watch")
    token = api.device(patient["id"])["token"]
    page = grant(api, patient["id"])
    recording = short_exercise("elbow_flexion", 3)

    async def scenario():
        kit = KitEmulator(recording, module_server.ws_url, token, speed=1)

        def lost(messages):
            return "Connection lost" in _labels(messages)

        viewer = asyncio.create_task(watch(ws_url(module_server, page), lost, 120))
        await asyncio.sleep(1.0)
        streaming = asyncio.create_task(kit.run())
        # the kit streams for 12 s of its ~27 s, then its link dies (no bye)
        await asyncio.sleep(12)
        assert not streaming.done(), "the kit ended before its link was cut"
        streaming.cancel()
        try:
            await streaming
        except (asyncio.CancelledError, Exception):
            pass
        return await viewer

    messages = asyncio.run(scenario())
    labels = _labels(messages)
    print(f"the panel's titles: {labels}")
    assert labels[0] == "Waiting for the kit"
    assert "Live: receiving" in labels
    assert labels[-1] == "Connection lost"
    assert "Connected" not in labels

    # a replay of a whole session: its marks in words in the dropdown
    kit_stats = asyncio.run(KitEmulator(recording, module_server.ws_url, token,
                                        speed=0).run())
    assert kit_stats.acked == kit_stats.total
    sessions = api.http.get(f"/api/patients/{patient['id']}/sessions").json()
    done = max(s["id"] for s in sessions)
    api.wait_processed(done, 120)
    replay = grant(api, patient["id"], done)

    def dropdown(messages):
        return any(m["type"] == "GuiDropdownMessage" and m["props"].get("label") == "Marks"
                   for m in messages)

    seen = asyncio.run(watch(ws_url(module_server, replay), dropdown, 30))
    options = next(m["props"]["options"] for m in seen
                   if m["type"] == "GuiDropdownMessage" and m["props"].get("label") == "Marks")
    print(f"the replay's marks: {options}")
    words = [o.split(" · ", 1)[1] for o in options]
    assert words == ["N-pose", "N-pose ends", "T-pose", "T-pose ends", "Elbow flexion",
                     "Elbow flexion ends"]
    assert not any(":" in o for o in options)
