"""Closed sessions estimated in the processing process (``server/store/background.py``):
the same estimates as in the server's own process, a new child after one is killed, and
no child left behind when the server is killed."""

from __future__ import annotations

import contextlib
import os
import signal
import statistics
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from armtrack.estimator.simulation import SimulationConfig, simulate
from armtrack.server.db import models
from armtrack.server.db.engine import make_engine, make_sessionmaker
from armtrack.server.db.migrate import upgrade
from armtrack.server.processes import PROCESSING
from armtrack.server.store.background import ProcessingFailed, SessionProcessing
from armtrack.server.store.processing import process_in_background, stored_estimates
from armtrack.server.store.recordings import add_recording
from server_support import add_patient


def _children_named(name: str, parent: int | None = None) -> list[int]:
    parent = os.getpid() if parent is None else parent
    found = []
    for task in Path(f"/proc/{parent}/task").iterdir():
        for pid in (task / "children").read_text().split():
            try:
                if Path(f"/proc/{pid}/comm").read_text().strip() == name:
                    found.append(int(pid))
            except FileNotFoundError:  # ended meanwhile
                pass
    return found


@pytest.fixture(scope="module")
def database(tmp_path_factory):
    """An SQLite file with two stored (uploaded) sessions of a simulated elbow flexion."""
    url = f"sqlite:///{tmp_path_factory.mktemp('bg') / 'bg.db'}"
    engine = make_engine(url)
    upgrade(engine)
    recording = simulate(SimulationConfig(exercise="elbow_flexion", repetitions=2,
                                          seed=3)).recording
    with make_sessionmaker(engine)() as db:
        patient = add_patient(db)
        ids = [add_recording(db, patient, recording).id for _ in range(3)]
        db.commit()
    yield url, engine, ids
    engine.dispose()


def _estimates(engine, session_id: int) -> tuple[list[str], np.ndarray]:
    with make_sessionmaker(engine)() as db:
        return stored_estimates(db, db.get(models.Session, session_id))


def test_the_child_stores_what_the_server_process_would(database):
    url, engine, (first, second, _) = database
    process_in_background(make_sessionmaker(engine), first, "qcf")  # here, as before
    processing = SessionProcessing(url, 1, 1, lambda *_: None)
    processing.start()
    try:
        processing.submit(second, "qcf").result(timeout=120)
        assert len(_children_named(PROCESSING)) == 1
        child = _children_named(PROCESSING)[0]
        niceness = int(Path(f"/proc/{child}/stat").read_text().rsplit(")", 1)[1].split()[16])
        policies = {int(task.name): os.sched_getscheduler(int(task.name))
                    for task in Path(f"/proc/{child}/task").iterdir()}
        names = {tid: Path(f"/proc/{child}/task/{tid}/comm").read_text().strip()
                 for tid in policies}
    finally:
        processing.stop()
    here, there = _estimates(engine, first), _estimates(engine, second)
    assert here[0] == there[0] and len(here[1]) > 1000
    assert here[1].tobytes() == there[1].tobytes()  # bit for bit
    assert niceness == 19  # below the server's own priority
    # the estimation on a thread of its own that takes only idle CPU; the main thread
    # (its database reads and write transaction) at an ordinary, lowest-nice policy
    assert policies[child] == os.SCHED_OTHER
    # idle: the estimation thread, and the kernels' warm-up while it lasts (1db6a41: with
    # two idle threads the count of one this test made before failed on CI), nothing else
    idle = {names[tid] for tid, policy in policies.items() if policy == os.SCHED_IDLE}
    assert "armtrack-estima" in idle and idle <= {"armtrack-estima", "armtrack-warm"}, names
    assert _children_named(PROCESSING) == []  # stop() ended it


def test_a_killed_child_fails_its_job_and_a_new_one_takes_the_next(database):
    url, engine, (_, _, third) = database
    processing = SessionProcessing(url, 1, 1, lambda *_: None)
    processing.start()
    try:
        processing.submit(third, "qcf").result(timeout=120)  # warm
        [child] = _children_named(PROCESSING)
        os.kill(child, signal.SIGKILL)
        deadline = time.monotonic() + 10
        while _children_named(PROCESSING) == [child] and time.monotonic() < deadline:
            time.sleep(0.05)
        # a job given to the dead child (before its end was seen) fails, or runs on the
        # next one; either way a later job is done by a new child
        outcome = processing.submit(third, "qcf")
        try:
            outcome.result(timeout=120)
        except ProcessingFailed as exc:
            assert "exit code -9" in str(exc) and f"reprocess {third}" in str(exc)
            processing.submit(third, "qcf").result(timeout=120)
        assert child not in _children_named(PROCESSING)
        assert len(_estimates(engine, third)[1]) > 1000
    finally:
        processing.stop()


def _thread_names(pid: int) -> list[str]:
    """The system names of process ``pid``'s threads (``background._only_idle_cpu`` gives
    its idle threads their Python names)."""
    names = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):  # a thread that ended meanwhile
            names.append((task / "comm").read_text().strip())
    return names


def test_while_streams_are_live_the_child_rests_between_jobs(database):
    """Busy (streams live), at a share of 0.25 the child rests 3× each job's time before
    the next queued job; not busy, the jobs follow each other at once."""
    url, _, (_, _, third) = database
    busy = [False]
    processing = SessionProcessing(url, 1, 1, lambda *_: None, busy=lambda: busy[0],
                                   share_while_busy=0.25)
    processing.start()

    def gap() -> float:
        """Between the ends of two jobs given together [s]."""
        done: list[float] = []
        futures = [processing.submit(third, "qcf") for _ in range(2)]
        for future in futures:
            future.add_done_callback(lambda _: done.append(time.monotonic()))
        for future in futures:
            future.result(timeout=120)
        return done[1] - done[0]

    try:
        processing.submit(third, "qcf").result(timeout=120)  # warm
        # the child's kernels' warm-up (1db6a41) over: its thread shares the interpreter
        # and made jobs ~1.8× slower while it ran (29 → 50 ms), so the rest measured
        # against them looked short (CI-identical run: 124 ms ≤ 2.5 × 60 ms)
        [child] = _children_named(PROCESSING)
        deadline = time.monotonic() + 300
        while "armtrack-warm" in _thread_names(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        at_once = statistics.median(gap() for _ in range(3))  # the second job's time
        busy[0] = True
        # a rest of 3× the first's time, then the second's
        rested = statistics.median(gap() for _ in range(3))
        busy[0] = False
    finally:
        processing.stop()
    print(f"\nnot busy: {at_once * 1e3:.0f} ms between two jobs; busy: {rested * 1e3:.0f} ms")
    assert rested > 2.5 * at_once  # 4× the job's time, jobs vary a little


def test_the_child_ends_when_the_server_is_killed(database, tmp_path):
    """A server killed with SIGKILL leaves no processing child behind: the child sees the
    pipe close (a ``ProcessPoolExecutor``'s workers would stay)."""
    url, _, _ = database
    script = tmp_path / "server.py"
    script.write_text(textwrap.dedent(f"""
        import time
        from armtrack.server.store.background import SessionProcessing
        if __name__ == "__main__":
            processing = SessionProcessing({url!r}, 1, 1, lambda *_: None)
            processing.start()
            print("started", flush=True)
            time.sleep(600)
        """))
    server = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        assert server.stdout.readline().strip() == "started"
        deadline = time.monotonic() + 30
        while not _children_named(PROCESSING, server.pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        [child] = _children_named(PROCESSING, server.pid)
        server.kill()
        server.wait()
        deadline = time.monotonic() + 30
        while Path(f"/proc/{child}").exists() and time.monotonic() < deadline:
            state = Path(f"/proc/{child}/stat").read_text().rsplit(")", 1)[1].split()[0] \
                if Path(f"/proc/{child}").exists() else "gone"
            if state == "Z":
                break  # ended; only its parent (now init) has to reap it
            time.sleep(0.05)
        alive = Path(f"/proc/{child}").exists() and Path(
            f"/proc/{child}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
        assert not alive, f"processing child {child} outlived the killed server"
    finally:
        if server.poll() is None:
            server.kill()



def test_a_child_outlives_the_thread_that_started_it(database):
    """The child is started when a job comes (``submit``), often from a worker thread
    that ends soon after, while the child still imports (a second or more). The child
    must live on and do the job: one that asked to end with its parent (Linux's
    PR_SET_PDEATHSIG means the thread that started it, not the process) died with that
    thread and failed the job."""
    url, engine, (_, _, third) = database
    processing = SessionProcessing(url, 1, 1, lambda *_: None)
    given: list = []
    try:
        starter = threading.Thread(target=lambda: given.append(
            processing.submit(third, "qcf")) or time.sleep(0.3))
        starter.start()
        starter.join()  # it ends while the child it started still imports
        given[0].result(timeout=120)
        assert len(_estimates(engine, third)[1]) > 1000
    finally:
        processing.stop()
