"""`laserpi record --port P --seconds N --out FILE`: store the raw wire bytes of a sensor.

The file (format in host_sdk/recording.py) holds every byte the sensor sent, with host arrival
times, starting with the opening handshake so that it carries the sensor's INFO.
"""

from __future__ import annotations

import argparse
import time

from .argtypes import positive_float, positive_int


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", required=True, help="device path or pyserial URL (e.g. sim://wall)")
    parser.add_argument("--baud", type=positive_int, default=921600)
    parser.add_argument("--seconds", type=positive_float, required=True, help="how long to record")
    parser.add_argument("--out", required=True, help="recording to create (.lpr); must not exist")


def run(args: argparse.Namespace) -> int:
    from host_sdk import LaserPi, LaserPiError
    from host_sdk.recording import RecordingHeader, RecordingWriter

    header = RecordingHeader(args.baud, time.time_ns(), time.monotonic_ns(), args.port)
    try:
        with RecordingWriter(args.out, header) as writer, LaserPi(args.port, args.baud, tap=writer.write) as sensor:
            sensor.start()
            end = time.monotonic() + args.seconds
            for _ in sensor.scans():  # keep the reader's queue moving; the tap records
                if time.monotonic() >= end:
                    break
            sensor.stop()
            stats = sensor.stats
    except FileExistsError:
        print(f"laserpi record: {args.out} exists; not overwriting it")
        return 2
    except LaserPiError as exc:
        print(f"laserpi record: {exc}")
        return 1
    print(f"recorded {stats.scans} scans to {args.out} (crc errors {stats.crc_errors}, "
          f"bytes discarded {stats.bytes_discarded})")
    return 0
