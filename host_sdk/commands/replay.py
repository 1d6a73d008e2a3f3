"""`laserpi replay FILE [--link PATH] [--speed X]`: play a recording again.

With --link, a pseudo-terminal symlinked at PATH serves the recording to any host program
(host_sdk/replay_link.py says how); the command ends after the last byte or on SIGTERM/SIGINT
and removes the link. Without --link it prints one line per recorded scan.
"""

from __future__ import annotations

import argparse
import signal
import threading

from .argtypes import positive_float


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="recording (.lpr) from `laserpi record`")
    parser.add_argument("--link", metavar="PATH", help="serve through a pty symlinked at PATH")
    parser.add_argument("--speed", type=positive_float, default=1.0, help="playback speed, x real time")


def run(args: argparse.Namespace) -> int:
    if args.link is None:
        from host_sdk import replay
        from host_sdk.commands.scans import scan_line

        rep = replay(args.file)
        for scan in rep:
            print(scan_line(scan))
        print(f"# {rep.stats.as_dict()}")
        return 0
    from protocol.ports import PtyLink
    from host_sdk.replay_link import ReplayServer

    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        with PtyLink(args.link) as pty:
            server = ReplayServer(pty.port, args.file, args.speed)
            print(f"replaying {args.file} on {args.link} -> {pty.slave_name}", flush=True)
            server.serve(stop)
    except ValueError as exc:
        print(f"laserpi replay: {exc}")
        return 2
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
