"""A newcomer's first run: a fresh server says how to make an account (log and sign-in
page), a second server on a busy port says which port and what to do (exit code 2, no
traceback), the demo keeps a bounded number of sessions, and files holding patients' data
are readable by their owner only. Real processes throughout."""

from __future__ import annotations

import socket
import stat
import subprocess
import sys
import time

import httpx
import pytest
from server_support import ServerProcess, armtrack

#: What docker/Dockerfile runs the server with: every interface, TLS left to a proxy.
AS_IN_DOCKER = {"ARMTRACK_HOST": "0.0.0.0", "ARMTRACK_BEHIND_PROXY": "true"}
#: The start-up warning of a server other machines reach over plain http.
PLAIN_HTTP_WARNING = "WARNING: serving plain http on 0.0.0.0"


@pytest.fixture
def fresh_server(tmp_path):
    """A fresh server as the Docker image starts it (its health is asked on 127.0.0.1)."""
    server = ServerProcess(tmp_path / "data", AS_IN_DOCKER).start(timeout=120)
    yield server
    server.stop()


def wait_for_line(path, words: str, timeout_s: float = 180.0) -> str:
    """The log at ``path`` once a line holds ``words`` (raises with its tail if none does
    within ``timeout_s``)."""
    deadline = time.monotonic() + timeout_s
    while True:
        text = path.read_text()
        if words in text:
            return text
        if time.monotonic() > deadline:
            raise AssertionError(f"no {words!r} in the log within {timeout_s} s: {text[-2000:]}")
        time.sleep(0.2)


def first_run_hint_shown(html: str) -> bool:
    return '<div id="first-run" class="notice">' in html


def test_a_fresh_server_says_how_to_make_an_account(fresh_server):
    log = fresh_server.log.read_text()
    assert "no therapist account yet" in log and "armtrack create-user NAME" in log
    # the clinic's name left unset is said to the operator here, not printed on reports
    assert "ARMTRACK_CLINIC_NAME is not set" in log, log[-2000:]
    # Found by ops20 (compose publishes the image's plain http on 8000): nothing told the
    # IT person that phones need https in front; the log now says so, and what to do
    line = next((x for x in log.splitlines() if PLAIN_HTTP_WARNING in x), None)
    assert line, log[-2000:]
    assert "ARMTRACK_PUBLIC_URL" in line and "docs/operator.md#tls" in line
    page = httpx.get(fresh_server.url + "/signin").text
    assert first_run_hint_shown(page)
    assert "armtrack create-user NAME" in page

    fresh_server.create_user("ada")
    page = httpx.get(fresh_server.url + "/signin").text
    assert not first_run_hint_shown(page)
    assert '<div id="first-run" class="notice" hidden>' in page


def test_a_server_with_an_account_logs_no_hint(tmp_path):
    server = ServerProcess(tmp_path / "data")
    server.create_user("ada")
    server.start(timeout=120)
    try:
        log = server.log.read_text()
        assert "no therapist account yet" not in log
        assert "plain http" not in log  # 127.0.0.1: only this machine reaches it
    finally:
        server.stop()


@pytest.mark.parametrize("command", ["serve", "demo"])
def test_a_busy_port_is_named_with_what_to_do(tmp_path, command):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        done = armtrack(command, "--port", str(port), "--data-dir", str(tmp_path / "d"),
                        timeout=120)
    assert done.returncode == 2, done.stderr
    assert f"port {port} on 127.0.0.1 is already in use" in done.stderr
    assert f"armtrack {command} --port {port + 1}" in done.stderr
    assert "Traceback" not in done.stderr and "Errno" not in done.stderr
    print(done.stderr)


def test_the_demo_keeps_a_bounded_number_of_sessions(tmp_path):
    """A demo left running erases its oldest sessions: with --keep 2, after four sessions
    the database holds at most two, the one streaming included — at every moment, not only
    just after an erase (the bound was once kept only after the pause that followed a
    close: a look in those 5 s saw three)."""
    from server_support import free_port

    port = free_port()
    data = tmp_path / "demo"
    log = open(tmp_path / "demo.log", "w")
    demo = subprocess.Popen([sys.executable, "-m", "armtrack.server.cli", "demo", "--port",
                             str(port), "--data-dir", str(data), "--speed", "25",
                             "--exercises", "elbow_flexion", "--keep", "2"],
                            stdout=log, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 240
        text, seen, rows = "", [], []
        while time.monotonic() < deadline and text.count("demo: erased") < 2:
            time.sleep(0.5)
            text = (tmp_path / "demo.log").read_text()
            assert demo.poll() is None, text
            if "demo: the simulated patient" in text:  # the schema is made by then
                rows = ServerProcess(data).sql("SELECT id, status FROM sessions ORDER BY id")
                seen.append(rows)
                assert len(rows) <= 2, (rows, text[-2000:])
        assert text.count("demo: erased") >= 2, text
        # ops20, the README's run command as a newcomer: the demo's first line told them
        # to set ARMTRACK_CLINIC_NAME, a clinic's setting the demo has no use for
        assert "ARMTRACK_CLINIC_NAME" not in text, text[:2000]
        print(f"{len(seen)} looks, the last: {rows}")
        assert rows[-1][0] >= 3  # older sessions were made, then erased
    finally:
        demo.terminate()
        demo.wait(30)
        log.close()


def test_files_with_patients_data_are_owner_only(tmp_path, fresh_server):
    """The database (and its folder), a simulated recording and its truth, an estimate's
    output: 0600, whatever the umask."""
    def mode(path):
        return stat.S_IMODE(path.stat().st_mode)

    db = fresh_server.data_dir / "armtrack.db"
    assert mode(db) == 0o600
    for extra in ("armtrack.db-wal", "armtrack.db-shm"):
        if (fresh_server.data_dir / extra).exists():
            assert mode(fresh_server.data_dir / extra) == 0o600, extra
    rec = tmp_path / "rec.csv"
    done = armtrack("simulate", "--reps", "1", "-o", str(rec))
    assert done.returncode == 0, done.stderr
    assert mode(rec) == 0o600
    assert mode(tmp_path / "rec.truth.csv") == 0o600
    out = tmp_path / "angles.csv"
    done = armtrack("estimate", str(rec), "-o", str(out))
    assert done.returncode == 0, done.stderr
    assert mode(out) == 0o600
    # Found by ops20 (user19 measured it): on a fresh install the first patient's live
    # angles came 55-70 s into the exercise while numba built the kernels. The processing
    # process now builds them (or loads their cache) at start, on idle CPU time (asked
    # here, where the server has been up for the commands above: no wait of its own)
    wait_for_line(fresh_server.log, "armtrack: compiled kernels ready (")


def test_an_existing_world_readable_database_is_narrowed(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    db = data / "armtrack.db"
    db.touch(mode=0o644)
    db.chmod(0o644)
    done = armtrack("create-user", "ada", "--password", "long-enough-1", "--data-dir",
                    str(data))
    assert done.returncode == 0, done.stderr
    assert stat.S_IMODE(db.stat().st_mode) == 0o600


def test_the_serving_line_keeps_the_database_password_out_of_the_log(tmp_path, postgres_url):
    """Found by the clinic IT walk (`armtrack serve --settings` hides it): the start line
    "armtrack: serving on … (database postgresql+psycopg://armtrack:PASSWORD@…)" put the
    database password in the service's log (journald, docker logs). PostgreSQL here trusts
    local connections, so any password connects."""
    from conftest import fresh_postgres_database
    from sqlalchemy.engine import make_url

    url = make_url(fresh_postgres_database(postgres_url)).set(password="s3cret-pw")
    server = ServerProcess(tmp_path / "data", {
        "ARMTRACK_DATABASE_URL": url.render_as_string(hide_password=False)})
    server.create_user("ada")
    server.start(timeout=120)
    try:
        log = server.log.read_text()
    finally:
        server.stop()
    line = next(x for x in log.splitlines() if x.startswith("armtrack: serving on"))
    print("\n" + line)
    assert "s3cret-pw" not in log
    assert ":***@" in line
