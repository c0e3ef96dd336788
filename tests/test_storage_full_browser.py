"""The server's disk fills up while a kit streams (month two of a clinic: the recordings
grew). Found: the therapist's live view went on showing a healthy stream ("Connected",
100 samples/s) while nothing was stored; ``/healthz`` said ok to the clinic's monitoring;
signing in answered a bare "Internal Server Error". The kit kept its readings unacked and
sent them once there was room (nothing lost: that part held). Now the live views say that
nothing is stored and why, ``/healthz`` answers 503 with the reason, and a request that
cannot be stored answers 503 in words. A real server whose data folder is on a 24 MB tmpfs
(mounting needs root: skipped without), ``armtrack stream`` at real time, the patient page
at 1280 px in Debian's chromium."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys

import httpx
import pytest
from browser_helpers import need_browser, page_at, sign_in_as
from server_support import PASSWORD, ServerProcess

sync_api = need_browser()


@pytest.fixture
def small_disk(tmp_path):
    mount = tmp_path / "disk"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=24m", "tmpfs", str(mount)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here ({done.stderr.strip()})")
    yield mount
    subprocess.run(["umount", "-l", str(mount)], check=False)


def fill(folder) -> None:
    """Take every free byte of ``folder``'s file system, written until it is full: the
    server writes meanwhile (``fallocate`` of the free bytes read a moment before failed
    with "No space left on device" on CI)."""
    fd = os.open(folder / "filler", os.O_WRONLY | os.O_CREAT, 0o600)
    try:
        size = 1 << 20
        while size >= 512:
            try:
                os.write(fd, b"\0" * size)
            except OSError as exc:
                if exc.errno != errno.ENOSPC:
                    raise
                size //= 2  # the last bytes, in smaller pieces
    finally:
        os.close(fd)
    assert shutil.disk_usage(folder).free < 1 << 20, shutil.disk_usage(folder)


def test_a_full_disk_is_said_to_the_therapist_and_the_monitor_and_loses_nothing(small_disk):
    server = ServerProcess(small_disk / "data")
    server.create_user("alice")
    server.start(timeout=180)
    kit = None
    try:
        api = server.client("alice")
        patient = api.patient("Full Disk")
        token = api.device(patient["id"], "kit")["token"]
        kit = subprocess.Popen(
            [sys.executable, "-m", "armtrack.server.cli", "stream", "--exercise",
             "elbow_flexion", "--url", server.ws_url, "--token", token, "--quiet"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        with page_at(1280) as page:
            sign_in_as(page, server.url, "alice")
            page.goto(f"{server.url}/patients/{patient['id']}")
            sync_api.expect(page.locator("#sensor-table tbody tr").first).to_contain_text(
                "Connected", timeout=60_000)
            fill(small_disk)
            notice = page.locator("#storage-failing")
            sync_api.expect(notice).to_be_visible(timeout=30_000)
            words = notice.inner_text()
            print("\nthe therapist reads:", words)
            assert "not stored" in words and "disk is full" in words
            assert "kit keeps" in words and "clinic's IT" in words

            health = httpx.get(server.url + "/healthz", timeout=30)
            print("healthz:", health.status_code, health.text)
            assert health.status_code == 503 and "disk is full" in health.text
            signed = httpx.post(server.url + "/api/auth/token", timeout=30,
                                data={"username": "alice", "password": PASSWORD})
            print("sign-in:", signed.status_code, signed.text)
            assert signed.status_code == 503, signed.text
            assert "disk is full" in signed.json()["detail"]

            os.remove(small_disk / "filler")  # IT makes room
            sync_api.expect(notice).to_be_hidden(timeout=30_000)
            assert httpx.get(server.url + "/healthz", timeout=30).status_code == 200
        out, _ = kit.communicate(timeout=180)
        print(out[-600:])
        assert kit.returncode == 0, out
        session = api.http.get(f"/api/patients/{patient['id']}/sessions").json()[0]
        assert session["samples"] == 10428, session  # every reading the kit sent
    finally:
        if kit is not None and kit.poll() is None:
            kit.kill()
        server.stop()
