"""Simulated wrist points, as an end-effector robot or a camera gives them
(``docs/extensions/points.md``).

Both give the wrist in their own z-up base frame — here the simulation's world (ENU) —
with the set-up step's shoulder (the handle held at the shoulder, exact here: see
``shoulder_error_m``) and the direction the patient faces.

- **robot**: its handle at the wrist, 100 Hz, stamped on the kit's clock, 0.5 mm noise.
- **camera**: 30 Hz, 2–5 mm noise (drawn per session), dropouts (a marker hidden for
  0.2–1.5 s about every 10 s), and a latency of 40–80 ms (drawn per session) of which
  the declared 60 ms is taken off: stamps are late by the rest (±20 ms), plus 1 ms jitter.

Units: s, m.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..body import SegmentLengths
from ..recording.points import PointsFrame, PointStream
from .body_motion import Stance, body_motion
from .profiles import Motion


@dataclass(frozen=True)
class WristSource:
    """How a position source samples the wrist: ``rate_hz``; noise σ per axis [m] drawn
    from ``noise_m`` (low, high) per session; ``latency_s`` (low, high) true latency and
    the ``declared_latency_s`` the kit takes off its stamps; ``jitter_s`` stamp jitter;
    ``dropout_every_s`` mean time between dropouts (0: none) of ``dropout_s`` (low, high)."""

    rate_hz: float
    noise_m: tuple[float, float]
    latency_s: tuple[float, float] = (0.0, 0.0)
    declared_latency_s: float = 0.0
    jitter_s: float = 0.0
    dropout_every_s: float = 0.0
    dropout_s: tuple[float, float] = (0.0, 0.0)
    shoulder_error_m: float = 0.0


WRIST_SOURCES: dict[str, WristSource] = {
    "robot": WristSource(rate_hz=100.0, noise_m=(0.0005, 0.0005)),
    "camera": WristSource(rate_hz=30.0, noise_m=(0.002, 0.005), latency_s=(0.040, 0.080),
                          declared_latency_s=0.060, jitter_s=0.001, dropout_every_s=10.0,
                          dropout_s=(0.2, 1.5)),
}


def wrist_points(source: WristSource, motion: Motion, config, lengths: SegmentLengths,
                 stance: Stance, duration: float, rng: np.random.Generator
                 ) -> tuple[dict[str, PointStream], PointsFrame]:
    """The wrist's points over ``duration`` [s] and their base frame (the world)."""
    n = int(np.floor(duration * source.rate_hz)) + 1
    capture = np.arange(n) / source.rate_hz
    keep = np.ones(n, dtype=bool)
    if source.dropout_every_s:
        at = 0.0
        while True:
            at += rng.exponential(source.dropout_every_s)
            if at >= duration:
                break
            length = rng.uniform(*source.dropout_s)
            keep &= ~((capture >= at) & (capture < at + length))
            at += length
    capture = capture[keep]
    body = body_motion(motion, config.side, lengths, capture, stance)
    sigma = rng.uniform(*source.noise_m)
    p = body.points["wrist"].p + rng.normal(0.0, sigma, (len(capture), 3))
    late = rng.uniform(*source.latency_s) - source.declared_latency_s
    t = capture + late + (rng.uniform(-source.jitter_s, source.jitter_s, len(capture))
                          if source.jitter_s else 0.0)
    t = np.maximum.accumulate(t)  # a kit's stamps never go backwards
    rest = body_motion(motion, config.side, lengths, np.zeros(1), stance)
    shoulder = rest.points["shoulder"].p[0] + rng.normal(0.0, source.shoulder_error_m, 3) \
        if source.shoulder_error_m else rest.points["shoulder"].p[0]
    frame = PointsFrame("base", thorax_yaw_deg=float(config.heading_deg),
                        shoulder_m=tuple(float(v) for v in shoulder))
    return {"wrist": PointStream(t, p)}, frame
