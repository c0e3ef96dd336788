"""The command line starts fast: building its parser (``armtrack --help``, and so every
command's start) imports no heavy package, and the light commands import only what they
use. Checked on a real new interpreter with ``-X importtime``, which lists every module a
process imports. Wall times are bench/startup.py's business (a loaded CI machine would make
a time limit here flaky); what is imported decides them."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

#: Packages that cost 0.1-1 s each to import (measured in bench/startup.py).
HEAVY = ("numpy", "scipy", "numba", "llvmlite", "pyarrow", "sqlalchemy", "alembic", "fastapi",
         "starlette", "uvicorn", "viser", "matplotlib", "pydantic", "websockets")


def imported_modules(*argv: str, cwd: Path | None = None, env: dict | None = None,
                     stdin: str | None = None) -> tuple[set[str], subprocess.CompletedProcess]:
    """Every module ``python -X importtime -m armtrack.server.cli ARGV`` imports (a real new
    process), and the finished process."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "armtrack.server.cli",
                           *argv], capture_output=True, text=True, cwd=cwd, input=stdin,
                          env={**os.environ, **(env or {})}, timeout=120)
    return reported_modules(done.stderr), done


def reported_modules(stderr: str) -> set[str]:
    """The modules a ``-X importtime`` report (a process's stderr) lists."""
    modules = set(re.findall(r"^import time:\s+\d+ \|\s+\d+ \| *(\S+)$", stderr,
                             re.MULTILINE))
    assert modules, f"no -X importtime report:\n{stderr[-2000:]}"
    return modules


def heavy_in(modules: set[str], packages=HEAVY) -> list[str]:
    return sorted(p for p in packages if p in modules)


def test_help_imports_no_heavy_package():
    modules, done = imported_modules("--help")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "create-user" in done.stdout and "estimate" in done.stdout
    assert heavy_in(modules) == [], f"armtrack --help imports {heavy_in(modules)}"
    # nor asyncio (~0.1 s): the commands that stream import it in their run
    assert "asyncio" not in modules


@pytest.mark.parametrize("command", ["estimate", "simulate", "stream", "serve", "demo", "import",
                                     "create-user", "reprocess", "orient"])
def test_each_commands_help_imports_no_heavy_package(command):
    modules, done = imported_modules(command, "--help")
    assert done.returncode == 0, done.stderr[-2000:]
    assert heavy_in(modules) == [], f"armtrack {command} --help imports {heavy_in(modules)}"


def test_pose_takes_the_pure_python_path():
    """``armtrack pose`` needs numpy and the arm model, not scipy (its one quaternion per
    segment is plain Python) nor numba (~0.45 s alone)."""
    modules, done = imported_modules("pose", "shoulder_abduction=90", "elbow_flexion=45")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "elbow" in done.stdout
    assert heavy_in(modules, ("scipy", "numba", "llvmlite", "sqlalchemy", "fastapi",
                              "pyarrow")) == []


def test_check_reads_a_recording_without_the_estimator(tmp_path):
    from armtrack.estimator.recording import write_recording
    from armtrack.estimator.simulation import SimulationConfig, simulate

    path = tmp_path / "rec.csv"
    write_recording(simulate(SimulationConfig(repetitions=1)).recording, path)
    modules, done = imported_modules("check", str(path))
    assert done.returncode == 0, done.stderr[-2000:]
    assert "a valid recording" in done.stdout
    assert heavy_in(modules, ("scipy", "numba", "llvmlite", "sqlalchemy", "fastapi")) == []


def test_create_user_on_a_migrated_database_needs_only_the_database(tmp_path):
    """On a database at the newest schema, create-user imports sqlalchemy and argon2, not
    alembic (no migration to run) nor the server (viewer, estimator, web framework)."""
    data = tmp_path / "data"
    _, first = imported_modules("create-user", "first", "--password", "long-enough-1",
                                "--data-dir", str(data))
    assert first.returncode == 0, first.stderr[-2000:]
    modules, done = imported_modules("create-user", "second", "--data-dir", str(data),
                                     stdin="long-enough-2\n")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "created therapist 'second'" in done.stdout
    assert heavy_in(modules, ("numpy", "scipy", "numba", "alembic", "fastapi", "uvicorn",
                              "viser", "pyarrow")) == []


def test_the_cli_choices_match_what_they_name():
    """The filter and exercise names the parser offers without importing the estimator are
    the estimator's."""
    from armtrack.estimator.orientation import DEFAULT_FILTER, FILTERS
    from armtrack.estimator.simulation import EXERCISES
    from armtrack.server.commands import choices

    where = "server/commands/choices.py lists the names the command line offers: update it"
    assert sorted(choices.FILTER_NAMES) == sorted(FILTERS), where
    assert choices.DEFAULT_FILTER == DEFAULT_FILTER, where
    assert sorted(choices.EXERCISE_NAMES) == sorted(EXERCISES), where


def test_head_revision_read_from_the_files_is_alembics():
    """create-user skips alembic when the database is at the newest migration, read from
    the migration files; it must be the head alembic finds."""
    from alembic.config import Config
    from alembic.script import ScriptDirectory
    from armtrack.server.db.migrate import MIGRATIONS, head_revision

    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    assert head_revision() == ScriptDirectory.from_config(config).get_current_head()


def test_the_server_starts_without_what_only_reports_and_calibration_use():
    """``armtrack serve`` (and every test's server) imports its app at start; matplotlib
    (the PDFs) and scipy.integrate (calibration) are imported where first used: 1 s of a
    server's 3.5-s import here. (scipy.signal and scipy.stats, for repetition counting and
    the live trunk guide, stay at start: imported in the first export's thread instead,
    they changed what test_export_memory measures, unexplained.)"""
    done = subprocess.run([sys.executable, "-X", "importtime", "-c",
                           "import armtrack.server.app"], capture_output=True, text=True,
                          timeout=120)
    modules = reported_modules(done.stderr)
    assert "armtrack.server.app" in modules, done.stderr[-2000:]
    late = ("matplotlib", "scipy.integrate")
    assert sorted(m for m in late if m in modules) == []
