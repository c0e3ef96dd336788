"""Shared fixtures. Tests that need ``../shared`` (the spec's data, beside the repo) skip
with a clear reason when it is absent, as in a user's clone; CI has it."""

from pathlib import Path

import pytest

SHARED_DIR = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not (SHARED_DIR / "data" / "recordings").is_dir():
        pytest.skip(f"needs the shared data folder beside the repo ({SHARED_DIR}); "
                    "a user's clone has none, CI has it")
    return SHARED_DIR


@pytest.fixture
def server(tmp_path):
    """A running armtrack server with one therapist ``alice`` (see ``server_support``)."""
    from server_support import ServerProcess

    process = ServerProcess(tmp_path / "server")
    process.create_user("alice")
    process.start()
    yield process
    process.stop()


@pytest.fixture(scope="module")
def module_server(tmp_path_factory):
    """One server for a whole test module, with therapists ``alice`` and ``bob``."""
    from server_support import ServerProcess

    process = ServerProcess(tmp_path_factory.mktemp("server"))
    process.create_user("alice")
    process.create_user("bob")
    process.start()
    yield process
    process.stop()
