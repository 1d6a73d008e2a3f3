"""Argument types shared by the command modules: bad values become argparse errors naming the
argument (exit code 2), never a traceback."""

from __future__ import annotations

import argparse
import math


def finite_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text.strip()!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text.strip()!r}")
    return value


def positive_float(text: str) -> float:
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a finite positive number, got {text.strip()!r}")
    return value


def nonnegative_float(text: str) -> float:
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text.strip()!r}")
    return value


def positive_floats(text: str) -> list[float]:
    """A comma-separated list of finite positive numbers."""
    return [positive_float(part) for part in text.split(",")]


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text.strip()!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text.strip()!r}")
    return value


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
