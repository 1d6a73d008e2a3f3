"""`laserpi export-bag FILE OUT`: a recording as a ROS 2 bag of sensor_msgs/msg/LaserScan.

Needs the `ros` extra (`pip install laserpi[ros]`, the `rosbags` package; no ROS install).
The bag uses MCAP storage when the installed rosbags can write it (0.10 and later; checked at
run time), else sqlite3 with a warning.
Header stamps are wall-clock (UTC) times: the recording's host monotonic stamps shifted by the
offset between the two clocks noted when recording began (header wall_start_ns/mono_start_ns).
The bag's receive time of each message is the same stamp.
"""

from __future__ import annotations

import argparse
import errno
import logging
import os

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="recording (.lpr) from `laserpi record`")
    parser.add_argument("out", help="bag directory to create; must not exist")
    parser.add_argument("--topic", default="/scan")
    parser.add_argument("--frame-id", default="laser")


def storage_plugin():
    """MCAP if this rosbags can write it (>= 0.10), else sqlite3 with a warning saying so."""
    from rosbags.rosbag2 import StoragePlugin

    if hasattr(StoragePlugin, "MCAP"):
        return StoragePlugin.MCAP
    log.warning("the installed rosbags cannot write MCAP; writing sqlite3 storage instead")
    return StoragePlugin.SQLITE3


def export_bag(recording: str, out: str, topic: str = "/scan", frame_id: str = "laser") -> tuple[int, dict]:
    """Write the bag; returns (messages written, replay stats). FileExistsError if ``out`` exists."""
    import numpy as np
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    from host_sdk.recording import Replay

    if os.path.lexists(out):
        raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), out)
    ts = get_typestore(Stores.ROS2_HUMBLE)
    LaserScanMsg = ts.types["sensor_msgs/msg/LaserScan"]
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    rep = Replay(recording)
    wall_minus_mono_ns = rep.header.wall_start_ns - rep.header.mono_start_ns
    n = 0
    with Writer(out, version=9, storage_plugin=storage_plugin()) as writer:
        conn = writer.add_connection(topic, LaserScanMsg.__msgtype__, typestore=ts)
        for scan in rep:
            ls = scan.to_laserscan(frame_id)
            t_ns = int(round(ls.stamp * 1e9)) + wall_minus_mono_ns
            msg = LaserScanMsg(
                header=Header(stamp=Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000), frame_id=frame_id),
                angle_min=ls.angle_min, angle_max=ls.angle_max, angle_increment=ls.angle_increment,
                time_increment=ls.time_increment, scan_time=ls.scan_time, range_min=ls.range_min,
                range_max=ls.range_max, ranges=np.asarray(ls.ranges, dtype=np.float32),
                intensities=np.asarray(ls.intensities, dtype=np.float32))
            writer.write(conn, t_ns, ts.serialize_cdr(msg, LaserScanMsg.__msgtype__))
            n += 1
    return n, rep.stats.as_dict()


def run(args: argparse.Namespace) -> int:
    try:
        import rosbags  # noqa: F401
    except ImportError:
        print("laserpi export-bag needs the 'ros' extra: pip install 'laserpi[ros]'")
        return 2
    try:
        n, stats = export_bag(args.file, args.out, args.topic, args.frame_id)
    except FileExistsError:
        print(f"laserpi export-bag: {args.out} exists; not overwriting it")
        return 2
    except ValueError as exc:
        print(f"laserpi export-bag: {exc}")
        return 2
    print(f"wrote {n} LaserScan messages on {args.topic} to {args.out} ({storage_plugin().name}); dropped: "
          f"crc {stats['crc_errors']}, decode {stats['decode_errors']}")
    return 0
