"""The 3D viewer: one-time grants, the proxied viser page and WebSocket, per-viewer scenes of
a live patient and of a stored session, and the scene builder driven in-process.

Viewers are real WebSocket clients speaking viser's protocol (``viser-v<version>``): they
send the camera message a browser sends on connecting, and decode viser's frames (zstd
msgpack) into messages."""

import asyncio
import time

import msgspec
import numpy as np
import pytest
import viser
import zstandard
from armtrack.estimator.arm.forward import POINTS, forward_kinematics
from armtrack.estimator.arm.joints import REPORTED_ANGLES, SEGMENTS
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.rotations import matrix_to_quat, quat_to_matrix
from armtrack.estimator.simulation import SimulationConfig, simulate
from armtrack.server.emulator import KitEmulator
from armtrack.web.viewer.geometry import z_to
from armtrack.web.viewer.grants import CLOSED, OPEN, WAITING, GrantBook
from armtrack.web.viewer.host import CLOSE_NO_GRANT, ViewerHost, quiet_viser_server, stop_quietly
from armtrack.web.viewer.pose import Pose
from armtrack.web.viewer.rom import AMBER, ARC_PIECES, GREEN, RED, arc_points, band_colour
from armtrack.web.viewer.view import ClientView
from viser import _messages
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

SUBPROTOCOL = f"viser-v{viser.__version__}"
ARM_NODES = {"/arm/thorax", "/arm/thorax/upper_arm", "/arm/thorax/forearm", "/arm/thorax/hand",
             "/arm/thorax/joints/elbow", "/floor", "/stance/facing"}
CAMERA = _messages.ViewerCameraMessage(
    wxyz=(1.0, 0.0, 0.0, 0.0), position=(3.0, 0.0, 1.2), fov=1.0, near=0.01, far=100.0,
    image_height=600, image_width=800, look_at=(0.0, 0.0, 1.2), up_direction=(0.0, 0.0, 1.0))


def decode(frame: bytes) -> list[dict]:
    """viser's server → client frame: sizes, zstd msgpack, then raw buffers."""
    size = int.from_bytes(frame[:8], "little")
    packed = int.from_bytes(frame[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(frame[16:16 + packed], max_output_size=size)
    return msgspec.msgpack.decode(inner)["messages"]


async def watch(url: str, until=lambda messages: False, seconds: float = 5.0) -> list[dict]:
    """A viewer's messages until ``until(messages)`` or ``seconds``; a close ends it."""
    messages: list[dict] = []
    async with connect(url, subprotocols=[SUBPROTOCOL], max_size=None) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        await ws.send(msgspec.msgpack.encode(CAMERA.as_serializable_dict()))
        try:
            async with asyncio.timeout(seconds):
                while not until(messages):
                    messages += decode(await ws.recv())
        except (TimeoutError, ConnectionClosed):
            pass
    return messages


def names(messages: list[dict]) -> set[str]:
    return {m["name"] for m in messages if isinstance(m.get("name"), str)}


def positions(messages: list[dict], name: str) -> list[tuple]:
    return [tuple(m["position"]) for m in messages
            if m["type"] == "SetPositionMessage" and m.get("name") == name]


def texts(messages: list[dict]) -> str:
    return " ".join(str(m) for m in messages if "Markdown" in m["type"]
                    or m["type"] == "GuiUpdateMessage")


async def refused(url: str) -> int | str:
    """How a viewer is turned away: the HTTP status of a refused handshake, or the close
    code; fails if it receives any frame."""
    try:
        async with connect(url, subprotocols=[SUBPROTOCOL]) as ws:
            await ws.send(msgspec.msgpack.encode(CAMERA.as_serializable_dict()))
            frame = await asyncio.wait_for(ws.recv(), 5)
            raise AssertionError(f"a refused viewer got a frame: {decode(frame)[:3]}")
    except InvalidStatus as exc:
        return exc.response.status_code
    except ConnectionClosed as exc:
        return exc.rcvd.code if exc.rcvd else "closed"


# ---------------------------------------------------------------- pure parts, in-process


def test_grants_are_one_time_and_expire():
    book = GrantBook(ttl_s=0.2, ticket_ttl_s=0.2)
    grant = book.issue(therapist_id=1, patient_id=2, session_id=None)
    assert book.page(grant.id) is grant and book.page("nonsense") is None
    claimed = book.claim(grant.id)
    assert claimed is grant and claimed.ticket
    assert book.claim(grant.id) is None and book.page(grant.id) is None  # used
    assert book.take_ticket(claimed.ticket) is grant
    assert book.take_ticket(claimed.ticket) is None  # the ticket too
    late = book.issue(therapist_id=1, patient_id=2, session_id=3)
    time.sleep(0.25)
    assert book.page(late.id) is None and book.claim(late.id) is None


def test_a_grant_tells_whether_its_viewer_is_still_connected():
    book = GrantBook(ttl_s=0.2)
    grant = book.issue(therapist_id=1, patient_id=2, session_id=None)
    assert book.state(grant.id) == (grant, WAITING)
    book.claim(grant.id)
    assert book.state(grant.id) == (grant, OPEN)
    book.close(grant.id)
    assert book.state(grant.id) == (grant, CLOSED)  # the page asks for a new grant
    assert book.state("nonsense") is None  # unknown, e.g. after a restart: also a new one
    unused = book.issue(therapist_id=1, patient_id=2, session_id=None)
    time.sleep(0.25)
    assert book.state(unused.id) == (unused, CLOSED)


def test_the_viser_server_prints_nothing(capsys):
    server = quiet_viser_server()
    assert server.get_port() > 0
    stop_quietly(server)
    captured = capsys.readouterr()
    assert captured.out == "" and "viser" not in captured.err


def test_z_to_turns_z_onto_the_direction():
    rng = np.random.default_rng(1)
    for d in [*rng.normal(size=(200, 3)), np.array([0, 0, -1.0]), np.array([0, 0, 2.0])]:
        R = quat_to_matrix(z_to(d))
        np.testing.assert_allclose(R @ [0, 0, 1], d / np.linalg.norm(d), atol=1e-12)


def test_arcs_follow_the_chain_and_are_coloured_against_normal():
    lengths = SegmentLengths.from_height(1.75)
    pose = pose_from_angles({"shoulder_flexion": 30.0}, lengths, "right")
    points, theta = arc_points("shoulder_flexion", pose, lengths, 0.0, 90.0, pieces=2)
    r = 0.60 * lengths.upper_arm
    shoulder = pose.p_thorax["shoulder"]
    # flexion swings the arm forward (thorax +X) in the sagittal plane about the shoulder
    np.testing.assert_allclose(points[0], shoulder + r * np.array([0, -1, 0]), atol=1e-12)
    np.testing.assert_allclose(points[-1], shoulder + r * np.array([1, 0, 0]), atol=1e-12)
    np.testing.assert_allclose(theta, [0, 45, 90])
    left = pose_from_angles({"shoulder_abduction": 0.0}, lengths, "left")
    points, _ = arc_points("shoulder_abduction", left, lengths, 0.0, 90.0, pieces=1)
    np.testing.assert_allclose(points[-1], left.p_thorax["shoulder"] + r * 0.45 / 0.60
                               * np.array([0, 0, -1]), atol=1e-12)  # a left arm goes to −Z
    colours = band_colour(np.array([100.0, 155.0, 170.0, -5.0]), "elbow_flexion")
    assert [tuple(c) for c in colours] == [GREEN, AMBER, RED, AMBER]


def pose_from_angles(angles_deg: dict, lengths: SegmentLengths, side: str,
                     rom: dict | None = None, t: float = 0.0) -> Pose:
    """A live ``pose`` update made by forward kinematics, the thorax upright facing east."""
    arm = forward_kinematics({k: np.radians(v) for k, v in angles_deg.items()}, side, lengths)
    R_world_thorax = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    update = {
        "kind": "pose", "session_id": 1, "t": t,
        "angles_deg": {k: angles_deg.get(k, 0.0) for k in REPORTED_ANGLES},
        "positions_m": {k: np.asarray(arm.p_thorax[k]).tolist() for k in POINTS},
        "segments_q": {s: matrix_to_quat(R_world_thorax @ arm.R_thorax[s]).tolist()
                       for s in SEGMENTS},
        "rom_deg": {k: {"min": lo, "max": hi, "range": hi - lo}
                    for k, (lo, hi) in (rom or {}).items()},
    }
    return Pose.from_update(update)


def test_a_client_scene_is_built_once_and_moved_in_place():
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    views: list[ClientView] = []
    server.on_client_connect(lambda client: views.append(
        ClientView(client, heading="Ada · live", height_m=1.75, side="right")))
    lengths = SegmentLengths.from_height(1.75)
    try:
        async def scenario():
            url = f"ws://127.0.0.1:{server.get_port()}/"
            viewer = asyncio.create_task(watch(url, seconds=4.0))
            while not views:
                await asyncio.sleep(0.05)
            await asyncio.sleep(0.3)
            for k, elbow in enumerate(np.linspace(0.0, 120.0, 13)):
                pose = pose_from_angles({"elbow_flexion": elbow}, lengths, "right",
                                        {"elbow_flexion": (0.0, elbow)}, t=k / 30)
                await asyncio.to_thread(views[0].show, pose)
                await asyncio.sleep(1 / 30)
            return await viewer, pose

        messages, pose = asyncio.run(scenario())
    finally:
        server.stop()
    view = views[0]
    assert ARM_NODES <= names(messages)
    created = [m["name"] for m in messages if m["type"] == "CylinderMessage"]
    assert len(created) == len(set(created)), "a node was made twice"
    wrists = positions(messages, "/arm/thorax/joints/wrist")
    assert len(set(wrists)) >= 10, "the wrist did not move with the elbow"
    np.testing.assert_allclose(wrists[-1], pose.p_thorax["wrist"], atol=1e-6)
    np.testing.assert_allclose(view.arm.joints["wrist"].position, pose.p_thorax["wrist"])
    assert view.arcs._arcs["elbow_flexion"].visible
    assert not view.arcs._arcs["shoulder_flexion"].visible
    assert "Elbow flexion 120°" in view.arcs._labels["elbow_flexion"].text
    # the arc: a line of fixed width on screen and a translucent fan, green within normal
    assert view.arcs._arcs["elbow_flexion"].thickness_units == "screen"
    green, amber, red = view.arcs._fans["elbow_flexion"]
    assert green.visible and not amber.visible and not red.visible
    assert len(green.faces) == ARC_PIECES and 0 < green.opacity < 1
    # embedded beside the page's own angles: a small control panel, minimised when live
    theme = [m for m in messages if m["type"] == "ThemeConfigurationMessage"][-1]
    assert theme["control_width"] == "small" and not theme["show_logo"]
    assert any(m["type"] == "GuiSetPanelCollapsedMessage" and m["collapsed"]
               for m in messages)
    # the camera looks at the shoulder, the centre of the arm's reach (the framing of the
    # whole reach: tests/test_viewer_view.py)
    camera = view.client.camera
    target = np.asarray(camera.look_at)
    shoulder = view.arm.notch_world(pose) + pose.R_world["thorax"] @ pose.p_thorax["shoulder"]
    assert np.linalg.norm(np.asarray(camera.position) - target) < 3.0
    assert np.linalg.norm(target - shoulder) < 0.01


def test_a_segment_whose_sensor_stopped_is_left_out_of_the_view_not_drawn_wrong():
    """A live pose whose hand sensor stopped sending (its segment, point and angles null,
    ``server/live/estimator.py``): the arm is drawn all the same, without the hand and
    the wrist's arc; the first pose without a hand hides it (a pose with any unknown part
    was skipped whole before: the view froze)."""
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    views: list[ClientView] = []
    server.on_client_connect(lambda client: views.append(
        ClientView(client, heading="Ada · live", height_m=1.75, side="right")))
    lengths = SegmentLengths.from_height(1.75)
    whole = pose_from_angles({"elbow_flexion": 60.0, "wrist_flexion": 30.0}, lengths,
                             "right", {"elbow_flexion": (0.0, 60.0),
                                       "wrist_flexion": (0.0, 30.0)}, t=1.0)
    update = {"t": 2.0, "angles_deg": {**whole.angles_deg, "elbow_flexion": 90.0,
                                       "wrist_flexion": None, "wrist_deviation": None},
              "positions_m": {k: v.tolist() for k, v in whole.p_thorax.items()},
              "segments_q": {s: matrix_to_quat(R).tolist() for s, R in whole.R_world.items()},
              "rom_deg": {"elbow_flexion": {"min": 0.0, "max": 90.0},
                          "wrist_flexion": {"min": 0.0, "max": 30.0}}}
    update["positions_m"]["hand"] = [None, None, None]
    update["segments_q"]["hand"] = [None] * 4
    stopped = Pose.from_update(update)
    try:
        async def scenario():
            url = f"ws://127.0.0.1:{server.get_port()}/"
            viewer = asyncio.create_task(watch(url, seconds=1.5))
            while not views:
                await asyncio.sleep(0.05)
            await asyncio.to_thread(views[0].show, whole)
            hand_shown = views[0].arm.hand.visible
            await asyncio.to_thread(views[0].show, stopped)
            await viewer
            return hand_shown

        hand_shown = asyncio.run(scenario())
    finally:
        server.stop()
    view = views[0]
    assert hand_shown and not view.arm.hand.visible
    assert view._last is stopped  # drawn, not skipped
    assert view.arm.segments["forearm"].visible and view.arm.joints["wrist"].visible
    assert view.arcs._arcs["elbow_flexion"].visible
    assert not view.arcs._arcs["wrist_flexion"].visible


def test_the_gate_closes_a_viewer_without_a_ticket_before_sending_anything():
    class NoServices:  # the gate needs no database: it refuses before building anything
        db = hub = sensor_status = None

    host = ViewerHost(NoServices())

    async def scenario():
        await host.start()
        try:
            port = host.port
            return [await refused(f"ws://127.0.0.1:{port}/"),
                    await refused(f"ws://127.0.0.1:{port}/?ticket=guess")]
        finally:
            await host.stop()

    assert asyncio.run(scenario()) == [CLOSE_NO_GRANT, CLOSE_NO_GRANT]


# ---------------------------------------------------------------- a real server


@pytest.fixture(scope="module")
def elbow():
    return simulate(SimulationConfig(exercise="elbow_flexion", repetitions=3, seed=4))


def grant(api, patient_id: int, session_id: int | None = None) -> str:
    answer = api.http.post("/api/viewer", json={"patient_id": patient_id,
                                                "session_id": session_id})
    assert answer.status_code == 200, answer.text
    body = answer.json()
    assert body["url"].startswith("/viewer/") and body["url"].endswith("/")
    return body["url"]


def ws_url(server, page: str) -> str:
    return f"ws://127.0.0.1:{server.port}{page.rstrip('/')}"


def test_a_grant_is_only_for_a_therapists_own_patient_and_session(module_server):
    alice, bob = module_server.client("alice"), module_server.client("bob")
    ada, eve = alice.patient("Ada"), alice.patient("Eve")
    bert = bob.patient("Bert")
    assert alice.http.post("/api/viewer", json={"patient_id": ada["id"]}).json()[
        "expires_in"] == 60
    assert bob.http.post("/api/viewer", json={"patient_id": ada["id"]}).status_code == 404
    assert alice.http.post("/api/viewer", json={"patient_id": bert["id"]}).status_code == 404
    assert alice.http.post("/api/viewer", json={"patient_id": 10**6}).status_code == 404
    assert alice.http.post("/api/viewer", json={"patient_id": eve["id"],
                                                "session_id": 10**6}).status_code == 404
    anonymous = module_server.client("alice").http
    anonymous.headers.pop("Authorization")
    assert anonymous.post("/api/viewer", json={"patient_id": ada["id"]}).status_code == 401
    assert alice.http.post("/api/viewer", json={}).status_code == 422


def test_a_viewer_without_a_valid_grant_sees_nothing(module_server):
    alice = module_server.client("alice")
    ada = alice.patient("Ada")
    page = grant(alice, ada["id"])
    http = alice.http
    assert http.get(page).status_code == 200
    assert "viser" in http.get(page).text.lower()
    assert http.get("/viewer/nonsense/").status_code == 404

    async def scenario():
        outcomes = [await refused(ws_url(module_server, "/viewer/nonsense")),
                    await refused(ws_url(module_server, "/viewer/"))]
        used = await watch(ws_url(module_server, page),
                           until=lambda ms: ARM_NODES <= names(ms), seconds=15)
        assert ARM_NODES <= names(used), "the valid grant got no arm"
        outcomes.append(await refused(ws_url(module_server, page)))  # used once already
        return outcomes

    no_grant, bare, reused = asyncio.run(scenario())
    assert no_grant == 403 and reused == 403
    assert bare in (403, 404)
    assert http.get(page).status_code == 404  # the page too is gone once used


def test_an_expired_grant_opens_nothing(tmp_path):
    from server_support import ServerProcess

    process = ServerProcess(tmp_path / "server", env={"ARMTRACK_VIEWER_GRANT_S": "1"})
    process.create_user("alice")
    process.start()
    try:
        api = process.client("alice")
        page = grant(api, api.patient()["id"])
        time.sleep(1.3)
        assert api.http.get(page).status_code == 404
        assert asyncio.run(refused(ws_url(process, page))) == 403
    finally:
        process.stop()


def test_two_therapists_watch_their_own_patients_live_and_a_session_replays(
        module_server, elbow):
    alice, bob = module_server.client("alice"), module_server.client("bob")
    ada, bert = alice.patient("Ada"), bob.patient("Bert")
    token = alice.device(ada["id"])["token"]
    ada_page, bert_page = grant(alice, ada["id"]), grant(bob, bert["id"])

    def moved(ms):
        return len(set(positions(ms, "/arm/thorax/joints/wrist"))) >= 20

    async def scenario():
        ada_view = asyncio.create_task(watch(ws_url(module_server, ada_page), moved, 60))
        bert_view = asyncio.create_task(watch(ws_url(module_server, bert_page), seconds=8))
        await asyncio.sleep(0.5)
        kit = KitEmulator(elbow.recording, module_server.ws_url, token, speed=4)
        stats = await kit.run()
        return stats, await ada_view, await bert_view

    stats, ada_seen, bert_seen = asyncio.run(scenario())
    assert stats.acked == stats.total
    assert ARM_NODES <= names(ada_seen) and ARM_NODES <= names(bert_seen)
    assert moved(ada_seen), "the live arm did not move"
    assert "Ada" in texts(ada_seen) and "Bert" not in texts(ada_seen)
    assert "Bert" in texts(bert_seen) and "Ada" not in texts(bert_seen)
    assert not positions(bert_seen, "/arm/thorax/joints/wrist")[1:], \
        "Bert's viewer got poses, but Bert streams nothing"

    session = alice.http.get(f"/api/patients/{ada['id']}/sessions").json()[0]
    alice.wait_processed(session["id"])
    assert bob.http.post("/api/viewer", json={"patient_id": ada["id"],
                                              "session_id": session["id"]}).status_code == 404
    assert bob.http.post("/api/viewer", json={"patient_id": bert["id"],
                                              "session_id": session["id"]}).status_code == 404
    replay = grant(alice, ada["id"], session["id"])
    seen = asyncio.run(watch(ws_url(module_server, replay), moved, 30))
    assert ARM_NODES <= names(seen) and moved(seen), "the replay did not play"
    buttons = {m.get("props", {}).get("label") for m in seen if m["type"] == "GuiButtonMessage"}
    assert {"Play", "Pause", "Jump to mark"} <= buttons
    assert any(m["type"] == "GuiUplotMessage" for m in seen)
    assert "elbow flexion" in texts(seen)
