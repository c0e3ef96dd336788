"""The ``armtrack`` command line.

Each sub-command is a thin shell over the estimator or the server: argument parsing, clear
messages, exit codes (0 success, 2 bad input, with the message on standard error).

Start-up stays fast: building the parser imports each command module in
``armtrack.server.commands``, and those import only the standard library and light
constants at module level; numpy, scipy, numba, pyarrow, sqlalchemy, fastapi, uvicorn load
inside the command's ``run`` (tests/test_cli_startup.py checks this with a real process).
To add a command: a module ``server/commands/<name>.py`` with ``HELP``, ``DESCRIPTION``,
``add_arguments(parser)`` (light imports only) and ``run(args) -> int`` (heavy imports
inside), and its name in :data:`COMMANDS`.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
from collections.abc import Sequence

from armtrack.estimator.errors import EstimatorError
from armtrack.server.db.errors import DriverMissing, SchemaError

#: The sub-commands, in the order ``armtrack --help`` lists them; ``create-user`` is the
#: module ``commands/create_user.py``.
COMMANDS = ("pose", "check", "simulate", "estimate", "orient", "stream", "serve", "demo",
            "create-user", "import", "reprocess", "backup", "warm")
#: Commands whose module is not their name (``import`` is a Python keyword).
COMMAND_MODULES = {"import": "import_files"}


def command_module(name: str):
    """The module of the sub-command ``name`` (light: only its argument definitions)."""
    module = COMMAND_MODULES.get(name, name.replace("-", "_"))
    return importlib.import_module(f".commands.{module}", __package__)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="armtrack",
        description="Remote arm rehabilitation: IMU recordings in, joint angles and the "
        "arm's pose out; the server the kits stream to and the therapist's pages. Angles "
        "follow docs/spec/kinematics.md (degrees at this edge). First time? "
        "`armtrack demo` runs everything on this machine.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        module = command_module(name)
        module.add_arguments(commands.add_parser(name, help=module.HELP,
                                                 description=module.DESCRIPTION))
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        return command_module(args.command).run(args)
    except (EstimatorError, SchemaError, DriverMissing) as exc:
        print(f"armtrack {args.command}: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader went away (`armtrack … | head`): stop quietly, as Unix tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:
        print(f"armtrack {args.command}: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:
        from pydantic import ValidationError  # imported only here: start-up stays light

        if not isinstance(exc, ValidationError) or exc.title != "Settings":
            raise
        for line in setting_errors(exc):  # one line a bad setting, no traceback
            print(f"armtrack {args.command}: {line}", file=sys.stderr)
        return 2


def setting_errors(exc) -> list[str]:
    """The settings ``Settings`` refused, each as ``ARMTRACK_NAME='value': what it must
    be`` (pydantic's words, without its "Value error, " and its links)."""
    lines = []
    for error in exc.errors(include_url=False):
        name = "ARMTRACK_" + "_".join(str(part) for part in error["loc"]).upper()
        message = error["msg"].removeprefix("Value error, ").removeprefix(f"{name}: ")
        lines.append(f"setting {name}={error.get('input')!r}: {message}")
    return lines


def print_json(value: object) -> None:
    print(json.dumps(value, indent=2))


if __name__ == "__main__":
    raise SystemExit(main())
