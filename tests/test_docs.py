"""The guides in docs/ do what they say: the integrator's `curl` examples and the kit
builder's worked client are taken out of the markdown and run against a real server; a
backup taken with `armtrack backup` while a kit streams restores to a server that serves
the same sessions, as of the backup (the operator's guide). The README and docs link only
to files that exist."""

from __future__ import annotations

import os
import re
import shutil
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from server_support import PASSWORD, ServerProcess, armtrack

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def code_blocks(path: Path, language: str) -> list[str]:
    """The fenced code blocks of ``language`` in a markdown file, in order."""
    return re.findall(rf"^```{language}\n(.*?)^```", path.read_text("utf-8"), re.M | re.S)


def env_with_armtrack(**extra: str) -> dict[str, str]:
    """The environment with this interpreter's ``armtrack`` first on PATH."""
    return {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}",
            **extra}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    process = ServerProcess(tmp_path_factory.mktemp("docs-server"))
    process.create_user("alice")
    process.start(timeout=600)
    yield process
    process.stop()


@pytest.mark.skipif(not (shutil.which("curl") and shutil.which("jq")),
                    reason="the examples use curl and jq: apt-get install -y curl jq")
def test_the_integrators_curl_examples_run(server, tmp_path):
    blocks = code_blocks(DOCS / "integrator.md", "sh")
    assert len(blocks) >= 8
    script = "set -euo pipefail\n" + "\n".join(blocks)
    done = subprocess.run(["bash", "-c", script], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600, env=env_with_armtrack(
                              ARMTRACK=server.url, ARMTRACK_USER="alice",
                              ARMTRACK_PASSWORD=PASSWORD))
    print(done.stdout[-3000:])
    assert done.returncode == 0, done.stderr[-3000:] + done.stdout[-2000:]
    out = done.stdout
    assert "422" in out  # the JSON sign-in, refused as the guide says
    assert '"name": "Ada Example"' in out
    assert '"percent_of_normal"' in out and '"processed": true' in out
    assert out.splitlines().count("204") == 2  # kit revoked, session erased (lines: a
    # time stamp such as "04:37:36.204695Z" holds 204 too)
    assert (tmp_path / "report.pdf").read_bytes().startswith(b"%PDF")
    assert (tmp_path / "session.csv").read_text().startswith("# armtrack-recording: 1")
    assert (tmp_path / "angles.csv").read_text().startswith("t,")
    assert (tmp_path / "patient.zip").read_bytes().startswith(b"PK")
    assert '"resourceType": "Bundle"' in out


def test_the_worked_kit_client_streams_a_session(server, tmp_path):
    (client,) = code_blocks(DOCS / "kit-builder.md", "python")
    kit = tmp_path / "kit.py"
    kit.write_text(client)
    alice = server.client("alice")
    patient = alice.patient("Worked Example")
    token = alice.device(patient["id"])["token"]
    done = subprocess.run([sys.executable, str(kit)], capture_output=True, text=True,
                          timeout=300, env=env_with_armtrack(
                              ARMTRACK_INGEST=server.ws_url, ARMTRACK_TOKEN=token))
    print(done.stdout, done.stderr[-2000:])
    assert done.returncode == 0, done.stderr[-3000:]
    match = re.search(r"session (\d+): 202 messages acked, 0 refused", done.stdout)
    assert match, done.stdout
    session = alice.wait_processed(int(match.group(1)), timeout=120)
    assert session["status"] == "closed" and session["samples"] == 2000
    assert session["sensors"] == ["forearm"] and not session["processing_error"]


def _sessions_in(db: Path) -> dict[int, int]:
    with sqlite3.connect(db) as connection:
        return dict(connection.execute("SELECT id, samples FROM sessions"))


def test_a_backup_taken_while_streaming_restores_the_sessions_as_of_then(tmp_path):
    original = ServerProcess(tmp_path / "original")
    original.create_user("alice")
    original.start(timeout=600)
    try:
        alice = original.client("alice")
        patient = alice.patient("Backed Up")
        token = alice.device(patient["id"])["token"]
        # a first session, complete
        done = armtrack("simulate", "--exercise", "pronation", "--reps", "2",
                        "-o", str(tmp_path / "first.csv"))
        assert done.returncode == 0, done.stderr
        with open(tmp_path / "first.csv", "rb") as f:
            first = alice.http.post("/api/recordings", data={"patient_id": patient["id"]},
                                    files={"file": ("first.csv", f, "text/csv")}).json()
        alice.wait_processed(first["id"], timeout=120)
        # a second one streaming in real time while the backup is taken
        kit = subprocess.Popen(
            [sys.executable, "-m", "armtrack.server.cli", "stream", "--exercise",
             "elbow_flexion", "--url", original.ws_url, "--token", token, "--quiet"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                live = [s for s in alice.http.get(
                    f"/api/patients/{patient['id']}/sessions").json() if s["status"] == "live"]
                if live and live[0]["samples"] > 1000:
                    break
                time.sleep(0.5)
            assert live, "the kit's session never went live"
            backup = tmp_path / "armtrack-backup.db"
            done = original.armtrack("backup", str(backup))
            print(done.stdout, done.stderr)
            assert done.returncode == 0, done.stderr
            assert kit.poll() is None, "the stream ended before the backup: not a live backup"
            _, err = kit.communicate(timeout=180)
            assert kit.returncode == 0, err
        finally:
            if kit.poll() is None:
                kit.kill()
        final = {s["id"]: s for s in alice.http.get(
            f"/api/patients/{patient['id']}/sessions").json()}
        first_export = alice.http.get(f"/api/sessions/{first['id']}/recording.csv").content
    finally:
        original.stop()

    assert stat_mode(backup) == 0o600
    in_backup = _sessions_in(backup)
    streamed = live[0]["id"]
    assert set(in_backup) == set(final)  # both sessions, the streaming one in part
    assert 0 < in_backup[streamed] < final[streamed]["samples"]
    print(f"backup holds {in_backup[streamed]} of the streamed session's "
          f"{final[streamed]['samples']} samples")

    restored = ServerProcess(tmp_path / "restored")
    restored.data_dir.mkdir()
    shutil.copy(backup, restored.data_dir / "armtrack.db")
    restored.start(timeout=600)
    try:
        alice = restored.client("alice")  # the accounts came back too
        sessions = {s["id"]: s for s in alice.http.get(
            f"/api/patients/{patient['id']}/sessions").json()}
        assert set(sessions) == set(final)
        assert sessions[first["id"]]["samples"] == final[first["id"]]["samples"]
        assert alice.http.get(f"/api/sessions/{first['id']}/recording.csv").content \
            == first_export
        assert sessions[streamed]["samples"] == in_backup[streamed]
        # the session that was streaming is served as of the backup
        assert sessions[streamed]["status"] == "interrupted"
        rows = alice.http.get(f"/api/sessions/{streamed}/recording.csv").text
        assert sum(1 for line in rows.splitlines()
                   if line and not line.startswith(("#", "t,"))) == in_backup[streamed]
    finally:
        restored.stop()


def test_backup_of_a_postgresql_server_says_to_use_pg_dump(tmp_path):
    done = armtrack("backup", str(tmp_path / "x"), "--database-url",
                    "postgresql+psycopg://armtrack:secret@db.example/armtrack")
    assert done.returncode == 2
    assert "pg_dump --format=custom" in done.stderr and "secret" not in done.stderr


def stat_mode(path: Path) -> int:
    return path.stat().st_mode & 0o777


#: Pages other parts of the project write (issue 24 links them from the index); until they
#: land a link to them is not counted as broken.
WRITTEN_ELSEWHERE = {"phone-kit.md", "security.md"}


def test_the_docs_link_only_to_files_that_exist():
    broken = []
    for page in [ROOT / "README.md", *DOCS.rglob("*.md")]:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text("utf-8")):
            if "://" in target or target.startswith("mailto:"):
                continue
            if Path(target).name in WRITTEN_ELSEWHERE:
                continue
            if not (page.parent / target).exists():
                broken.append(f"{page.relative_to(ROOT)} → {target}")
    assert not broken, "\n".join(broken)


def test_the_readme_cites_no_spec_folder_a_clone_lacks():
    readme = (ROOT / "README.md").read_text("utf-8")
    assert not re.search(r"(?<!docs/)spec/\w+\.md", readme)


def test_every_setting_is_in_the_operators_guide():
    """Every ``ARMTRACK_`` setting (``server/settings.py``) has its row in docs/operator.md's
    settings tables (its default and meaning), where an operator looks for it."""
    from armtrack.server.settings import Settings

    guide = (DOCS / "operator.md").read_text("utf-8")
    missing = [f"ARMTRACK_{name.upper()}" for name in Settings.model_fields
               if not re.search(rf"^\|[^\n]*`ARMTRACK_{name.upper()}`", guide, re.M)]
    assert not missing, f"not in docs/operator.md's tables: {', '.join(missing)}"


def test_tests_run_after_the_readmes_run_command_or_say_how_to_make_the_env_afresh(tmp_path):
    """README: "Run it" (``pip install .``, then the demo) before "Test it" (``pip install
    -e``) in the same ``.venv``. The demo's numba cache files (``__pycache__/*.nbi``) lie in
    site-packages' ``armtrack/…`` folders, which ``pip`` does not remove on the editable
    install: those folders then hide the checkout's packages and every test failed to import
    (``No module named 'armtrack.server.ingest.protocol'``; seen on a fresh clone). The same
    leftovers here, ahead of the checkout on the path: the tests stop at once and say how to
    make the environment afresh, as README says beside "Test it". (An installed copy no
    longer leaves them: the next test.)"""
    for folder, cached in (("server/ingest", "protocol._plausible_loop-425.py311.nbi"),
                           ("estimator/pipeline", "tracks._not_increasing_python-18.py311.nbi")):
        cache = tmp_path / "armtrack" / folder / "__pycache__"
        cache.mkdir(parents=True)
        (cache / cached).write_bytes(b"")
    run = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
         str(ROOT / "tests" / "test_emulator.py")],
        cwd=ROOT, env={**os.environ, "PYTHONPATH": str(tmp_path)},
        capture_output=True, text=True, timeout=120)
    said = run.stdout + run.stderr
    print(said[-1500:])
    afresh = "python3 -m venv --clear .venv && .venv/bin/pip install -e '.[test]'"
    assert run.returncode != 0
    assert str(tmp_path / "armtrack") in said and afresh in said, said[-1500:]
    assert afresh in (ROOT / "README.md").read_text("utf-8")


def test_an_installed_copy_caches_its_kernels_outside_site_packages(tmp_path):
    """The cause of the leftovers above: numba cached the kernels of an installed copy
    (``pip install .``) beside its sources in site-packages, where pip's next install
    leaves them. An installed copy now caches under the user's cache folder, so README's
    "Run it" then "Test it" in one ``.venv`` leaves nothing behind."""
    target = tmp_path / "lib" / "site-packages"
    pip = subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps",
         "--target", str(target), str(ROOT)], capture_output=True, text=True, timeout=300)
    assert pip.returncode == 0, pip.stderr[-2000:]
    cache = tmp_path / "cache"
    compile_one = ("import numpy as np\n"
                   "import armtrack.estimator.pipeline.tracks as tracks\n"
                   "print(tracks.__file__)\n"
                   "print(tracks._not_increasing(np.array([0.0, 1.0, 1.0]), -1.0))\n")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    run = subprocess.run([sys.executable, "-c", compile_one], cwd=tmp_path,
                         env={**env, "PYTHONPATH": str(target), "XDG_CACHE_HOME": str(cache)},
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    imported_from, answer = run.stdout.split()
    assert Path(imported_from).is_relative_to(target) and answer == "True"
    in_site_packages = sorted(p.name for p in target.rglob("*.nb[ic]"))
    in_user_cache = sorted(p.name for p in (cache / "armtrack" / "numba").rglob("*.nb[ic]"))
    print(f"numba cache files: {len(in_site_packages)} in site-packages, "
          f"{len(in_user_cache)} in the user's cache folder")
    assert not in_site_packages
    assert any(name.startswith("tracks._not_increasing_python") for name in in_user_cache)


def test_the_operators_install_steps_make_accounts_the_server_has(tmp_path):
    """docs/operator.md's Install block, run as written from a scratch folder (its
    ``/opt/armtrack/bin/`` is this environment's, ``/var/lib/armtrack`` a folder here; the
    clone and install line is skipped). Found: its ``create-user`` lines gave no data
    folder, so the accounts went to ./armtrack-data while the server, started on
    /var/lib/armtrack, said "no therapist account yet"."""
    guide = (DOCS / "operator.md").read_text("utf-8")
    block = re.search(r"## Install\n.*?```text\n(.*?)```", guide, re.S).group(1)
    lines = [line.split("  #")[0].strip() for line in block.splitlines()
             if line.strip() and "git clone" not in line]
    bin_dir = str(Path(sys.executable).parent) + "/"
    env = {k: v for k, v in os.environ.items() if not k.startswith("ARMTRACK_")}
    served = None
    for line in lines:
        line = line.replace("/opt/armtrack/bin/", bin_dir).replace(
            "/var/lib/armtrack", str(tmp_path / "var-lib-armtrack"))
        if line.startswith("export "):  # kept for the lines after it, as a shell does
            name, value = line[len("export "):].split("=", 1)
            env[name] = value
            continue
        if line.endswith("armtrack serve"):  # where this server would keep its database
            inline = dict(re.findall(r"(ARMTRACK_\w+)=(\S+)", line))
            served = Path({**env, **inline}.get("ARMTRACK_DATA_DIR", "armtrack-data"))
            continue
        done = subprocess.run(["bash", "-c", line], cwd=tmp_path, input="a long password\n",
                              capture_output=True, text=True, timeout=120, env=env)
        print(line, "→", done.returncode, done.stdout.strip(), done.stderr.strip()[-300:])
        assert done.returncode == 0, done.stderr
    assert served is not None, "the block starts no server"
    served = served if served.is_absolute() else tmp_path / served
    print("the server's data folder:", served, "; databases made:",
          sorted(str(f.relative_to(tmp_path)) for f in tmp_path.rglob("armtrack.db")))
    assert (served / "armtrack.db").exists(), \
        "the accounts went elsewhere than the server's database"
    accounts = ServerProcess(served).sql(
        "SELECT username FROM therapists ORDER BY username")
    assert [name for (name,) in accounts] == ["alice", "root"], accounts


def test_the_operators_accounts_steps_run_and_say_how_a_password_is_changed(tmp_path):
    """docs/operator.md's Accounts block, run as written on a scratch data folder: a second
    therapist, and disabling one. Found by an IT person asked to add a therapist and
    rotate one's password: the operator's guide said neither (the command line's
    "exists already" said no more), and nothing where the server's log goes. The section
    names the pages that do it, which exist."""
    guide = (DOCS / "operator.md").read_text("utf-8")
    section = re.search(r"^## Accounts\n(.*?)^## ", guide, re.S | re.M)
    assert section, "the operator's guide has no Accounts section"
    text = section.group(1)
    block = re.search(r"```text\n(.*?)```", text, re.S).group(1)
    env = {k: v for k, v in os.environ.items() if not k.startswith("ARMTRACK_")}
    env["ARMTRACK_DATA_DIR"] = str(tmp_path / "data")
    bin_dir = str(Path(sys.executable).parent) + "/"
    for line in (ln.split("  #")[0].strip() for ln in block.splitlines() if ln.strip()):
        done = subprocess.run(["bash", "-c", line.replace("/opt/armtrack/bin/", bin_dir)],
                              cwd=tmp_path, input="a long password\n", capture_output=True,
                              text=True, timeout=120, env=env)
        print(line, "→", done.returncode, done.stdout.strip(), done.stderr.strip()[-300:])
        assert done.returncode == 0, done.stderr
    rows = ServerProcess(tmp_path / "data").sql(
        "SELECT username, full_name, disabled_at IS NOT NULL FROM therapists ORDER BY username")
    print(rows)
    assert [(name, disabled) for name, _, disabled in rows] == [
        ("alice", False), ("bob", True), ("carol", False)]
    assert dict((n, f) for n, f, _ in rows)["carol"] == "Carol Meier"
    # bob, disabled, asked for again: the refusal says how he comes back, not how to
    # change a password he cannot sign in to use
    again = subprocess.run([str(Path(sys.executable).parent / "armtrack"), "create-user", "bob"],
                           input="a long password\n", capture_output=True, text=True,
                           timeout=120, env=env)
    print(again.stderr)
    assert again.returncode == 2 and "is disabled" in again.stderr
    assert "enables it" in again.stderr and "/admin" in again.stderr
    routes = (ROOT / "web" / "pages" / "routes.py").read_text("utf-8")
    for page in ("/account", "/admin"):
        assert f"`{page}`" in text and f'@router.get("{page}")' in routes, page
    for words in ("reset code", "I have a reset code", "journalctl", "/healthz"):
        assert words in text, words


def _docker_ignored(path: str, patterns: list[str]) -> bool:
    """Whether ``docker build`` leaves ``path`` (relative to the context) out, by
    .dockerignore's rules: a pattern, anchored at the context's root, matches the path or
    a folder above it, segment by segment (``*`` within one, ``**`` any number of them); a
    later ``!pattern`` takes a path back."""
    import fnmatch

    def match(pattern: list[str], parts: list[str]) -> bool:
        if not pattern:
            return not parts
        if pattern[0] == "**":
            return any(match(pattern[1:], parts[i:]) for i in range(len(parts) + 1))
        return bool(parts) and fnmatch.fnmatchcase(parts[0], pattern[0]) and \
            match(pattern[1:], parts[1:])

    parts = path.split("/")
    ignored = False
    for pattern in patterns:
        keep = pattern.startswith("!")
        segments = pattern.lstrip("!").strip("/").split("/")
        if any(match(segments, parts[:i]) for i in range(1, len(parts) + 1)):
            ignored = not keep
    return ignored


def test_the_docker_image_leaves_out_patients_data_and_the_hosts_environment():
    """Found reading docker/ as a clinic's IT person (no docker daemon on this machine):
    the Dockerfile copies the whole checkout (``COPY . /app``, context the repository
    root) and there was no .dockerignore, so an image built in a checkout the server had
    run from took its ``armtrack-data/`` (the patients' database, which .gitignore says
    never to commit), ``armtrack-demo/``, database copies, the host's ``.venv`` (whose
    python the image lacks, over which ``.ci/install`` makes its own) and ``.git``. What
    the image needs stays in."""
    ignore = ROOT / ".dockerignore"
    assert ignore.exists(), "no .dockerignore beside the build context's root"
    patterns = [ln.strip() for ln in ignore.read_text("utf-8").splitlines()
                if ln.strip() and not ln.startswith("#")]
    out = [".venv/bin/python", ".git/HEAD", "armtrack-data/armtrack.db",
           "armtrack-data/armtrack.db-wal", "armtrack-demo/armtrack.db",
           "clinic/armtrack-data/armtrack.db", "backups/armtrack-2026-12-02.db",
           "armtrack.dump", "build/lib/x.py", "armtrack.egg-info/PKG-INFO",
           "server/__pycache__/app.cpython-311.pyc", ".pytest_cache/v", "demo.csv",
           # recordings anywhere in the checkout, not only at its top (`*.csv` matched
           # only there): a patient's export unpacked in a folder, the demo's angles
           "exports/patient-3/session-12.csv", "recordings/demo.angles.csv"]
    kept = ["pyproject.toml", "README.md", ".ci/install", "server/app.py",
            "server/db/migrations/versions/0001_initial_schema.py", "estimator/__init__.py",
            "web/pages/static/kit.js", "docker/Dockerfile"]
    wrong = [p for p in out if not _docker_ignored(p, patterns)]
    wrong += [f"{p} (needed)" for p in kept if _docker_ignored(p, patterns)]
    assert not wrong, wrong
    for path in kept:
        assert (ROOT / path).exists(), path


def test_the_operators_guide_says_where_the_compiled_kernels_are_cached(monkeypatch):
    """Found installing afresh as a clinic's IT person: the first patient's live angles
    came 34 s into the exercise (the kernels compiled on first use; later starts 3 s),
    which operator.md did not say. It now says so, where they are cached (this test: the
    folder ``estimator/jit.py`` uses) and how to build them before patients come."""
    from armtrack.estimator.jit import installed_cache_dir

    guide = (DOCS / "operator.md").read_text("utf-8")
    monkeypatch.setenv("XDG_CACHE_HOME", "/x")
    assert installed_cache_dir() == Path("/x/armtrack/numba")
    assert "`$XDG_CACHE_HOME` or `~/.cache`, then `armtrack/numba`" in guide
    block = re.search(r"\*\*The first session after an install\.\*\*(.*?)\n\n", guide, re.S)
    assert block, "operator.md does not say what the first session after an install waits"
    # ops20: the server builds them at start (its log's line) and `armtrack warm` ahead
    assert "armtrack warm" in block.group(1), block.group(1)
    assert "armtrack: compiled kernels ready (" in block.group(1)
    from armtrack.server.store import background
    assert "armtrack: compiled kernels ready (" in Path(background.__file__).read_text()


def test_compose_passes_the_clinics_settings_to_the_app(monkeypatch):
    """Found by user19 and ops20 reading docker/compose.yaml (no docker daemon here): the
    single-machine app took only ARMTRACK_DATABASE_URL, so the https address phones use
    (ARMTRACK_PUBLIC_URL), the trusted proxy and the clinic's name could not be given
    without editing the file. They are passed from compose's shell when set there (a key
    without a value), never as an empty string: an empty ARMTRACK_PUBLIC_URL or
    ARMTRACK_CLINIC_TIMEZONE stops the server. (`docker-compose config` of docker-compose
    1.29.2 accepts the file with each profile; checked by hand, not here.)"""
    import yaml
    from armtrack.server.settings import Settings

    compose = yaml.safe_load((ROOT / "docker" / "compose.yaml").read_text("utf-8"))
    environment = compose["services"]["app"]["environment"]
    for name in ("ARMTRACK_PUBLIC_URL", "ARMTRACK_TRUSTED_PROXIES", "ARMTRACK_CLINIC_NAME",
                 "ARMTRACK_CLINIC_TIMEZONE"):
        assert name in environment, name
    for name, value in environment.items():
        assert name.startswith("ARMTRACK_"), name
        assert name.removeprefix("ARMTRACK_").lower() in Settings.model_fields, name
        assert value is None or value == f"${{{name}:-}}", (name, value)
        if value is not None:  # compose gives "" when the shell has no such variable
            monkeypatch.setenv(name, "")
    Settings()  # what the app then starts with validates
