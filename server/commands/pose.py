"""``armtrack pose``: forward kinematics from the command line."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.errors import InvalidArgument

from .output import open_output

HELP = "the arm's pose (segment orientations, joint positions) from joint angles"
DESCRIPTION = ("Forward kinematics of the 9-DoF arm. Give angles as NAME=DEGREES "
               "(e.g. shoulder_abduction=90 elbow_flexion=45), or a CSV of angles over time "
               "with --angles-csv (columns t and any of the joint-angle names, in degrees). "
               "Positions are in the thorax frame (X anterior, Y superior, Z right), in metres.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("angles", nargs="*", metavar="NAME=DEGREES")
    parser.add_argument("--side", choices=("right", "left"), default="right")
    size = parser.add_mutually_exclusive_group()
    size.add_argument("--height", type=float, default=1.75, metavar="METRES",
                      help="body height for the segment lengths (default 1.75)")
    size.add_argument("--lengths", metavar="C,U,F,H",
                      help="measured clavicle, upper arm, forearm, hand lengths in metres")
    parser.add_argument("--angles-csv", type=Path, metavar="FILE",
                        help="angles over time; writes a CSV of positions")
    parser.add_argument("-o", "--output", type=Path, metavar="FILE",
                        help="where to write the positions CSV (default: standard output)")
    parser.add_argument("--json", action="store_true", help="print one pose as JSON")


def _lengths(args: argparse.Namespace) -> SegmentLengths:
    if args.lengths is None:
        return SegmentLengths.from_height(args.height)
    try:
        values = [float(v) for v in args.lengths.split(",")]
    except ValueError:
        values = []
    if len(values) != 4:
        raise InvalidArgument(
            f"--lengths takes four numbers in metres, clavicle,upper_arm,forearm,hand; "
            f"got {args.lengths!r}")
    return SegmentLengths(*values)


def _parse_assignments(items: list[str]) -> dict[str, float]:
    from armtrack.estimator.arm import ANGLE_NAMES

    angles: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise InvalidArgument(f"expected NAME=DEGREES, got {item!r}")
        if name not in ANGLE_NAMES:
            raise InvalidArgument(f"unknown joint angle {name!r}; one of {', '.join(ANGLE_NAMES)}")
        try:
            degrees = float(value)
        except ValueError:
            raise InvalidArgument(f"{name}: {value!r} is not a number of degrees") from None
        if not math.isfinite(degrees):
            raise InvalidArgument(f"{name}: {value!r} is not a finite number of degrees")
        angles[name] = degrees
    return angles


def _read_angles_csv(path):
    """``t [s], {name: angle [rad]}`` of an angles CSV, checked."""
    import numpy as np
    from armtrack.estimator.arm import ANGLE_NAMES

    with open(path, encoding="utf-8") as file:
        header = file.readline().strip().split(",")
    if "t" not in header:
        raise InvalidArgument(f"{path}: line 1: the header needs a column t (seconds)")
    wanted = [name for name in header if name in ANGLE_NAMES]
    if not wanted:
        raise InvalidArgument(
            f"{path}: line 1: no joint-angle column; expected some of {', '.join(ANGLE_NAMES)}")
    try:
        table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2,
                           usecols=[header.index(n) for n in ["t", *wanted]])
    except ValueError as exc:
        raise InvalidArgument(f"{path}: {exc}") from None
    if not np.isfinite(table).all():
        row = int(np.flatnonzero(~np.isfinite(table).all(axis=1))[0])
        raise InvalidArgument(f"{path}: line {row + 2}: non-finite value")
    return table[:, 0], {name: np.deg2rad(table[:, i + 1]) for i, name in enumerate(wanted)}


def run(args: argparse.Namespace) -> int:
    import numpy as np
    from armtrack.estimator.arm import ANGLE_NAMES, POINTS, forward_kinematics, joint_angles
    from armtrack.estimator.scalar_rotations import quat_from_rows

    lengths = _lengths(args)
    if args.angles_csv is not None:
        if args.angles:
            raise InvalidArgument("give angles either as NAME=DEGREES or with --angles-csv")
        t, angles = _read_angles_csv(args.angles_csv)
        pose = forward_kinematics(angles, args.side, lengths)
        columns = ["t"] + [f"{p}_{a}" for p in POINTS for a in "xyz"]
        table = np.column_stack([t, *(pose.p_thorax[p] for p in POINTS)])
        with open_output(args.output) as out:
            out.write(",".join(columns) + "\n")
            np.savetxt(out, table, delimiter=",", fmt=["%.5f"] + ["%.6f"] * 12)
        return 0

    degrees = _parse_assignments(args.angles)
    pose = forward_kinematics({k: np.deg2rad(v) for k, v in degrees.items()}, args.side, lengths)
    elevation = np.rad2deg(joint_angles({k: v[None] for k, v in pose.R_thorax.items()
                                         if k != "thorax"}, args.side)
                           .angles["shoulder_elevation"][0])
    result = {
        "side": args.side,
        "lengths_m": lengths.as_dict(),
        "angles_deg": {name: degrees.get(name, 0.0) for name in ANGLE_NAMES},
        "shoulder_elevation_deg": float(elevation),
        "positions_m": {p: pose.p_thorax[p].tolist() for p in POINTS},
        "orientations_wxyz": {s: list(quat_from_rows(*R.ravel().tolist()))
                              for s, R in pose.R_thorax.items()},
    }
    if args.json:
        from ..cli import print_json

        print_json(result)
        return 0
    shown = ", ".join(f"{k} {v:g}" for k, v in degrees.items()) or "all 0 (the N-pose)"
    print(f"{args.side} arm; lengths (m): "
          + ", ".join(f"{k} {v:.3f}" for k, v in lengths.as_dict().items()))
    print(f"joint angles (deg): {shown}; shoulder elevation {elevation:.1f}")
    print("positions in the thorax frame (X anterior, Y superior, Z right), metres:")
    print(f"  {'point':<9}{'x':>8}{'y':>8}{'z':>8}")
    for point in POINTS:
        x, y, z = pose.p_thorax[point]
        print(f"  {point:<9}{x:8.3f}{y:8.3f}{z:8.3f}")
    print("segment orientations in the thorax frame (quaternion w, x, y, z):")
    for segment, R in pose.R_thorax.items():
        if segment != "thorax":
            q = quat_from_rows(*R.ravel().tolist())
            print(f"  {segment:<10}" + " ".join(f"{c:7.4f}" for c in q))
    return 0
