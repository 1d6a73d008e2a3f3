"""pyserial URL handler ``sim://``: a mock LaserPi in-process, no OS device needed.

    LaserPi("sim://wall?distance=2.0")

pyserial imports ``<package>.protocol_<scheme>`` for a URL, and host_sdk/device.py adds
"host_sdk" to ``serial.protocol_handler_packages``. Opening runs the real device link server
(protocol/server.py) with the analytic wall source (protocol/mock_wall.py) on threads, connected
to this port by an in-memory pipe whose device-to-host writes are paced at the port's baud rate
like a UART. Every open is a fresh device; closing stops it.

URL options (all optional):
    distance=2.0     wall distance, m            points=1640   columns per scan
    fov_deg=105      field of view, degrees      rate=10       scan rate at power-on, Hz
    noise=1          0 turns the noise model off (and dropouts)   seed=0   noise seed
    limit_mw=5.0     the device's Class 1 laser power limit, mW
    unplug_after=S   the device vanishes S seconds after opening (tests of DisconnectedError)
    ber=1e-5         bit error rate on the device-to-host line (tests of corruption handling)
    start_delay=S    the first scan comes S seconds after START (a sensor starting up)
    host_timeout=5   the device stops scanning when the host sent nothing for this long, s; 0 never
"""

from __future__ import annotations

import math
import threading
import time
import urllib.parse

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from protocol.mock_wall import LASER_LIMIT_MW, AnalyticWallSource, default_settings
from protocol.ports import NoisyPort, PacedPort, PortClosed, pipe_pair
from protocol.server import DeviceConfig, LinkServer

_OPTIONS = {"distance": float, "points": int, "fov_deg": float, "rate": float, "noise": int, "seed": int,
            "limit_mw": float, "unplug_after": float, "ber": float, "start_delay": float, "host_timeout": float}


def parse_sim_url(url: str) -> tuple[str, dict]:
    """("wall", {option: value}) from a sim:// URL; SerialException naming a bad part."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme != "sim":
        raise SerialException(f"expected sim://SCENE?options, got {url!r}")
    scene = parts.netloc or "wall"
    if scene != "wall":
        raise SerialException(f"sim:// knows the scene 'wall', not {scene!r}")
    opts = {}
    for key, values in urllib.parse.parse_qs(parts.query, keep_blank_values=True).items():
        if key not in _OPTIONS:
            raise SerialException(f"unknown sim:// option {key!r}; known: {', '.join(_OPTIONS)}")
        try:
            opts[key] = _OPTIONS[key](values[-1])
        except ValueError:
            raise SerialException(f"sim:// option {key}={values[-1]!r} is not a {_OPTIONS[key].__name__}") from None
    limit = opts.get("limit_mw", LASER_LIMIT_MW)
    if not 0 < limit <= LASER_LIMIT_MW:  # as serve --mock --laser-limit-mw: it can only lower the limit
        raise SerialException(f"sim:// option limit_mw={limit:g}: the mock device's Class 1 limit is "
                              f"{LASER_LIMIT_MW:g} mW; limit_mw can only lower it (0 < limit_mw <= {LASER_LIMIT_MW:g})")
    return scene, opts


def build_sim_device(opts: dict) -> tuple[AnalyticWallSource, DeviceConfig]:
    """The analytic source and device config a sim:// URL's options describe."""
    points = opts.get("points", 1640)
    noisy = opts.get("noise", 1) != 0
    source = AnalyticWallSource(opts.get("distance", 2.0), n_points=points,
                                fov_rad=math.radians(opts.get("fov_deg", 105.0)),
                                noise_floor_m=0.001 if noisy else 0.0, noise_rel_per_m=0.0025 if noisy else 0.0,
                                dropout=0.01 if noisy else 0.0, seed=opts.get("seed", 0),
                                start_delay_s=opts.get("start_delay", 0.0))
    limit_mw = opts.get("limit_mw", LASER_LIMIT_MW)
    settings = default_settings(points, limit_mw)
    if "rate" in opts:
        settings = settings.merged(type(settings)(scan_rate_hz=opts["rate"]))
    return source, DeviceConfig(laser_limit_mw=limit_mw, settings=settings,
                                host_timeout_s=opts.get("host_timeout", 5.0))


class Serial(SerialBase):
    """A serial port whose far end is a simulated LaserPi."""

    def open(self):
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        _, opts = parse_sim_url(self.portstr)
        try:
            source, config = build_sim_device(opts)
        except ValueError as exc:
            raise SerialException(f"sim://: {exc}") from None
        self._host, device_end = pipe_pair()
        try:
            line = NoisyPort(device_end, opts.get("ber", 0.0), seed=opts.get("seed", 0))
        except ValueError as exc:
            raise SerialException(f"sim://: {exc}") from None
        self._server = LinkServer(PacedPort(line, self._baudrate), source, config).start()
        self._unplug_timer = None
        if "unplug_after" in opts:
            self._unplug_timer = threading.Timer(opts["unplug_after"], self._unplug)
            self._unplug_timer.daemon = True
            self._unplug_timer.start()
        self.is_open = True

    def _unplug(self):
        self._host.close()  # the host's next read or write raises, like a pulled cable
        self._server.close()

    def close(self):
        if self.is_open:
            self.is_open = False
            if self._unplug_timer is not None:
                self._unplug_timer.cancel()
            self._server.close()
            self._host.close()
        super().close()

    def _reconfigure_port(self):
        pass  # the baud rate is read at open and paces the simulated UART

    @property
    def in_waiting(self):
        if not self.is_open:
            raise PortNotOpenError()
        return self._host.in_waiting

    def read(self, size=1):
        """Up to size bytes; waits until size arrived or the timeout passed (pyserial's rule)."""
        if not self.is_open:
            raise PortNotOpenError()
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        data = bytearray()
        while len(data) < size:
            left = 0.1 if deadline is None else deadline - time.monotonic()
            if left <= 0 and data:
                break
            try:
                data += self._host.read(size - len(data), timeout_s=max(left, 0.0))
            except PortClosed as exc:
                raise SerialException(f"device reports readiness to read but returned no data "
                                      f"(device disconnected): {exc}") from None
            if deadline is not None and time.monotonic() >= deadline:
                break
        return bytes(data)

    def write(self, data):
        if not self.is_open:
            raise PortNotOpenError()
        try:
            return self._host.write(bytes(data))
        except PortClosed as exc:
            raise SerialException(f"write failed (device disconnected): {exc}") from None

    def reset_input_buffer(self):
        if not self.is_open:
            raise PortNotOpenError()
        self._host.reset_input()

    def reset_output_buffer(self):
        if not self.is_open:
            raise PortNotOpenError()
