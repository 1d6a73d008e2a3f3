"""The checks `laserpi doctor` runs before `laserpi serve` on a Pi: each says ok or not, what it
found, and what to do. They run anywhere (here they report what is missing); none changes
anything.

Each check is a function ``(DoctorSetup) -> (ok, detail)``; an exception in one is that check
failing with the exception as its detail. The table ``CHECKS`` is the order they run and print in.
"""

from __future__ import annotations

import importlib
import os
import platform
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from device.config import SensorConfig

SETUP_FIX = "sudo tools/pi-setup.sh (README \"On the Pi\")"


class Unmet(Exception):
    """A check that cannot run because an earlier one failed; the message says which."""


@dataclass(frozen=True)
class CheckResult:
    """One check's outcome: its name, whether it passed, and what was found or what to do."""

    name: str
    ok: bool
    detail: str


@dataclass(frozen=True)
class DoctorSetup:
    """What the checks look at: the configuration, the co-MCU's UART, the host link's port, the
    GPIO edge line (CHIP:LINE, None: the configuration's), and where the kernel reports its
    command line and clock source (files, so that tests can point them elsewhere)."""

    config: SensorConfig
    comcu: str = "/dev/serial0"
    port: str = "/dev/ttyGS0"
    gpio_edge: str | None = None
    cmdline: str = "/proc/cmdline"
    clocksource: str = "/sys/devices/system/clocksource/clocksource0/current_clocksource"
    camera_num: int = 0


def _picamera2():
    from device.camera.picamera2_camera import camera_stack_problem

    if camera_stack_problem():
        raise Unmet("needs the camera stack (see above)")
    return importlib.import_module("picamera2")


def check_camera_stack(s: DoctorSetup) -> tuple[bool, str]:
    from device.camera.picamera2_camera import camera_stack_problem

    problem = camera_stack_problem()
    if problem:
        return False, problem
    return True, f"picamera2 from {Path(importlib.import_module('picamera2').__file__).parent}"


def check_camera_detected(s: DoctorSetup) -> tuple[bool, str]:
    cameras = _picamera2().Picamera2.global_camera_info()
    if len(cameras) <= s.camera_num:
        return False, (f"libcamera sees {len(cameras)} camera(s), camera {s.camera_num} is not there: check the ribbon "
                       "cable (contacts towards the board on a Zero 2 W) and camera_auto_detect=1 in config.txt")
    cam = cameras[s.camera_num]
    return True, f"camera {s.camera_num}: {cam.get('Model', '?')} ({cam.get('Id', '?')})"


def check_sensor_mode(s: DoctorSetup) -> tuple[bool, str]:
    want = s.config.window.mode
    cam = _picamera2().Picamera2(s.camera_num)
    try:
        modes = cam.sensor_modes
    finally:
        cam.close()
    sizes = [tuple(m["size"]) for m in modes if "size" in m]
    if (want.width, want.height) not in sizes:
        listed = ", ".join(f"{w}x{h}" for w, h in sizes) or "none"
        return False, f"[image] sensor_mode {want.name} is not among the camera's modes ({listed}): an IMX219 (Camera Module v2)?"
    return True, f"{want.name} available"


def check_comcu(s: DoctorSetup) -> tuple[bool, str]:
    import serial

    from device.laser.comcu import BAUDRATE, CoMcu

    try:
        port = serial.Serial(s.comcu, BAUDRATE, timeout=0.2)
    except serial.SerialException as exc:
        return False, f"cannot open {s.comcu}: {exc}; enable the UART ({SETUP_FIX}) and wire the co-MCU (firmware_pwm/README.md)"
    try:
        info = CoMcu(port).info()
    finally:
        port.close()
    hz = info.ticks_per_second
    return True, (f"firmware version {info.firmware_version}; envelope: pulse <= {1e3 * info.max_pulse_ticks / hz:.1f} ms, "
                  f"duty <= {info.max_duty_ppm / 1e4:.1f} %, heartbeat timeout {info.heartbeat_timeout_ms} ms")


def check_gpio_edge(s: DoctorSetup) -> tuple[bool, str]:
    from device.sync.gpio_edges import GpioEdgeSource, parse_gpio_edge

    spec = s.gpio_edge or s.config.gpio_edge
    if spec is None:
        return False, ("no GPIO edge line configured (serve --gpio-edge CHIP:LINE or [pi] gpio_edge): sync would use "
                       "pings only (degraded)")
    chip, line = parse_gpio_edge(spec)
    try:
        with GpioEdgeSource(chip, line, consumer="laserpi-doctor") as edges:
            edges.read(0.0)
    except OSError as exc:
        return False, f"{spec}: {exc}; is the user in the gpio group ({SETUP_FIX} installs the udev rule)?"
    return True, f"{spec} readable, edges on CLOCK_MONOTONIC"


_CONSOLE = re.compile(r"(?:^|\s)console=(serial0|serial1|ttyAMA\d+|ttyS\d+)\S*")


def check_uart_console(s: DoctorSetup) -> tuple[bool, str]:
    cmdline = Path(s.cmdline).read_text()
    found = _CONSOLE.search(cmdline)
    if found:
        return False, f"the kernel has a console on the UART ({found.group(0).strip()}): the co-MCU's line would be shared; {SETUP_FIX}"
    return True, "no serial console on the kernel command line"


def check_host_link(s: DoctorSetup) -> tuple[bool, str]:
    if not os.path.exists(s.port):
        return False, (f"no {s.port}: the USB gadget serial port appears once dtoverlay=dwc2 and modules-load=dwc2,g_serial "
                       f"are set and the Pi's USB data port is connected to the host; {SETUP_FIX}")
    return True, f"{s.port} present"


def check_kernel(s: DoctorSetup) -> tuple[bool, str]:
    from device.vision.kernel import columns_kernel

    try:
        mod = columns_kernel()
    except ImportError as exc:
        return False, str(exc)
    return True, f"{Path(mod.__file__).name} loads on {platform.machine()}"


def check_clock(s: DoctorSetup) -> tuple[bool, str]:
    source = Path(s.clocksource).read_text().strip() if os.path.exists(s.clocksource) else "unknown"
    res_ns = time.clock_getres(time.CLOCK_MONOTONIC) * 1e9
    if source == "jiffies" or res_ns > 1000:
        return False, f"clock source {source}, CLOCK_MONOTONIC resolution {res_ns:g} ns: too coarse to time frames and edges"
    return True, f"clock source {source}, CLOCK_MONOTONIC resolution {res_ns:g} ns"


#: (name, check), in the order they run.
CHECKS: tuple[tuple[str, Callable[[DoctorSetup], tuple[bool, str]]], ...] = (
    ("camera stack", check_camera_stack),
    ("camera detected", check_camera_detected),
    ("sensor mode", check_sensor_mode),
    ("co-MCU", check_comcu),
    ("GPIO edge line", check_gpio_edge),
    ("UART console", check_uart_console),
    ("host link", check_host_link),
    ("C kernel", check_kernel),
    ("clock", check_clock),
)


def run_checks(setup: DoctorSetup) -> list[CheckResult]:
    results = []
    for name, check in CHECKS:
        try:
            ok, detail = check(setup)
        except Unmet as exc:
            ok, detail = False, str(exc)
        except Exception as exc:  # a check that cannot run has failed; say why
            ok, detail = False, f"{type(exc).__name__}: {exc}"
        results.append(CheckResult(name, ok, detail))
    return results
