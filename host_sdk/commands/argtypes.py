"""Number types of the `laserpi` commands' options, device and host commands alike (host_sdk/
imports nothing of device/): a bad value becomes an argparse error naming the option (exit
code 2), never a traceback."""

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
