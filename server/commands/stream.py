"""``armtrack stream``: play a recording (or a simulated exercise) to the server as a
sensor kit would, over the ingest protocol of ``docs/spec/ingest.md``."""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from armtrack.estimator.errors import InvalidArgument

from .choices import EXERCISE_NAMES

if TYPE_CHECKING:  # the estimator, the emulator (and websockets) load only when streaming
    from armtrack.estimator.recording import Recording

    from ..emulator import KitEmulator, KitStats

HELP = "play a recording to the server as a sensor kit (docs/spec/ingest.md)"
DESCRIPTION = ("Connects to the ingest WebSocket with a device token and streams a recording "
               "(or a simulated exercise) paced by its clock, resuming after a lost "
               "connection and waiting while the server refuses the kit for now (up to "
               "--busy-retry seconds); a session the server says is full "
               "(ARMTRACK_MAX_SESSION_SAMPLES) is closed and the rest goes on in a new "
               "session. Prints progress to standard error and a summary at the end.")

#: Exit code when the server refuses the kit or cannot be reached (2 is bad input).
EXIT_REFUSED = 1


def _default_url() -> str:
    host = os.environ.get("ARMTRACK_HOST", "127.0.0.1")
    port = os.environ.get("ARMTRACK_PORT", "8000")
    return f"ws://{host}:{port}/ws/ingest"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("recording", nargs="?", type=Path,
                        help="the recording to stream (docs/spec/recording.md)")
    source.add_argument("--exercise", choices=sorted(EXERCISE_NAMES),
                        help="stream a simulated exercise session instead of a file")
    parser.add_argument("--url", default=_default_url(),
                        help="the ingest WebSocket (default ws://$ARMTRACK_HOST:"
                        "$ARMTRACK_PORT/ws/ingest, i.e. %(default)s)")
    parser.add_argument("--token", default=os.environ.get("ARMTRACK_TOKEN"),
                        help="the device token (default $ARMTRACK_TOKEN)")
    parser.add_argument("--speed", type=float, default=1.0,
                        help="playback speed: 1 real time, 10 ten times faster, "
                        "0 or inf as fast as possible (default 1)")
    parser.add_argument("--rows-per-message", type=int, default=10, metavar="N",
                        help="sample rows per message, 1 to 1000 (default 10)")
    parser.add_argument("--device", default="armtrack-emulator", metavar="NAME",
                        help="the device name sent in hello")
    parser.add_argument("--busy-retry", type=float, default=60.0, metavar="SECONDS",
                        help="how long to keep trying while the server refuses the kit for "
                        "now (close 4429 in answer to hello: too many new sessions this "
                        "hour or streams open; not too many refused messages, which ends "
                        "it at once), every 0.5 s doubling to 5 s; then give up (exit 1). "
                        "Default %(default)g")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    simulated = parser.add_argument_group("with --exercise")
    simulated.add_argument("--side", choices=("right", "left"), default="right")
    simulated.add_argument("--rate", type=float, default=100.0, metavar="HZ")
    simulated.add_argument("--six-axis", action="store_true", help="no magnetometer")
    simulated.add_argument("--seed", type=int, default=0)


def _recording(args: argparse.Namespace) -> tuple[Recording, str]:
    from armtrack.estimator.recording import read_recording
    from armtrack.estimator.simulation import SimulationConfig, simulate

    if args.recording is not None:
        return read_recording(args.recording), str(args.recording)
    config = SimulationConfig(exercise=args.exercise, side=args.side, rate_hz=args.rate,
                              nine_axis=not args.six_axis, seed=args.seed)
    return simulate(config).recording, f"simulated {args.exercise}"


def _progress(kit: KitEmulator, started: float) -> str:
    s = kit.stats
    elapsed = max(time.monotonic() - started, 1e-9)
    return (f"sent {s.sent}/{s.total} messages ({s.rows_sent} rows), acked {s.acked}"
            + (f", refused {s.refused}" if s.refused else "")
            + (f", reconnects {s.reconnects}" if s.reconnects else "")
            + f", {s.rows_acked / elapsed:.0f} rows/s")


async def _stream(kit: KitEmulator, quiet: bool) -> KitStats:
    import asyncio

    started = time.monotonic()
    run = asyncio.create_task(kit.run())
    while not quiet:
        done, _ = await asyncio.wait({run}, timeout=1.0)
        if done:
            break
        print(_progress(kit, started), file=sys.stderr, flush=True)
    return await run


def _summary(kit: KitEmulator, what: str, url: str) -> str:
    s = kit.stats
    if len(s.sessions) > 1:  # the server's session-size cap: went on in new sessions
        lines = [f"streamed {what} to {url}: sessions {', '.join(map(str, s.sessions))}; "
                 "each time a session was full, it was closed and the rest went on in a new "
                 f"session (the server: {s.session_full[0]})"]
    else:
        lines = [f"streamed {what} to {url}: stream {s.stream}, session {s.session}"]
    lines.append(f"  {s.acked} of {s.total} messages acked ({s.rows_acked} rows) in "
                 f"{s.elapsed_s or 0.0:.1f} s; resent {s.resent}, refused {s.refused}, "
                 f"reconnects {s.reconnects}")
    latency = s.latency_percentiles()
    if latency:
        lines.append("  ack latency " + ", ".join(
            f"p{p:g} {v * 1000:.1f} ms" for p, v in latency.items()))
    lines += [f"  error: seq {e['seq']}: {e['reason']}" for e in s.errors[:10]]
    if len(s.errors) > 10:
        lines.append(f"  … and {len(s.errors) - 10} more errors")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    import asyncio

    if not args.token:
        raise InvalidArgument("give the device token with --token or $ARMTRACK_TOKEN")
    if not (args.speed >= 0) or math.isnan(args.speed):
        raise InvalidArgument(f"--speed must be >= 0, got {args.speed}")
    if not (args.busy_retry >= 0) or math.isinf(args.busy_retry):
        raise InvalidArgument(f"--busy-retry must be >= 0 seconds, got {args.busy_retry}")
    from ..emulator import KitEmulator, KitError, KitRefused

    def busy(reason: str, wait_s: float, left_s: float) -> None:
        # always said, --quiet or not: the user may want to stop and come back later
        print(f"armtrack stream: the server refuses this kit for now: {reason}. Trying "
              f"again in {wait_s:.1f} s (giving up in {left_s:.0f} s; --busy-retry)",
              file=sys.stderr, flush=True)

    recording, what = _recording(args)
    kit = KitEmulator(recording, args.url, args.token, device=args.device,
                      rows_per_message=args.rows_per_message, speed=args.speed,
                      busy_retry_s=args.busy_retry, on_busy=busy)
    try:
        asyncio.run(_stream(kit, args.quiet))
    except KitRefused as exc:
        if not exc.busy:  # a 4429 after ready: its own refused messages, no retry
            print(f"armtrack stream: {exc}", file=sys.stderr)
            return EXIT_REFUSED
        s = kit.stats
        stored = (f"{s.acked} of {s.total} messages acked are stored (session {s.session})"
                  if s.acked else "Nothing of it was stored")
        print(f"armtrack stream: gave up after {args.busy_retry:g} s: {exc}. {stored}; "
              f"run the command again later, or with a longer --busy-retry", file=sys.stderr)
        return EXIT_REFUSED
    except KitError as exc:  # the message says what went wrong
        print(f"armtrack stream: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except KeyboardInterrupt:
        s = kit.stats
        print(f"armtrack stream: interrupted after {s.sent} of {s.total} messages sent, "
              f"{s.acked} acked (stream {s.stream})", file=sys.stderr)
        return 130
    print(_summary(kit, what, args.url))
    return 0
