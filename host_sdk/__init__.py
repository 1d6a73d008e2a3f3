"""The robot side of LaserPi: ``host_sdk.LaserPi('/dev/ttyUSB0').scans()``.

Needs numpy, pyserial and cobs only (no OpenCV). See the README section "On your robot".
"""

from host_sdk.device import LaserPi
from host_sdk.diagnostics import DiagnosticStatus
from host_sdk.errors import (CommandRefused, DeviceTimeout, DisconnectedError, IncompatibleDevice, LaserPiError,
                             PortError)
from host_sdk.receiver import Stats
from host_sdk.recording import replay
from host_sdk.scan import Crop, LaserScan, Scan

__all__ = ["LaserPi", "Scan", "LaserScan", "Crop", "DiagnosticStatus", "Stats", "replay", "LaserPiError", "PortError",
           "DisconnectedError", "DeviceTimeout", "CommandRefused", "IncompatibleDevice"]
