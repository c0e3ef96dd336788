"""The ``armtrack`` command line.

Each sub-command is a thin shell over the estimator: argument parsing, clear messages,
exit codes (0 success, 2 bad input, with the message on standard error).
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from armtrack.estimator.errors import EstimatorError


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="armtrack",
        description="Remote arm rehabilitation: IMU recordings in, joint angles and the "
        "arm's pose out. Angles follow spec/kinematics.md (degrees at this edge).",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    pose = commands.add_parser(
        "pose",
        help="the arm's pose (segment orientations, joint positions) from joint angles",
        description="Forward kinematics of the 9-DoF arm. Give angles as NAME=DEGREES "
        "(e.g. shoulder_abduction=90 elbow_flexion=45), or a CSV of angles over time with "
        "--angles-csv (columns t and any of the joint-angle names, in degrees). Positions "
        "are in the thorax frame (X anterior, Y superior, Z right), in metres.",
    )
    pose.add_argument("angles", nargs="*", metavar="NAME=DEGREES")
    pose.add_argument("--side", choices=("right", "left"), default="right")
    size = pose.add_mutually_exclusive_group()
    size.add_argument("--height", type=float, default=1.75, metavar="METRES",
                      help="body height for the segment lengths (default 1.75)")
    size.add_argument("--lengths", metavar="C,U,F,H",
                      help="measured clavicle, upper arm, forearm, hand lengths in metres")
    pose.add_argument("--angles-csv", type=Path, metavar="FILE",
                      help="angles over time; writes a CSV of positions")
    pose.add_argument("-o", "--output", type=Path, metavar="FILE",
                      help="where to write the positions CSV (default: standard output)")
    pose.add_argument("--json", action="store_true", help="print one pose as JSON")

    check = commands.add_parser(
        "check",
        help="validate a recording file and summarise it",
        description="Reads a recording (spec/recording.md) with every rule checked; prints "
        "its sensors, rates, lost samples, calibration and marks, or the line and rule "
        "it breaks.",
    )
    check.add_argument("recording", type=Path)
    check.add_argument("--json", action="store_true", help="print the summary as JSON")

    simulate = commands.add_parser(
        "simulate",
        help="write a simulated recording with its ground truth",
        description="Simulates an exercise session (calibration poses, then the exercise) "
        "with exact IMU physics, sensor mounting, noise, gyroscope bias and optional faults; "
        "writes the recording and a truth CSV of joint angles (deg) and positions (m).",
    )
    from .commands import create_user, demo, estimate, orient, reprocess, serve, stream
    from .commands.simulate import add_arguments

    add_arguments(simulate)
    estimate.add_arguments(commands.add_parser(
        "estimate", help="joint angles and positions of a recording, with its range of motion",
        description="Calibrates from the recording's poses, runs an orientation filter per "
        "sensor and writes per-sample t, every joint angle of spec/kinematics.md (degrees), "
        "shoulder_elevation and shoulder_x … hand_z (metres, thorax frame); prints the "
        "range of motion against normal values."))
    orient.add_arguments(commands.add_parser(
        "orient", help="one sensor's orientation (quaternion, sensor to earth ENU)",
        description="Runs an orientation filter on one IMU: input t,ax,ay,az,gx,gy,gz,"
        "mx,my,mz; output t,qw,qx,qy,qz (R_world_sensor, earth x east, y north, z up)."))
    stream.add_arguments(commands.add_parser(
        "stream", help="play a recording to the server as a sensor kit (spec/ingest.md)",
        description="Connects to the ingest WebSocket with a device token and streams a "
        "recording (or a simulated exercise) paced by its clock, resuming after a lost "
        "connection; prints progress to standard error and a summary at the end."))
    serve.add_arguments(commands.add_parser(
        "serve", help="run the server (REST API, ingest WebSocket, dashboard)",
        description="Runs armtrack under uvicorn. Settings come from the environment "
        "(ARMTRACK_DATABASE_URL, ARMTRACK_DATA_DIR, ARMTRACK_HOST, ARMTRACK_PORT, ...) and "
        "these flags; the database is migrated on start."))
    demo.add_arguments(commands.add_parser(
        "demo", help="run the server with a simulated patient streaming exercises",
        description="Starts the server (SQLite in ./armtrack-demo), makes a demo therapist "
        "(user demo, a password printed each run), a patient and a kit, and streams a "
        "simulated patient (calibration poses, then exercises in a loop) through the real "
        "protocol in real time. Prints the address and the sign-in; Ctrl-C stops."))
    create_user.add_arguments(commands.add_parser(
        "create-user", help="make a therapist account",
        description="Creates a therapist who can sign in; the password comes from "
        "--password or standard input."))
    from .commands import import_files

    import_files.add_arguments(commands.add_parser(
        "import", help="vendor IMU exports (Movella DOT, APDM, Shimmer, MetaMotion, Sensor "
        "Logger, CSV) to a recording",
        description="Reads vendor exports into a strict recording (spec/recording.md): "
        "SENSOR=PATH[:LABEL] per sensor (a file, folder or zip; LABEL picks one sensor of a "
        "file that holds several; repeat SENSOR for several files of one sensor), puts the "
        "sensors on one clock and checks them. See docs/importing.md."))
    reprocess.add_arguments(commands.add_parser(
        "reprocess", help="recompute stored sessions' estimates with this estimator",
        description="Re-estimates sessions from their stored raw data and records the "
        "estimator version and settings used."))
    return parser


#: Commands whose module is not their name (``import`` is a Python keyword).
COMMAND_MODULES = {"import": "import_files"}


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        # one module per command, each with run(args); imported only when used
        module = COMMAND_MODULES.get(args.command, args.command.replace("-", "_"))
        command = importlib.import_module(f".commands.{module}", __package__)
        return command.run(args)
    except EstimatorError as exc:
        print(f"armtrack {args.command}: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader went away (`armtrack … | head`): stop quietly, as Unix tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:
        print(f"armtrack {args.command}: {exc}", file=sys.stderr)
        return 2


def print_json(value: object) -> None:
    print(json.dumps(value, indent=2))


if __name__ == "__main__":
    raise SystemExit(main())
