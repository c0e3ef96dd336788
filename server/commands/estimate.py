"""``armtrack estimate``: joint angles and positions of a recording, and its range of motion."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from armtrack.estimator.errors import InvalidArgument

from .choices import DEFAULT_FILTER, FILTER_NAMES
from .output import open_output, write_angles_csv

HELP = "joint angles and positions of a recording, with its range of motion"
DESCRIPTION = ("Calibrates from the recording's poses, runs an orientation filter per sensor "
               "and writes per-sample t, every joint angle of docs/spec/kinematics.md "
               "(degrees), shoulder_elevation and shoulder_x … hand_z (metres, thorax frame); "
               "prints the range of motion against normal values.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", type=Path)
    parser.add_argument("-o", "--output", type=Path, metavar="FILE",
                        help="the angles CSV to write (default: standard output)")
    parser.add_argument("--filter", choices=sorted(FILTER_NAMES), default=DEFAULT_FILTER,
                        help=f"orientation filter (default {DEFAULT_FILTER})")
    parser.add_argument("--gyro-bias-in", type=Path, metavar="FILE",
                        help="start each sensor's filter from the gyroscope bias the kit "
                             "remembered (JSON, docs/gyro-bias-memory.md; qcf only)")
    parser.add_argument("--gyro-bias-out", type=Path, metavar="FILE",
                        help="write the kit's memory after this recording: the biases "
                             "stillness taught, else those of --gyro-bias-in (may be the "
                             "same file)")


def run(args: argparse.Namespace) -> int:
    from armtrack.estimator.metrics import (
        BOTH_WAYS,
        calibration_exclusion,
        count_repetitions,
        range_of_motion_table,
        repetitions_by_angle,
    )
    from armtrack.estimator.orientation import BIAS_PRIOR_FILTERS
    from armtrack.estimator.pipeline import run_recording
    from armtrack.estimator.pipeline.bias_memory import (
        memory_to_json,
        priors,
        read_bias_memory,
        remember,
    )
    from armtrack.estimator.pipeline.quality import residual_warnings
    from armtrack.estimator.recording import read_recording

    if args.gyro_bias_in and args.filter not in BIAS_PRIOR_FILTERS:
        raise InvalidArgument(f"--gyro-bias-in needs a filter that starts from a remembered "
                              f"bias: {', '.join(sorted(BIAS_PRIOR_FILTERS))} (got --filter "
                              f"{args.filter})")
    if args.gyro_bias_out and args.filter not in BIAS_PRIOR_FILTERS:
        raise InvalidArgument(f"--gyro-bias-out needs a filter that learns a bias: "
                              f"{', '.join(sorted(BIAS_PRIOR_FILTERS))}")
    memory = read_bias_memory(args.gyro_bias_in) if args.gyro_bias_in else {}
    recording = read_recording(args.recording)
    pipeline = run_recording(recording, args.filter, priors(memory) if memory else None)
    estimates, calibration = pipeline.finish(), pipeline.calibration
    assert calibration is not None
    columns, values = estimates.table()
    exclude = calibration_exclusion(float(estimates.t[0]) if len(estimates) else 0.0,
                                    (p.end for p in recording.calibration)) or None
    # every step that can fail comes before the file is written: a failed command leaves
    # no angles file behind
    table = range_of_motion_table(estimates.angles, estimates.t, exclude=exclude)
    repetitions = (repetitions_by_angle({k: estimates.angles[k] for k in table},
                                        estimates.t, exclude=exclude) if table else {})
    learnt = pipeline.learnt_biases()
    with open_output(args.output) as out:
        write_angles_csv(out, columns, values)
    if args.gyro_bias_out:
        with open_output(args.gyro_bias_out) as out:
            json.dump(memory_to_json(remember(memory, learnt)), out, indent=2)
            out.write("\n")

    report = sys.stderr if args.output is None else sys.stdout
    print(f"{args.recording}: {len(estimates)} estimates, filter {args.filter}, calibration "
          f"{calibration.method}" + (f", written to {args.output}" if args.output else ""),
          file=report)
    if pipeline.gamma is not None:
        stats = pipeline.gamma.stats
        check = ("" if stats.disagreement_rms_deg is None else
                 f"; the points' elbow flexion differs from the IMUs' by "
                 f"{stats.disagreement_rms_deg:.1f}° RMS")
        source = "forearm IMU" if pipeline.elbow_source == "imu" else "wrist points (γ)"
        print(f"  elbow: from the {source}, upper-arm heading from the wrist points; heading "
              f"held in {stats.flagged_share:.0%} of samples (wrist near below the shoulder, or no "
              f"point){check}", file=report)
    if args.gyro_bias_in or args.gyro_bias_out:
        for name, value in learnt.items():
            print(f"  gyroscope bias {name}: {_bias_words(value, name in memory)}", file=report)
    for warning in (*calibration.warnings,
                    *residual_warnings(estimates, tuple(recording.sensors))):
        print(f"  warning: {warning.message}", file=report)
    if not table:
        print("  no joint moved more than the noise", file=report)
        return 0
    print(f"  {'range of motion (deg)':<24}{'min':>8}{'max':>8}{'range':>8}{'normal':>12}"
          f"{'% normal':>10}{'reps':>6}", file=report)
    for name, rom in table.items():
        normal = ("" if rom.normal_min_deg is None
                  else f"{rom.normal_min_deg:.0f}…{rom.normal_max_deg:.0f}")
        percent = "" if rom.percent_of_normal is None else f"{rom.percent_of_normal:.0f}"
        print(f"  {name:<24}{rom.min_deg:8.1f}{rom.max_deg:8.1f}{rom.range_deg:8.1f}"
              f"{normal:>12}{percent:>10}"
              f"{count_repetitions(repetitions[name], name in BOTH_WAYS):>6}", file=report)
    return 0


def _bias_words(value, remembered: bool) -> str:
    """How a sensor's gyroscope bias came out of the session, for the report."""
    mrad = " ".join(f"{1e3 * b:+.2f}" for b in value.bias)
    if value.remembered:
        return (f"[{mrad}] mrad/s, learnt from {value.still_s:.1f} s of stillness "
                f"({value.learnt}), {value.age_s:.0f} s before the end; remembered")
    start = "the remembered one" if remembered else "zero"
    return (f"[{mrad}] mrad/s, never still: not learnt (started from {start}); "
            + ("the older memory is kept" if remembered else "nothing remembered"))
