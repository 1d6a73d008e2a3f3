"""`laserpi ros2 --port P`: publish the sensor's scans into a ROS 2 graph, over DDS, without ROS.

Needs the `ros2` extra (`pip install 'laserpi[ros2]'`: the cyclonedds package, which carries the
Cyclone DDS library). Publishes sensor_msgs/msg/LaserScan on --topic and
diagnostic_msgs/msg/DiagnosticArray on /diagnostics, as a ROS 2 node with rmw_cyclonedds would
(host_sdk/ros2/conventions.py). Names and defaults follow the drivers of other scanners:
topic "scan" (rplidar_ros topic_name, urg_node), frame "laser" (urg_node laser_frame_id),
angle_min/angle_max as urg_node's crop, reliable QoS (both drivers), diagnostics at 1 Hz
(diagnostic_updater's period).

Parameters come from the command line, else from --params FILE (TOML, the keys are the options'
names with "_", e.g. frame_id = "laser"), else the defaults below. The domain id defaults to
$ROS_DOMAIN_ID, else 0, as rcl does (rcl/src/rcl/domain_id.c, rcl_get_default_domain_id).
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import math
import os
import signal
import sys
import tomllib

log = logging.getLogger(__name__)

# name: (type, default, help). The command line's default is None so that a file can fill it.
PARAMETERS = {
    "port": (str, None, "device path or pyserial URL (e.g. /dev/laserpi, sim://wall)"),
    "baud": (int, 921600, "baud rate"),
    "topic": (str, "/scan", "ROS topic of the LaserScan messages"),
    "frame_id": (str, "laser", "header.frame_id of the scans (RViz2's fixed frame)"),
    "domain_id": (int, None, "ROS domain id (default: $ROS_DOMAIN_ID, else 0)"),
    "qos": (str, "reliable", "reliable: rmw_qos_profile_default (reliable, keep last 10; serves reliable and "
                             "best-effort subscribers); sensor: rmw_qos_profile_sensor_data (best effort, keep last "
                             "5; serves best-effort subscribers only)"),
    "angle_min": (float, -math.inf, "crop: first angle kept, rad (rounded to the nearest ray, as urg_node)"),
    "angle_max": (float, math.inf, "crop: last angle kept, rad"),
    "range_min": (float, 0.0, "ranges below become -inf (REP 117); the message's range_min"),
    "range_max": (float, math.inf, "ranges beyond become +inf (REP 117); the message's range_max"),
    "diagnostics_hz": (float, 1.0, "rate of /diagnostics"),
    "reconnect": (bool, False, "reopen the port when the sensor goes away instead of exiting"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--params", metavar="FILE", help="TOML file of parameters (see the module docstring)")
    for name, (type_, default, help_) in PARAMETERS.items():
        flag = "--" + name.replace("_", "-")
        shown = f" (default {default})" if default is not None else ""
        if type_ is bool:
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=None, help=help_)
        else:
            parser.add_argument(flag, type=type_, default=None, help=help_ + shown,
                                choices=("reliable", "sensor") if name == "qos" else None)


def resolve(args: argparse.Namespace, environ=os.environ) -> dict:
    """{parameter: value}: command line, else --params file, else default. ValueError naming a
    bad file key or value."""
    values = {name: default for name, (_, default, _) in PARAMETERS.items()}
    values["domain_id"] = int(environ.get("ROS_DOMAIN_ID") or 0)
    if args.params:
        with open(args.params, "rb") as f:
            from_file = tomllib.load(f)
        for key, value in from_file.items():
            if key not in PARAMETERS:
                raise ValueError(f"{args.params}: unknown parameter {key!r}; known: {', '.join(PARAMETERS)}")
            type_ = PARAMETERS[key][0]
            if type_ is float and isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
            if not isinstance(value, type_) or (type_ is int and isinstance(value, bool)):
                raise ValueError(f"{args.params}: {key} must be a {type_.__name__}, got {value!r}")
            values[key] = value
    values.update({name: getattr(args, name) for name in PARAMETERS if getattr(args, name) is not None})
    if values["port"] is None:
        raise ValueError("no port: give --port or port = ... in the --params file")
    if values["qos"] not in ("reliable", "sensor"):
        raise ValueError(f"qos must be reliable or sensor, got {values['qos']!r}")
    return values


def publish_scans(publisher, sensor, options, reconnect: bool) -> None:
    """Publish the sensor's scans until it fails. With ``reconnect`` a pause in the scans (the
    sensor coming back more slowly than LaserPi's timeout_s after an unplug) is waited out, as the
    port is."""
    from host_sdk import DeviceTimeout
    from host_sdk.ros2.node import run_node

    while True:
        try:
            run_node(publisher, sensor.scans(), options)
            return
        except DeviceTimeout as exc:
            if not reconnect:
                raise
            log.warning("%s; waiting for scans", exc)


def run(args: argparse.Namespace) -> int:
    if importlib.util.find_spec("cyclonedds") is None:
        print("laserpi ros2 needs the 'ros2' extra: pip install 'laserpi[ros2]'")
        return 2
    from host_sdk import LaserPi, LaserPiError
    from host_sdk.ros2.dds import Ros2Publisher
    from host_sdk.ros2.node import DiagnosticsThread, ScanOptions

    try:
        p = resolve(args)
        options = ScanOptions(p["frame_id"], p["angle_min"], p["angle_max"], p["range_min"], p["range_max"])
        publisher = Ros2Publisher(p["domain_id"], p["topic"], p["qos"])
    except (ValueError, OSError, tomllib.TOMLDecodeError) as exc:
        print(f"laserpi ros2: {exc}")
        return 2
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # systemd stop: close the sensor cleanly
    try:
        with LaserPi(p["port"], p["baud"], reconnect=p["reconnect"]) as sensor:
            diagnostics = DiagnosticsThread(publisher, sensor.diagnostics, sensor.info().serial_number,
                                            p["diagnostics_hz"])
            print(f"laserpi ros2: publishing {p['topic']} (frame {p['frame_id']}, QoS {p['qos']}) and /diagnostics "
                  f"on ROS domain {p['domain_id']}", flush=True)
            diagnostics.start()
            try:
                publish_scans(publisher, sensor, options, p["reconnect"])
            finally:
                diagnostics.stop()
    except (LaserPiError, ValueError) as exc:
        print(f"laserpi ros2: {exc}")
        return 1
    finally:
        publisher.close()
    return 0
