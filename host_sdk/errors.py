"""Exceptions of the host SDK. Every one is a LaserPiError; catch that to catch them all.

    LaserPiError
    ├── PortError            the port cannot be opened (missing device, permissions, busy)
    │   └── DisconnectedError  the port went away while open (unplugged, device process died)
    ├── DeviceTimeout        no reply to a request, or no scan, within the timeout
    ├── CommandRefused       the device refused a request (NACK): .code and .reason say why
    └── IncompatibleDevice   the device speaks another major protocol version
"""

from __future__ import annotations


class LaserPiError(Exception):
    """Base class of every error the SDK raises on purpose."""


class PortError(LaserPiError):
    """The serial port could not be opened or used."""


class DisconnectedError(PortError):
    """The port disappeared while open (and reconnecting was off or gave up)."""


class DeviceTimeout(LaserPiError, TimeoutError):
    """The device did not answer, or sent no scan, within the timeout."""


class CommandRefused(LaserPiError):
    """The device answered a request with NACK; nothing of the request was applied."""

    def __init__(self, request: str, code, reason: str):
        super().__init__(f"{request} refused ({code.name}): {reason}")
        self.request = request
        self.code = code
        self.reason = reason


class IncompatibleDevice(LaserPiError):
    """The device's major protocol version differs from this SDK's (see protocol/SPEC.md)."""
