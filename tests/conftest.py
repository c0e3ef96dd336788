"""Shared fixtures. Tests that need a recording with its ground truth take
``recording_set`` (run on every set there is: the project's simulator's stand-ins always,
the independent simulator's files of ``../shared/data/recordings`` too where present) or
``recordings_dir`` (one set: the shared files where present, else the stand-ins), so every
such test runs everywhere; see ``recording_sets``. Tests that need the real-data sets
(``../shared/data/broad``, ``ring``) skip with a clear reason when ``../shared`` is absent."""

import os
import secrets
from pathlib import Path

import pytest


def _checkout_hidden() -> str | None:
    """Words for an environment whose ``armtrack`` packages are not this checkout's, or
    None. ``pip install .`` then ``pip install -e`` in one venv (README's "Run it", then
    "Test it") leaves site-packages' ``armtrack/…`` folders holding the demo's numba cache
    files; those folders hide the editable install and every import of a module inside them
    fails."""
    import importlib.util

    root = Path(__file__).resolve().parents[1]
    for package, folder in (("armtrack.server", "server"), ("armtrack.estimator", "estimator")):
        spec = importlib.util.find_spec(package)
        found = Path(spec.origin).parent if spec and spec.origin else None
        if found != root / folder:
            where = ", ".join(spec.submodule_search_locations or []) if spec else "nowhere"
            return (f"{package} is imported from {found or where}, not from this checkout "
                    f"({root / folder}): an earlier `pip install .` left it (numba's cache "
                    "files stay behind when pip replaces the package). Make the environment "
                    "afresh: python3 -m venv --clear .venv && .venv/bin/pip install -e '.[test]'")
    return None


if (_hidden := _checkout_hidden()) is not None:
    pytest.exit(_hidden, returncode=4)
from recording_sets import (  # noqa: E402 (after the check: it imports armtrack)
    SHARED_DIR,
    SHARED_FACTS,
    SHARED_RECORDINGS,
    RecordingSet,
    available_sources,
    make_stand_ins,
)

# A kit starts at most ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR (20) new sessions an hour;
# many tests stream session after session with one module's kit (test_ingest_protocol's
# 21st was refused). Their servers (and in-process settings) get no such bound; the tests
# of the bound set it themselves (test_security_session_flood, the phone kit's).
os.environ.setdefault("ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR", "1000000")


@pytest.fixture(scope="session")
def postgres_url() -> str:
    """A PostgreSQL server's URL for the tests (``ARMTRACK_TEST_POSTGRES_URL``: CI starts
    one with ``.ci/postgres``); skips where there is none, as in a user's clone."""
    url = os.environ.get("ARMTRACK_TEST_POSTGRES_URL")
    if not url:
        pytest.skip('needs PostgreSQL: ARMTRACK_TEST_POSTGRES_URL is unset (CI sets it; '
                    'eval "$(.ci/postgres start)" makes a throwaway one)')
    try:
        import psycopg  # noqa: F401
    except ImportError:
        pytest.skip("needs the PostgreSQL driver: pip install -e '.[postgres]'")
    return url


def fresh_postgres_database(url: str) -> str:
    """A new, empty database on the server of ``url``; its URL."""
    from sqlalchemy import create_engine, text
    from sqlalchemy.engine import make_url

    name = f"armtrack_test_{secrets.token_hex(6)}"
    engine = create_engine(url, isolation_level="AUTOCOMMIT")
    with engine.connect() as connection:
        connection.execute(text(f"CREATE DATABASE {name}"))
    engine.dispose()
    return make_url(url).set(database=name).render_as_string(hide_password=False)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item, nextitem):
    """Marks the teardown (``server_support.TEARDOWN``): a server stopped now is stopped
    for good, and ``ServerProcess.stop`` does not wait for its session estimations."""
    from server_support import TEARDOWN

    TEARDOWN.active = True
    try:
        yield
    finally:
        TEARDOWN.active = False


def pytest_generate_tests(metafunc):
    """Tests marked ``both_databases`` run with their server on SQLite and PostgreSQL;
    tests taking ``recording_set`` run on each set of recordings there is."""
    if "recording_set" in metafunc.fixturenames:
        metafunc.parametrize("recording_set", available_sources(), indirect=True,
                             scope="session")
    if metafunc.definition.get_closest_marker("both_databases") is None:
        return
    for name, scope in (("server", "function"), ("module_server", "module")):
        if name in metafunc.fixturenames:
            metafunc.parametrize(name, ["sqlite", "postgres"], indirect=True, scope=scope)


def _database_env(request) -> dict[str, str]:
    if getattr(request, "param", "sqlite") != "postgres":
        return {}
    url = request.getfixturevalue("postgres_url")
    return {"ARMTRACK_DATABASE_URL": fresh_postgres_database(url)}


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` for the real-data sets (``data/broad``, ``data/ring``): real
    recordings cannot be made, so their tests skip where it is absent."""
    if not (SHARED_DIR / "data").is_dir():
        pytest.skip(f"needs the shared data folder beside the repo ({SHARED_DIR}); "
                    "a user's clone has none, CI has it")
    return SHARED_DIR


@pytest.fixture(scope="session")
def stand_ins(tmp_path_factory) -> RecordingSet:
    """The ten sessions made by the project's simulator, with their truth's facts."""
    folder = tmp_path_factory.mktemp("stand-ins")
    return RecordingSet("stand-in", folder, make_stand_ins(folder))


def _set(source: str, request) -> RecordingSet:
    if source == "shared":
        return RecordingSet("shared", SHARED_RECORDINGS, SHARED_FACTS)
    return request.getfixturevalue("stand_ins")


@pytest.fixture(scope="session")
def recording_set(request) -> RecordingSet:
    """Each set of simulated recordings there is (parametrized: ``stand-in``, and
    ``shared`` where ``../shared`` exists)."""
    return _set(request.param, request)


@pytest.fixture(scope="session")
def recordings(request) -> RecordingSet:
    """One set: the shared recordings where present, else the stand-ins."""
    return _set(available_sources()[-1], request)


@pytest.fixture(scope="session")
def recordings_dir(recordings) -> Path:
    """The folder of :func:`recordings`."""
    return recordings.folder


@pytest.fixture
def server(tmp_path, request):
    """A running armtrack server with one therapist ``alice`` (see ``server_support``)."""
    from server_support import ServerProcess

    process = ServerProcess(tmp_path / "server", _database_env(request))
    process.create_user("alice")
    process.start()
    yield process
    process.stop()


@pytest.fixture(scope="module")
def module_server(tmp_path_factory, request):
    """One server for a whole test module, with therapists ``alice`` and ``bob``."""
    from server_support import ServerProcess

    process = ServerProcess(tmp_path_factory.mktemp("server"), _database_env(request))
    process.create_user("alice")
    process.create_user("bob")
    process.start()
    yield process
    process.stop()
