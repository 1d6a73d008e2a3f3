"""The simulated scene's motion options, shared by the commands that render it (the number
types of every command's options are host_sdk/commands/argtypes.py)."""

from __future__ import annotations

import argparse

from host_sdk.commands.argtypes import finite_float, nonnegative_float, positive_float


def add_motion_arguments(parser: argparse.ArgumentParser) -> None:
    """The simulated scene's motion, ambient light and flicker (device.sim.scene.with_motion);
    each replaces the scene's own value."""
    parser.add_argument("--yaw-rate-deg-s", type=finite_float, help="the sensor turns at this rate (counter-clockwise)")
    parser.add_argument("--speed-m-s", type=finite_float, help="the sensor moves forward at this speed")
    parser.add_argument("--sensor-ahead-m", type=finite_float,
                        help="the sensor is mounted this far ahead of the robot's turning axis, its x in base_link "
                             "(negative: behind; a turn then also moves it sideways)")
    parser.add_argument("--ambient-scale", type=nonnegative_float, help="ambient light x this (1: the scene's own)")
    parser.add_argument("--flicker-hz", type=positive_float, help="ambient flicker frequency (100 or 120: twice the mains)")
    parser.add_argument("--flicker-depth", type=nonnegative_float, help="ambient flicker modulation depth, 0..1")


def scene_with_motion(scene, args: argparse.Namespace):
    """``scene`` with the arguments of :func:`add_motion_arguments` applied."""
    from device.sim.scene import with_motion

    return with_motion(scene, args.yaw_rate_deg_s, args.speed_m_s, args.ambient_scale, args.flicker_hz,
                       args.flicker_depth, args.sensor_ahead_m)
