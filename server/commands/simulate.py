"""``armtrack simulate``: write a simulated recording and its ground truth."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from armtrack.estimator.body import SENSOR_NAMES
from armtrack.estimator.errors import InvalidArgument

from .choices import EXERCISE_NAMES

HELP = "write a simulated recording with its ground truth"
DESCRIPTION = ("Simulates an exercise session (calibration poses, then the exercise) with "
               "exact IMU physics, sensor mounting, noise, gyroscope bias and optional faults; "
               "writes the recording and a truth CSV of joint angles (deg) and positions (m).")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--exercise", default="elbow_flexion", choices=sorted(EXERCISE_NAMES))
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="FILE",
                        help="the recording to write (docs/spec/recording.md)")
    parser.add_argument("--truth", type=Path, metavar="FILE",
                        help="where to write the ground truth (default: FILE with .truth.csv)")
    parser.add_argument("--side", choices=("right", "left"), default="right")
    parser.add_argument("--height", type=float, default=1.75, metavar="METRES")
    parser.add_argument("--rate", type=float, default=100.0, metavar="HZ")
    parser.add_argument("--six-axis", action="store_true", help="no magnetometer")
    parser.add_argument("--sensors", default="upper_arm,forearm,hand",
                        help=f"comma-separated, of {', '.join(SENSOR_NAMES)}")
    parser.add_argument("--reps", type=int, help="repetitions (default: the exercise's)")
    parser.add_argument("--amplitude", type=float, metavar="DEGREES",
                        help="peak of the main joint (default: the exercise's)")
    parser.add_argument("--lost", type=float, default=0.0, metavar="FRACTION",
                        help="share of samples lost at random, e.g. 0.02")
    parser.add_argument("--jitter-ms", type=float, default=0.0, help="timestamp jitter")
    parser.add_argument("--bias-walk", type=float, default=0.0, metavar="RAD_S_PER_SQRT_S",
                        help="gyroscope bias random walk, e.g. 2e-4 (drifts over a session)")
    parser.add_argument("--magnet", action="store_true",
                        help="a magnet near the hand's path disturbs the magnetometers")
    parser.add_argument("--no-calibration", action="store_true",
                        help="skip the N-pose/T-pose sequence at the start")
    parser.add_argument("--wrist-points", choices=("robot", "camera"),
                        help="also write the wrist's position as an end-effector robot "
                        "(100 Hz, 0.5 mm) or a camera (30 Hz, 2-5 mm, latency, dropouts) "
                        "gives it: the recording's points extension (docs/extensions/points.md)")
    parser.add_argument("--seed", type=int, default=0)


def run(args: argparse.Namespace) -> int:
    from armtrack.estimator.recording import write_recording
    from armtrack.estimator.simulation import SimulationConfig, simulate, write_truth

    sensors = tuple(s.strip() for s in args.sensors.split(",") if s.strip())
    unknown = [s for s in sensors if s not in SENSOR_NAMES]
    if unknown:
        raise InvalidArgument(f"unknown sensor(s) {unknown}; one of {', '.join(SENSOR_NAMES)}")
    config = SimulationConfig(
        exercise=args.exercise, side=args.side, height_m=args.height, rate_hz=args.rate,
        nine_axis=not args.six_axis, sensors=sensors, repetitions=args.reps,
        amplitude_deg=args.amplitude, calibration=not args.no_calibration, seed=args.seed,
        jitter_s=args.jitter_ms / 1000.0, lost_fraction=args.lost,
        magnet_near_hand=args.magnet, wrist_points=args.wrist_points,
        errors=replace(SimulationConfig().errors, gyro_bias_walk=args.bias_walk))
    result = simulate(config)
    truth_path = args.truth or args.output.with_name(
        args.output.name.removesuffix(".csv") + ".truth.csv")
    write_recording(result.recording, args.output)
    write_truth(result.truth, truth_path)
    rows = sum(len(s) for s in result.recording.sensors.values())
    points = "".join(f", {len(p)} {name} points" for name, p in result.recording.points.items())
    print(f"wrote {args.output} ({rows} rows, {len(sensors)} sensors{points}, "
          f"{result.truth.t[-1]:.1f} s) and its truth {truth_path}")
    return 0
