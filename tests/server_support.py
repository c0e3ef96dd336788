"""A real armtrack server for the tests: ``armtrack serve`` in its own process on a free
loopback port with its own data folder, a therapist made by ``armtrack create-user``, and
a small REST client. The process can be killed (SIGKILL) and started again on the same
database."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from armtrack.server.processes import PROCESSING

PASSWORD = "correct horse battery"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_port_free(port: int, timeout: float = 60.0) -> None:
    """Wait until 127.0.0.1:``port`` can be bound again, as ``armtrack serve`` binds it
    (``SO_REUSEADDR``). A SIGKILLed server's listening socket is closed only once the last
    of its threads has exited; its main thread shows as a zombie (what a forked server's
    ``kill()`` waits for) before that, the longer on a loaded machine, and a restart on the
    same port in between failed with 'port ... is already in use' (test_reliability_faults,
    two pytest processes on 2 cores)."""
    deadline = time.monotonic() + timeout
    while True:
        with socket.socket() as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind(("127.0.0.1", port))
                return
            except OSError:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"port {port} still held after {timeout} s") from None
        time.sleep(0.02)


async def send_paced(ws, plan, speed: float, *, first: int = 0,
                     stop_at_s: float | None = None, now_at_s: float | None = None,
                     hold_at_s: float | None = None, until=None,
                     hold_limit_s: float = 120.0) -> int:
    """Send ``plan``'s messages (a ``MessagePlan``) from ``first`` on ``ws``, each when
    its recording time comes at ``speed`` times real time; returns the seq it stopped at
    (``len(plan)``: all sent). ``now_at_s``: the recording time [s] it is now (older
    messages go at once, a backlog; default: the first message's). ``stop_at_s``: stop
    before the first message at or after it [s]. ``hold_at_s`` with ``until``: before
    the first message at or after it [s], wait (at most ``hold_limit_s``) until
    ``until()`` is true — the live estimation may start slowly on a busy machine, so an
    exercise begins once the first feedback is in — and pace from there."""
    start, origin = time.monotonic(), plan.times[first] if now_at_s is None else now_at_s
    for seq in range(first, len(plan)):
        if stop_at_s is not None and plan.times[seq] >= stop_at_s:
            return seq
        if (hold_at_s is not None and seq > first
                and plan.times[seq] >= hold_at_s > plan.times[seq - 1]):
            deadline = time.monotonic() + hold_limit_s
            while not until() and time.monotonic() < deadline:
                await asyncio.sleep(0.1)
            start, origin = time.monotonic(), plan.times[seq]
        await asyncio.sleep(max(0.0, start + (plan.times[seq] - origin) / speed
                                - time.monotonic()))
        await ws.send(plan.encode(seq))
    return len(plan)


class _Teardown:
    """Whether pytest is tearing a test down now (``active``; tests/conftest.py's
    ``pytest_runtest_teardown``), when module and test fixtures stop their servers."""

    active = False


TEARDOWN = _Teardown()


def kill_children(pid: int, name: str) -> None:
    """SIGKILL the child processes of ``pid`` named ``name`` (``/proc/PID/comm``), and
    its children still starting (``multiprocessing``'s spawned children are named once
    their imports are done: a server that lost its processing child starts another for
    the next queued job, and that one would be waited for)."""
    try:
        tasks = list(Path(f"/proc/{pid}/task").iterdir())
    except OSError:
        return
    for task in tasks:
        try:
            children = (task / "children").read_text().split()
        except OSError:
            continue
        for child in children:
            try:
                comm = Path(f"/proc/{child}/comm").read_text().strip()
                starting = (comm.startswith("python") and b"spawn_main"
                            in Path(f"/proc/{child}/cmdline").read_bytes())
                if comm == name or starting:
                    os.kill(int(child), signal.SIGKILL)
            except (OSError, ValueError):
                pass


def armtrack(*args: str, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "armtrack.server.cli", *args],
                          capture_output=True, text=True, **kwargs)


class ServerProcess:
    """``armtrack serve`` on 127.0.0.1:``port`` with data in ``data_dir``."""

    def __init__(self, data_dir: Path, env: dict[str, str] | None = None):
        self.data_dir = data_dir
        self.port = free_port()
        self.env = {**os.environ, **(env or {})}
        self.process: subprocess.Popen | None = None
        self.log = data_dir / "server.log"

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def database_url(self) -> str:
        """The server's SQLAlchemy URL (``ARMTRACK_DATABASE_URL``, else its SQLite file)."""
        return (self.env.get("ARMTRACK_DATABASE_URL")
                or f"sqlite:///{(self.data_dir / 'armtrack.db').resolve()}")

    def sql(self, statement: str, **params) -> list[tuple]:
        """Rows of one SQL statement on the server's database (any backend)."""
        from sqlalchemy import create_engine, text

        engine = create_engine(self.database_url)
        try:
            with engine.begin() as connection:
                result = connection.execute(text(statement), params)
                return [tuple(row) for row in result] if result.returns_rows else []
        finally:
            engine.dispose()

    def armtrack(self, *args: str, **kwargs) -> subprocess.CompletedProcess:
        """``armtrack ARGS --data-dir DATA_DIR`` with the server's environment."""
        return armtrack(*args, "--data-dir", str(self.data_dir), env=self.env, **kwargs)

    @property
    def ws_url(self) -> str:
        return f"ws://127.0.0.1:{self.port}/ws/ingest"

    def start(self, timeout: float = 120.0) -> ServerProcess:
        self.data_dir.mkdir(parents=True, exist_ok=True)
        wait_port_free(self.port, timeout)  # a restart after kill(): see wait_port_free
        log = open(self.log, "ab")  # the child process writes to it
        self.process = subprocess.Popen(
            [sys.executable, "-m", "armtrack.server.cli", "serve", "--port", str(self.port),
             "--data-dir", str(self.data_dir)], stdout=log, stderr=subprocess.STDOUT,
            env=self.env)
        log.close()
        return self._wait_healthy(timeout, 0.1)

    def _wait_healthy(self, timeout: float, poll_s: float):
        """Wait until the started server answers /healthz; raises with its log's tail if
        it exits or does not answer within ``timeout`` [s]."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(f"server exited: {self.log.read_text()[-2000:]}")
            try:
                if httpx.get(self.url + "/healthz", timeout=1).status_code == 200:
                    return self
            except httpx.HTTPError:
                time.sleep(poll_s)
        raise RuntimeError(f"server did not start: {self.log.read_text()[-2000:]}")

    def kill(self) -> None:
        """SIGKILL: no shutdown code runs."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait()

    def stop(self) -> None:
        """SIGTERM, then wait (15 s at most, else SIGKILL) for the server to end. It stops
        as it does for users: it stores what kits sent, and waits for the session
        estimations it was given (``SessionProcessing``: what is queued is estimated
        first, there being nothing that estimates it later). When pytest tears a test down
        (``TEARDOWN``, set by tests/conftest.py) nobody reads the server's data again, so
        its processing child (``armtrack-proc``) is killed instead of waited for: its
        first job runs at ``nice`` 19 with its estimation at ``SCHED_IDLE``, on a loaded
        2-core machine 20 s and more (child imports, compiled kernels loaded), and the
        teardown of every module whose server had just closed a session took the whole
        15 s (ci20). A server that hangs on anything else still takes the 15 s."""
        if self.process is None or self.process.poll() is not None:
            return
        self.process.terminate()
        deadline = time.monotonic() + 15
        while self.process.poll() is None:
            if time.monotonic() > deadline:
                self.kill()
                return
            if TEARDOWN.active:
                kill_children(self.process.pid, PROCESSING)
            time.sleep(0.02)

    def create_user(self, name: str, password: str = PASSWORD) -> None:
        done = self.armtrack("create-user", name, "--password", password)
        assert done.returncode == 0, done.stderr

    def create_admin(self, name: str, password: str = PASSWORD) -> None:
        """A clinic admin's account (manages accounts, holds no patients)."""
        done = self.armtrack("create-user", name, "--admin", "--password", password)
        assert done.returncode == 0, done.stderr

    def client(self, name: str, password: str = PASSWORD) -> Api:
        return Api(self.url, name, password)


def server_fixture(name: str, *users: str, timeout: float = 180.0,
                   env: dict[str, str] | None = None):
    """A module-scoped pytest fixture: a started ``ServerProcess`` in a new folder
    ``name`` (with the settings ``env``) with a therapist account for each of ``users``,
    stopped after the module."""

    @pytest.fixture(scope="module")
    def server(tmp_path_factory):
        process = ServerProcess(tmp_path_factory.mktemp(name), env)
        for user in users:
            process.create_user(user)
        process.start(timeout=timeout)
        yield process
        process.stop()

    return server


class Api:
    """A therapist's REST client (signed in)."""

    def __init__(self, base: str, name: str, password: str):
        # an idle connection is dropped here after 2 s, before uvicorn closes it (5 s):
        # with both at 5 s a request sent after a 5-s pause met the server's close
        # ("Connection reset by peer", test_phone_kit_browser_storage in a targeted run)
        self.http = httpx.Client(base_url=base, timeout=60,
                                 limits=httpx.Limits(keepalive_expiry=2.0))
        answer = self.http.post("/api/auth/token", data={"username": name, "password": password})
        answer.raise_for_status()
        self.token = answer.json()["access_token"]
        self.http.headers["Authorization"] = f"Bearer {self.token}"

    def patient(self, name: str = "Ada", side: str = "right", height_m: float = 1.75) -> dict:
        answer = self.http.post("/api/patients",
                                json={"name": name, "side": side, "height_m": height_m})
        answer.raise_for_status()
        return answer.json()

    def device(self, patient_id: int, name: str = "kit") -> dict:
        answer = self.http.post(f"/api/patients/{patient_id}/devices", json={"name": name})
        answer.raise_for_status()
        return answer.json()

    def session(self, session_id: int) -> dict:
        answer = self.http.get(f"/api/sessions/{session_id}")
        answer.raise_for_status()
        return answer.json()

    def settled(self, session_id: int, timeout: float = 15) -> dict:
        """The session once it is no longer live. A kit's ``bye`` is acked, then the server
        closes the session (``endpoint._finish``); a kit that closes its socket right after
        bye (``KitEmulator``, the phone page) finishes before that, and the session reads
        "live" for a moment on a loaded machine. After ``timeout`` the session as it is."""
        deadline = time.monotonic() + timeout
        while True:
            session = self.session(session_id)
            if session["status"] != "live" or time.monotonic() > deadline:
                return session
            time.sleep(0.1)

    def live_session(self, patient_id: int, timeout: float = 60) -> dict:
        """The session the patient's kit streams now (``/live``'s), once it has begun."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            live = self.http.get(f"/api/patients/{patient_id}/live").json()["session"]
            if live is not None:
                return live
            time.sleep(0.1)
        raise AssertionError(f"the kit's stream did not start in {timeout} s")

    def wait_processed(self, session_id: int, timeout: float = 60) -> dict:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            session = self.session(session_id)
            if session["processed"] or session["processing_error"]:
                return session
            time.sleep(0.1)
        raise TimeoutError(f"session {session_id} was not processed in {timeout} s")


# -- fast restarts: servers forked from a process that has imported the server ---------------

_ZYGOTE = r"""
import json, os, signal, sys
from armtrack.server.cpu_threads import one_blas_thread
one_blas_thread()  # as `armtrack serve` does, before numpy is loaded (forks inherit it)
import armtrack.server.app  # noqa: F401  (the slow imports, done once)
import armtrack.server.commands.serve  # noqa: F401
from armtrack.server.cli import main
signal.signal(signal.SIGCHLD, signal.SIG_IGN)  # children are reaped by the kernel
exec(sys.argv[1])  # a preamble (test hooks), run before any fork
# what is loaded here is frozen before any fork, as heap.settle() does after a start: the
# forked server's settle then walks only what its own start made, instead of writing to
# every inherited object's page (copy-on-write: 0.5-1.0 s of each restart's 1.7-2.2 s)
import gc
gc.collect()
gc.freeze()
for line in sys.stdin:
    order = json.loads(line)
    pid = os.fork()
    if pid == 0:
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        os.setsid()
        fd = os.open(order["log"], os.O_WRONLY | os.O_CREAT | os.O_APPEND)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        os.environ.update(order["env"])
        code = 1
        try:
            code = main(order["argv"]) or 0
        finally:
            os._exit(code)
    print(pid, flush=True)
"""


class _Forked:
    """A forked server's pid with the part of ``Popen`` that ``ServerProcess`` uses."""

    def __init__(self, pid: int):
        self.pid = pid
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            try:
                state = Path(f"/proc/{self.pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
            except OSError:
                state = "X"
            if state in ("X", "Z"):
                self.returncode = -9
        return self.returncode

    def send_signal(self, sig: int) -> None:
        try:
            os.kill(self.pid, sig)
        except ProcessLookupError:
            pass

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired("armtrack serve", timeout)
            time.sleep(0.01)
        return self.returncode  # type: ignore[return-value]


#: A ``Zygote`` preamble that sets the server's clock (``armtrack.server.clock.now``) from
#: the ISO time written in the file ``{path}`` (the real clock while it is empty or absent):
#: a test moves the server's days by writing that file.
SIMULATED_CLOCK_PREAMBLE = """
import datetime as _dt, pathlib as _pl
import armtrack.server.clock as _clock
_NOW_FILE = _pl.Path({path!r})
def _simulated_now():
    text = _NOW_FILE.read_text().strip() if _NOW_FILE.exists() else ""
    return _dt.datetime.fromisoformat(text) if text else _dt.datetime.now(_dt.UTC)
_clock.now = _simulated_now
"""


class Zygote:
    """A process that has imported the server and forks ``armtrack`` commands from it
    (their own ``main``): a server starts in about a second instead of several.
    ``preamble``: Python run once before any fork (e.g. a test hook on the engine)."""

    def __init__(self, preamble: str = "", env: dict[str, str] | None = None):
        self.process = subprocess.Popen([sys.executable, "-c", _ZYGOTE, preamble],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        text=True, env={**os.environ, **(env or {})})

    def fork(self, argv: list[str], log: Path, env: dict[str, str] | None = None) -> _Forked:
        order = {"argv": argv, "log": str(log), "env": env or {}}
        assert self.process.stdin is not None and self.process.stdout is not None
        self.process.stdin.write(json.dumps(order) + "\n")
        self.process.stdin.flush()
        line = self.process.stdout.readline()
        if not line:
            raise RuntimeError("the zygote died")
        return _Forked(int(line))

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()


class ZygoteServerProcess(ServerProcess):
    """A ``ServerProcess`` forked from a :class:`Zygote`: the child runs ``armtrack
    serve``'s own ``main``, and ``kill()`` is a real SIGKILL of it. For tests that restart
    a server many times. ``env``: settings of this server (``ARMTRACK_…``)."""

    def __init__(self, data_dir: Path, zygote: Zygote, env: dict[str, str] | None = None):
        super().__init__(data_dir, env)
        self.zygote = zygote
        self.extra_env = env or {}

    def create_user(self, name: str, password: str = PASSWORD) -> None:
        self.data_dir.mkdir(parents=True, exist_ok=True)
        child = self.zygote.fork(["create-user", name, "--password", password,
                                  "--data-dir", str(self.data_dir)], self.log, self.extra_env)
        child.wait(60)

    def start(self, timeout: float = 60.0) -> ZygoteServerProcess:
        self.data_dir.mkdir(parents=True, exist_ok=True)
        wait_port_free(self.port, timeout)  # a restart after kill(): see wait_port_free
        self.process = self.zygote.fork(  # type: ignore[assignment]
            ["serve", "--port", str(self.port), "--data-dir", str(self.data_dir)],
            self.log, self.extra_env)
        return self._wait_healthy(timeout, 0.02)


def add_patient(db, name: str = "p", therapist=None):
    """A patient (right arm, 1.7 m) of ``therapist``, or of a new therapist ``t``, added
    straight to the database session ``db`` (flushed, not committed)."""
    from armtrack.server.db import models

    if therapist is None:
        therapist = models.Therapist(username="t", password_hash="x")
        db.add(therapist)
        db.flush()
    patient = models.Patient(therapist_id=therapist.id, name=name, side="right",
                             height_m=1.7)
    db.add(patient)
    db.flush()
    return patient
