"""A real armtrack server for the tests: ``armtrack serve`` in its own process on a free
loopback port with its own data folder, a therapist made by ``armtrack create-user``, and
a small REST client. The process can be killed (SIGKILL) and started again on the same
database."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

PASSWORD = "correct horse battery"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


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

    def start(self, timeout: float = 30.0) -> ServerProcess:
        self.data_dir.mkdir(parents=True, exist_ok=True)
        log = open(self.log, "ab")  # the child process writes to it
        self.process = subprocess.Popen(
            [sys.executable, "-m", "armtrack.server.cli", "serve", "--port", str(self.port),
             "--data-dir", str(self.data_dir)], stdout=log, stderr=subprocess.STDOUT,
            env=self.env)
        log.close()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(f"server exited: {self.log.read_text()[-2000:]}")
            try:
                if httpx.get(self.url + "/healthz", timeout=1).status_code == 200:
                    return self
            except httpx.HTTPError:
                time.sleep(0.1)
        raise RuntimeError(f"server did not start: {self.log.read_text()[-2000:]}")

    def kill(self) -> None:
        """SIGKILL: no shutdown code runs."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait()

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(15)
            except subprocess.TimeoutExpired:
                self.kill()

    def create_user(self, name: str, password: str = PASSWORD) -> None:
        done = self.armtrack("create-user", name, "--password", password)
        assert done.returncode == 0, done.stderr

    def client(self, name: str, password: str = PASSWORD) -> Api:
        return Api(self.url, name, password)


class Api:
    """A therapist's REST client (signed in)."""

    def __init__(self, base: str, name: str, password: str):
        self.http = httpx.Client(base_url=base, timeout=60)
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

    def wait_processed(self, session_id: int, timeout: float = 60) -> dict:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            session = self.session(session_id)
            if session["processed"] or session["processing_error"]:
                return session
            time.sleep(0.1)
        raise TimeoutError(f"session {session_id} was not processed in {timeout} s")
