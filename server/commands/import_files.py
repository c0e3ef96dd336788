"""``armtrack import``: vendor exports (Movella DOT, APDM Opal, Shimmer, MetaMotion,
Sensor Logger, any CSV with a column map) → a strict recording file.

Sensors are given as ``SENSOR=PATH[:LABEL]``: PATH a file, a folder or a zip; LABEL picks
one sensor of a file that holds several (an APDM ``.h5``, a Shimmer file of two devices);
the same SENSOR given twice groups several files into one sensor (MetaMotion's files per
signal). Heavy modules are imported in :func:`run` only.
"""

from __future__ import annotations

import argparse
from pathlib import Path

SENSORS = ("trunk", "clavicle", "upper_arm", "forearm", "hand")

HELP = ("vendor IMU exports (Movella DOT, APDM, Shimmer, MetaMotion, Sensor Logger, CSV) to a "
        "recording")
DESCRIPTION = ("Reads vendor exports into a strict recording (docs/spec/recording.md): "
               "SENSOR=PATH[:LABEL] per sensor (a file, folder or zip; LABEL picks one sensor "
               "of a file that holds several; repeat SENSOR for several files of one sensor), "
               "puts the sensors on one clock and checks them. See docs/importing.md.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("specs", nargs="+", metavar="SENSOR=PATH[:LABEL]",
                        help=f"SENSOR one of {', '.join(SENSORS)}; PATH a file, folder or zip; "
                        "LABEL the sensor's label or id inside PATH when it holds several. "
                        "Repeat SENSOR to give one sensor several files. With --inspect: "
                        "just PATHs")
    parser.add_argument("--format", metavar="NAME",
                        help="xsens-dot, apdm, shimmer, metamotion, sensor-logger or generic "
                        "(default: detected from the files)")
    parser.add_argument("--inspect", action="store_true",
                        help="list the sensors found in the PATHs (label, rate, duration) "
                        "and write nothing")
    parser.add_argument("--side", choices=("right", "left"))
    size = parser.add_mutually_exclusive_group()
    size.add_argument("--height", type=float, metavar="METRES", help="body height")
    size.add_argument("--lengths", metavar="C,U,F,H",
                      help="measured clavicle, upper arm, forearm, hand lengths in metres")
    parser.add_argument("--calibration", metavar="POSES",
                        help="'npose START END; tpose START END' in seconds of the imported "
                        "recording, or 'auto' to take the proposed still periods; without it "
                        "a proposal is printed and the file has no poses")
    parser.add_argument("--columns", metavar="MAP",
                        help="generic CSV: 't=COL:UNIT ax=COL:UNIT … [mx=COL:UNIT …] "
                        "[sensor=COL]'; a '-' before COL flips the sign")
    parser.add_argument("--mag-field", type=float, default=50.0, metavar="UT",
                        help="µT one magnetometer a.u. stands for (Movella DOT; default 50)")
    parser.add_argument("--platform", choices=("android", "ios", "standardised"),
                        help="Sensor Logger: the phone's platform when its metadata.csv is "
                        "missing ('standardised' when Standardise Units & Frames was on)")
    parser.add_argument("-o", "--output", type=Path, metavar="FILE",
                        help="the recording to write (docs/spec/recording.md)")


def parse_spec(spec: str) -> tuple[str, Path, str | None]:
    """``SENSOR=PATH[:LABEL]`` → (sensor, path, label). A ``:`` belongs to the path when
    the whole text names an existing file (``C:\\data\\x.csv``)."""
    from armtrack.estimator.errors import InvalidArgument

    sensor, eq, rest = spec.partition("=")
    if not eq or not rest:
        raise InvalidArgument(f"{spec!r}: expected SENSOR=PATH[:LABEL], e.g. forearm=dot2.csv")
    if sensor not in SENSORS:
        raise InvalidArgument(f"{spec!r}: unknown sensor {sensor!r} (one of {', '.join(SENSORS)})")
    path, label = Path(rest), None
    if not path.exists() and ":" in rest:
        head, _, tail = rest.rpartition(":")
        if head and "/" not in tail and "\\" not in tail:
            path, label = Path(head), tail or None
    if not path.exists():
        raise InvalidArgument(f"{spec!r}: no file or folder {str(path)!r}")
    return sensor, path, label


def run(args: argparse.Namespace) -> int:
    from armtrack.estimator.body import SegmentLengths
    from armtrack.estimator.errors import InvalidArgument
    from armtrack.estimator.importers import (
        Assignment,
        ReadOptions,
        describe,
        import_recording,
        read_signals,
    )
    from armtrack.estimator.importers.sources import expand
    from armtrack.estimator.recording import write_recording

    options = ReadOptions(field_ut=args.mag_field, columns=args.columns, platform=args.platform)
    if args.columns and not args.format:
        args.format = "generic"
    if args.inspect:
        for spec in args.specs:
            path = Path(spec.partition("=")[2] if "=" in spec and not Path(spec).exists()
                        else spec)
            for signal in read_signals(expand(path), args.format, options):
                d = describe(signal)
                print(f"{path}: {d['label']} ({d['format']}), {d['axes']} axes, "
                      f"{d['rate_hz']:g} Hz, {d['duration_s']:g} s, {d['samples']} samples, "
                      f"clock {d['clock']}")
        return 0
    if args.output is None or args.side is None or (args.height is None and not args.lengths):
        raise InvalidArgument("armtrack import needs -o FILE, --side and --height (or "
                              "--lengths); vendor files carry no side or body size")
    grouped: dict[str, Assignment] = {}
    for spec in args.specs:
        sensor, path, label = parse_spec(spec)
        a = grouped.setdefault(sensor, Assignment(sensor, [], label, args.format))
        if label and a.label and label != a.label:
            raise InvalidArgument(f"{sensor}: two labels given ({a.label}, {label})")
        a.label = a.label or label
        a.sources.extend(expand(path))
    lengths = None
    if args.lengths:
        try:
            values = [float(v) for v in args.lengths.split(",")]
            lengths = SegmentLengths(*values)
        except (TypeError, ValueError):
            raise InvalidArgument(f"--lengths must be four numbers C,U,F,H in metres, got "
                                  f"{args.lengths!r}") from None
    result = import_recording(list(grouped.values()), side=args.side, height_m=args.height,
                              calibration=args.calibration, options=options, lengths=lengths)
    write_recording(result.recording, args.output)
    rec = result.recording
    print(f"wrote {args.output}: {rec.side} arm, {len(rec.sensors)} sensor(s), "
          f"{rec.duration:.1f} s")
    for sensor, s in result.signals.items():
        d = describe(s)
        print(f"  {sensor:<10} {d['label']} ({d['format']}), {d['axes']} axes, "
              f"{d['rate_hz']:g} Hz, {d['duration_s']:.1f} s")
    for note in result.notes:
        print(f"  note: {note}")
    if rec.calibration:
        print("  calibration: " + "; ".join(f"{p.name} {p.start:g} {p.end:g}"
                                            for p in rec.calibration))
    elif result.proposal:
        print("  no calibration given; still periods that look like the poses:\n"
              f"    --calibration \"{result.proposal}\"\n"
              "  check them against the session and import again with that option "
              "(or --calibration auto)")
    else:
        print("  no calibration given and no still periods that look like the poses: the "
              "default mounting will be assumed")
    return 0
