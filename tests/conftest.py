"""Shared fixtures. Tests that need ``../shared`` (the spec's data, beside the repo) skip
with a clear reason when it is absent, as in a user's clone; CI has it."""

import os
import secrets
from pathlib import Path

import pytest

SHARED_DIR = Path(__file__).resolve().parents[1].parent / "shared"


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


def pytest_generate_tests(metafunc):
    """Tests marked ``both_databases`` run with their server on SQLite and PostgreSQL."""
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
    if not (SHARED_DIR / "data" / "recordings").is_dir():
        pytest.skip(f"needs the shared data folder beside the repo ({SHARED_DIR}); "
                    "a user's clone has none, CI has it")
    return SHARED_DIR


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
