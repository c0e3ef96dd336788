"""Shared fixtures. Tests that need a recording with its ground truth use
``recordings_dir``: the independent simulator's set in ``../shared/data/recordings`` where
it is (CI has it: the independent check), else the same ten sessions made by the project's
own simulator (a user's clone), so every such test runs everywhere. Tests that need the
real-data sets (``../shared/data/broad``, ``ring``) or the shared files' own facts skip
with a clear reason when ``../shared`` is absent."""

import os
import secrets
from pathlib import Path

import pytest

#: ``../shared`` beside the repository; ``ARMTRACK_TEST_SHARED_DIR`` points elsewhere (a
#: folder that does not exist runs the tests as on a user's clone).
SHARED_DIR = Path(os.environ.get("ARMTRACK_TEST_SHARED_DIR")
                  or Path(__file__).resolve().parents[1].parent / "shared")


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


#: The shared recordings' sessions (README of shared/data/recordings), as the project's
#: simulator makes them: name → SimulationConfig's arguments. Same side, height, rate,
#: axes, sensors, exercise (amplitudes and repetition counts), losses and jitter; another
#: simulator, other mountings, biases and noise draws.
STAND_INS: dict[str, dict] = {
    "elbow_flexion": {"exercise": "elbow_flexion", "height_m": 1.80},
    "shoulder_abduction": {"exercise": "shoulder_abduction", "height_m": 1.74},
    "shoulder_flexion": {"exercise": "shoulder_flexion", "height_m": 1.66},
    "wrist_flexion": {"exercise": "wrist_flexion", "height_m": 1.83},
    "pronation": {"exercise": "pronation", "height_m": 1.78},
    "left_reach_50hz": {"exercise": "reach", "side": "left", "height_m": 1.70,
                        "rate_hz": 50.0},
    "elbow_6axis": {"exercise": "elbow_wrist", "height_m": 1.80, "nine_axis": False},
    "elbow_6axis_long": {"exercise": "long_session", "height_m": 1.76, "nine_axis": False,
                         "gyro_bias_walk": 2e-4},
    "trunk_reach": {"exercise": "trunk_reach", "height_m": 1.69,
                    "sensors": ("trunk", "upper_arm", "forearm", "hand")},
    "abduction_120": {"exercise": "abduction_120", "height_m": 1.72, "lost_fraction": 0.02,
                      "jitter_s": 0.001},
}


#: Where a stand-in is not the shared file in a way a test checks: (name, what) → why.
#: Tests skip that one case on stand-ins (they run it on the shared set).
STAND_IN_DIFFERENCES: dict[tuple[str, str], str] = {
    ("trunk_reach", "calibration"): "the project's trunk_reach sways from t = 0, through "
    "the calibration poses, so calibration warns the trunk was not still; the shared "
    "file's trunk is still in the poses",
    ("elbow_6axis_long", "repetitions"): "the project's long_session holds the elbow at 90° "
    "for each pronation set (4 more elbow excursions than the shared file's 40)",
}


def skip_where_stand_in_differs(recordings_dir: Path, name: str, what: str) -> None:
    """Skip when ``recordings_dir`` holds stand-ins and ``name``'s stand-in differs from
    the shared file in ``what`` (:data:`STAND_IN_DIFFERENCES`)."""
    reason = STAND_IN_DIFFERENCES.get((name, what))
    if reason and recordings_dir != SHARED_DIR / "data" / "recordings":
        pytest.skip(f"stand-in for {name}: {reason} (needs ../shared for this case)")


def make_stand_ins(folder: Path) -> Path:
    """``NAME.csv`` and ``NAME.truth.csv`` for every name of :data:`STAND_INS` in
    ``folder``, by the project's simulator (about 10 s)."""
    import dataclasses

    from armtrack.estimator.recording import write_recording
    from armtrack.estimator.simulation import SimulationConfig, simulate, write_truth

    for seed, (name, given) in enumerate(sorted(STAND_INS.items()), start=1):
        given = dict(given)
        walk = given.pop("gyro_bias_walk", 0.0)
        config = SimulationConfig(seed=seed, **given)
        if walk:
            config = dataclasses.replace(
                config, errors=dataclasses.replace(config.errors, gyro_bias_walk=walk))
        result = simulate(config)
        write_recording(result.recording, folder / f"{name}.csv")
        write_truth(result.truth, folder / f"{name}.truth.csv")
    return folder


@pytest.fixture(scope="session")
def recordings_dir(tmp_path_factory) -> Path:
    """A folder of simulated recordings with their truth (see :data:`STAND_INS`): the shared
    set where present, else the project's simulator's stand-ins."""
    shared = SHARED_DIR / "data" / "recordings"
    if shared.is_dir():
        return shared
    return make_stand_ins(tmp_path_factory.mktemp("recordings"))


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
