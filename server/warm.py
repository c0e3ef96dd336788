"""Build armtrack's compiled kernels before the first patient needs them.

numba compiles each kernel the first time it runs and caches it on disk
(``estimator/jit.py``): on a fresh install the first live session showed no angle for
about 55 s and the first session's processing took 32 s while that happened. ``warm``
runs the server's own code paths on three short simulated sessions (kits of three
sensors, 9-axis and 6-axis, and a 6-axis phone on the forearm): the kit messages' checks, the live
estimation message by message, and a closed session's estimation. Afterwards every
process of the server (the live estimation, the processing) loads the kernels from the
cache in a fraction of a second. ``armtrack warm`` runs it by hand (and the Docker image
at build time); the server's processing process runs it at start, on CPU time nothing
else wants (``store/background.py``)."""

from __future__ import annotations

import time


def warm() -> float:
    """Compile, or load from the cache, every kernel the server runs; the seconds taken."""
    from armtrack.estimator.pipeline import PipelineConfig, run_recording
    from armtrack.estimator.simulation import ImuErrors, SimulationConfig, simulate

    from .emulator.messages import MessagePlan, hello_message
    from .ingest.protocol import check_hello, check_mark, check_samples, parse
    from .live.estimator import LiveEstimator

    start = time.monotonic()
    kits = (SimulationConfig(exercise="elbow_flexion", repetitions=1, seed=1),
            # headings from gyroscopes alone: the arm's mean heading (pipeline.session)
            SimulationConfig(exercise="elbow_flexion", nine_axis=False, repetitions=1, seed=1),
            SimulationConfig(exercise="elbow_flexion", sensors=("forearm",), rate_hz=60.0,
                             nine_axis=False, repetitions=1, seed=1,
                             errors=ImuErrors(gyro_noise=0.01, acc_noise=0.1)))
    for config in kits:
        recording = simulate(config).recording
        hello = check_hello(hello_message(recording, "warm-up"))
        live = LiveEstimator(PipelineConfig(side=recording.side,
                                            lengths=recording.segment_lengths(),
                                            sensors=tuple(recording.sensors)),
                             session_id=0, max_rate_hz=1e6)
        plan = MessagePlan(recording)
        last_t: dict[str, float] = {}
        for seq in range(len(plan)):
            message = parse(plan.encode(seq))
            if message["type"] == "mark":  # the calibration poses' marks
                live.process([check_mark(message, seq)])
                continue
            samples = check_samples(message, seq, hello, last_t)
            last_t[samples.sensor] = float(samples.rows[-1, 0])
            live.process([samples])
        run_recording(recording).finish()
    return time.monotonic() - start
