"""docs/operator.md's PostgreSQL backup, run as written (the URL and folder changed to the
test's): the dump holds patients' data, so it must be readable by its owner only, as
``armtrack backup`` writes SQLite's (0600). Found: ``pg_dump`` as written left it 0644 under
the usual umask 022 — readable by every account on the machine. The restore, as written,
onto another database gives a server with everything there. A throwaway PostgreSQL
(``.ci/postgres``; skipped without)."""

from __future__ import annotations

import os
import re
import shlex
import stat
import subprocess
from pathlib import Path

from conftest import fresh_postgres_database
from server_support import ServerProcess, armtrack
from sqlalchemy.engine import make_url

GUIDE = Path(__file__).parents[1] / "docs" / "operator.md"


def the_guides_postgres_block() -> list[str]:
    text = GUIDE.read_text("utf-8")
    part = text[text.index("**PostgreSQL**: use its own tools"):]
    block = re.search(r"```text\n(.*?)```", part, re.S).group(1)
    return [line for line in block.splitlines() if line.strip()]


def plain(url: str) -> str:
    return make_url(url).set(drivername="postgresql").render_as_string(hide_password=False)


def test_the_guides_postgres_backup_is_owner_only_and_restores(tmp_path, postgres_url):
    source = fresh_postgres_database(postgres_url)
    server = ServerProcess(tmp_path / "a", {"ARMTRACK_DATABASE_URL": source})
    server.create_user("alice")
    server.start(timeout=180)
    try:
        api = server.client("alice")
        patient = api.patient("Backed Up")
        api.device(patient["id"], "kit")
    finally:
        server.stop()
    target = fresh_postgres_database(postgres_url)
    folder = tmp_path / "backups"
    folder.mkdir()
    lines = the_guides_postgres_block()
    print("\n".join(lines))
    old = os.umask(0o022)  # the usual umask of an operator's shell
    try:
        for line, url in zip(lines, (source, target), strict=True):
            line = (line.replace("/backups/", f"{folder}/")
                    .replace("'postgresql://armtrack@db/armtrack'", shlex.quote(plain(url))))
            done = subprocess.run(["sh", "-c", line], capture_output=True, text=True)
            assert done.returncode == 0, (line, done.stderr)
    finally:
        os.umask(old)
    dump = folder / "armtrack.dump"
    mode = stat.S_IMODE(dump.stat().st_mode)
    print(f"the dump's mode: {mode:o}")
    assert mode == 0o600, f"the dump is {mode:o}: readable by others"

    restored = ServerProcess(tmp_path / "b", {"ARMTRACK_DATABASE_URL": target})
    restored.start(timeout=180)
    try:
        names = [p["name"] for p in restored.client("alice").http.get("/api/patients").json()]
        assert names == ["Backed Up"]
    finally:
        restored.stop()


def test_armtrack_backup_on_postgres_prints_the_guides_command(tmp_path, postgres_url):
    done = armtrack("backup", str(tmp_path / "x.dump"), "--database-url", postgres_url)
    assert done.returncode == 2
    print(done.stderr)
    assert "umask 077" in done.stderr and "pg_dump --format=custom" in done.stderr
    assert "umask 077" in the_guides_postgres_block()[0]
