"""``armtrack check``: validate a recording and summarise what it holds."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "validate a recording file and summarise it"
DESCRIPTION = ("Reads a recording (docs/spec/recording.md) with every rule checked; prints "
               "its sensors, rates, lost samples, calibration and marks, or the line and rule "
               "it breaks.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", type=Path)
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")


def run(args: argparse.Namespace) -> int:
    from armtrack.estimator.recording import read_recording
    from armtrack.estimator.sampling import summarise_sampling

    recording = read_recording(args.recording)
    lengths = recording.segment_lengths()
    sensors = {}
    for name, stream in recording.sensors.items():
        timing = summarise_sampling(stream.t, recording.rate_hz)
        sensors[name] = {
            "axes": 9 if stream.mag is not None else 6,
            "samples": timing.samples,
            "start_s": timing.start_s,
            "end_s": timing.end_s,
            "rate_hz": round(timing.rate_hz, 3),
            "lost_samples": timing.lost,
            "lost_percent": round(100 * timing.lost_fraction, 2),
            "longest_gap_s": timing.longest_gap_s,
        }
    summary = {
        "file": str(args.recording),
        "side": recording.side,
        "height_m": recording.height_m,
        "lengths_m": lengths.as_dict(),
        "rate_hz": recording.rate_hz,
        "sensors": sensors,
        "calibration": [{"pose": p.name, "start_s": p.start, "end_s": p.end}
                        for p in recording.calibration],
        "marks": [{"t": m.t, "label": m.label} for m in recording.marks],
        "metadata": recording.metadata,
    }
    if recording.points_frame is not None:  # docs/extensions/points.md
        frame = recording.points_frame
        summary["points_frame"] = {"kind": frame.kind, "thorax_yaw_deg": frame.thorax_yaw_deg,
                                   "shoulder_m": frame.shoulder_m}
        summary["points"] = {name: {"samples": len(p), "start_s": float(p.t[0]),
                                    "end_s": float(p.t[-1])}
                             for name, p in recording.points.items()}
    if args.json:
        from ..cli import print_json

        print_json(summary)
        return 0
    print(f"{args.recording}: a valid recording (format {recording.version})")
    print(f"  {recording.side} arm; lengths (m): "
          + ", ".join(f"{k} {v:.3f}" for k, v in lengths.as_dict().items())
          + ("" if recording.lengths else f" (from height {recording.height_m} m)"))
    print(f"  {'sensor':<10}{'axes':>5}{'samples':>9}{'from s':>9}{'to s':>9}{'Hz':>8}"
          f"{'lost':>7}{'lost %':>8}")
    for name, s in sensors.items():
        print(f"  {name:<10}{s['axes']:>5}{s['samples']:>9}{s['start_s']:>9.2f}{s['end_s']:>9.2f}"
              f"{s['rate_hz']:>8.1f}{s['lost_samples']:>7}{s['lost_percent']:>8.2f}")
    for name, p in summary.get("points", {}).items():
        print(f"  point {name}: {p['samples']} positions, {p['start_s']:.2f}–{p['end_s']:.2f} s, "
              f"frame {recording.points_frame.kind}")
    poses = "; ".join(f"{p.name} {p.start:g}–{p.end:g} s" for p in recording.calibration)
    print(f"  calibration: {poses or 'none (the default mounting will be assumed)'}")
    if recording.marks:
        print("  marks: " + "; ".join(f"{m.t:g} s {m.label}" for m in recording.marks))
    if recording.metadata:
        print("  metadata: " + "; ".join(f"{k}: {v}" for k, v in recording.metadata.items()))
    return 0
