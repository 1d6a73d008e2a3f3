"""Build the whole sensor (device.process.SensorSource) from its parts, on a Pi or simulated.

On a Pi: Picamera2Camera -> SyncedLaser (co-MCU on a UART) -> fast pipeline.
Simulated (``laserpi serve --simulate``): the same SensorSource, SyncedLaser and pipeline, with
* the camera: the scene renderer (device/sim/render.py) on the simulated clock, timed by the
  IMX219 timing simulation (device/sim/timing.py: line-quantised frame length, timestamp
  latency, dropped frames) -- ``SimCamera``;
* the co-MCU: the shipped firmware ELF in the simavr harness, stepped cycle-exactly, whose cycle
  count is also the simulated Pi's clock (``SimulatedHardware``); its UART is a pty that CoMcu
  opens through pyserial, as it opens /dev/serial0 on a Pi. The laser pin's edges become the
  pulses that light the rendered rows and, with a simulated kernel latency, the GPIO edge events
  of the laser trigger line for the clock map.

Why the emulator is stepped by the simulated clock and not free-running (the harness's own pty
mode, paced to the wall clock): on this shared 2-core machine the free-running emulator lagged
the wall clock by 10-180 ms, so its MCU clock wandered by thousands of ppm and heartbeats
arrived late; in simulated time nothing depends on how busy the machine is (it only runs slower
than real time then). The pty between the two is the same either way.

Operating point (both): 20 frames/s, every other frame lit (docs/thesis-notes.md N10), so 10 scans/s; exposure
``EXPOSURE_US``; the range limits ``RANGE_M`` narrow the region of interest (rows where the line
can land) and so the pulse, which must fit the firmware's compiled-in eye-safety envelope.
"""

from __future__ import annotations

import collections
import logging
import os
import select
import threading
import time
from dataclasses import dataclass, replace

import numpy as np

from device.camera.frame import Frame
from device.config import SensorConfig, load_config, load_preset
from device.link import ScanGeometry
from device.model.scan_frame import uniform_angles
from device.process import SensorSource
from device.synced_laser import HEARTBEAT_S
from protocol import messages as m

log = logging.getLogger(__name__)

SCAN_RATE_HZ = 10.0
FRAME_DURATION_S = 0.5 / SCAN_RATE_HZ  # a lit and an unlit frame per scan
EXPOSURE_US = 9200.0
RANGE_M = (0.4, 3.2)
PIPELINE = "fast-com-track"
ANALOG_GAIN = 4.0  # analogue gain, on a Pi and simulated (device/sim/sensor.py): at 1 the 3 m line is a few 8-bit levels (1.0 % at 3 m); 4 and 8 give 0.4 %
COMCU_BAUDRATE = 250_000
COMMAND_LATENCY_S = 0.02  # worst request round trip to the co-MCU seen here (emulator pty: median 3 ms, max 20 ms)


# --- pipeline: frame pair -> ranges on the scan's uniform angles -------------------------------
class ScanPipeline:
    """device.process.Pipeline over a device.vision pipeline: its per-column measurements resampled
    onto ``count`` uniform angles (device.vision.measurements.to_laser_scan: never across a depth
    jump), quality from the nearest measured column."""

    def __init__(self, pipeline, count: int):
        a = np.asarray(pipeline.geometry.column_angle, dtype=np.float64)
        a = a[np.isfinite(a)]
        if a.size < 2 or count < 2:
            raise ValueError(f"need at least 2 columns with an angle and 2 scan points, got {a.size} and {count}")
        self.pipeline = pipeline
        self.angle_min, self.angle_max = float(a.min()), float(a.max())
        self.angles = uniform_angles(self.angle_min, self.angle_max, count)

    def __call__(self, lit: Frame, dark: Frame) -> tuple[np.ndarray, np.ndarray]:
        from device.vision.measurements import to_laser_scan

        meas = self.pipeline.process(lit, dark)
        _, ranges = to_laser_scan(meas, self.angle_min, self.angle_max, self.angles.size)
        ok = np.isfinite(meas.angle)
        order = np.argsort(meas.angle[ok])
        a, q = meas.angle[ok][order], np.asarray(meas.quality, dtype=np.float64)[ok][order]
        idx = np.clip(np.searchsorted(a, self.angles), 1, max(a.size - 1, 1))
        nearest = np.where(np.abs(a[idx - 1] - self.angles) <= np.abs(a[np.minimum(idx, a.size - 1)] - self.angles),
                           idx - 1, np.minimum(idx, a.size - 1))
        quality = np.where(np.isfinite(ranges), np.clip(np.rint(q[nearest]), 0, 255), 0).astype(np.uint8)
        return ranges.astype(np.float32), quality


# --- the simulated hardware: the Pi's clock and the co-MCU (real firmware in the emulator) ------
class SimulatedHardware:
    """The simulated Pi's CLOCK_MONOTONIC and its co-MCU: the shipped firmware ELF running in the
    simavr harness (device/comcu_emulator.SteppedMcuPort), cycle-exact, behind a pty.

    Time: simulated CLOCK_MONOTONIC = ``t_base + emulator cycles / CPU_HZ``; a clock thread keeps
    it at the wall clock (it advances the emulator, never ahead of the wall clock) but not past
    ``limit_ns``, which the simulated camera sets one frame beyond the frame it waits for: when
    this machine is too busy for the device process to keep up in real time, the simulated world
    waits for it instead of running away (it runs slower than real time, and consistently: no
    heartbeat or frame is missed because the host machine was descheduled). Whether a Pi keeps
    up is judged from the measured CPU cost instead (laserpi bench process). While requests
    from the Pi wait for the co-MCU's answers (counted by frame delimiters), the clock may pass
    ``limit_ns`` (by at most ``answer_window_s`` after the last request), as the MCU's time would.
    Every ``tick_s`` of simulated time the ``tickers`` run on their own thread
    (SyncedLaser.heartbeat).

    The co-MCU's UART is a pty (``tty_path``), opened by CoMcu through pyserial exactly as the
    real one's UART is on a Pi (``open_comcu``); the clock thread moves its bytes to and from the
    emulator at every step (at most ``step_s`` of simulated time, and at once when the Pi writes).
    The laser pin's edges (CPU cycles, exact) become the laser's on-windows that light the
    rendered rows (``windows``, a device.sim.pulses.PulseSource) and, plus a simulated kernel
    latency (3 us + exponential, mean ``gpio_latency_s``), the GPIO edge events of the trigger
    line that the clock map uses (``gpio_edges``).
    """

    def __init__(self, *, seed: int = 0, gpio_latency_s: float = 20e-6, tick_s: float = HEARTBEAT_S,
                 history_s: float = 2.0, step_s: float = 0.002, answer_window_s: float = 0.05):
        from device.comcu_emulator import CPU_HZ, ELF, HARNESS, build_emulator
        from device.ports import open_raw_pty

        if not (HARNESS.exists() and ELF.exists()):
            build_emulator()
        self.harness, self.elf, self.cpu_hz = HARNESS, ELF, CPU_HZ
        self.gpio_latency_s = gpio_latency_s
        self.tick_ns, self.step_ns = int(tick_s * 1e9), int(step_s * 1e9)
        self.answer_window_ns = int(answer_window_s * 1e9)
        self.tickers: list = []
        self._rng = np.random.default_rng([seed, 0x6910])
        self._lock = threading.RLock()  # the emulator: one command at a time
        self._advanced = threading.Condition(self._lock)
        self._windows: collections.deque[tuple[int, int]] = collections.deque(maxlen=int(64 * history_s))
        self._gpio: collections.deque[tuple[int, bool]] = collections.deque(maxlen=1024)
        self._rise: int | None = None
        self.mcu = None
        self.clock_cpu_s = 0.0
        self.limit_ns: int | None = None  # the clock does not pass this (the camera's consumer lags)
        self._answer_until_ns = 0  # requests are in flight: the MCU's time may pass limit_ns until then
        self._requests_in_flight = 0  # frames (0x00 delimiters) the Pi sent that the MCU has not answered
        self.resets = -1
        # the UART: the Pi's end is the pty's slave (raw, like a serial port), the MCU's the master
        self._master, self._slave, self.tty_path = open_raw_pty()
        os.set_blocking(self._master, False)
        self._pending_to_pi = bytearray()
        self._t_base_ns = time.monotonic_ns()
        self.reset_mcu()
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._run_clock, name="sim-clock", daemon=True),
                         threading.Thread(target=self._run_tickers, name="sim-ticker", daemon=True)]
        for t in self._threads:
            t.start()

    # the clock
    def now_ns(self) -> int:
        return self._t_base_ns + self.mcu.cycle * 1_000_000_000 // self.cpu_hz

    def _run_clock(self) -> None:
        while not self._stop.is_set():
            self.clock_cpu_s = time.thread_time()  # stepping the emulator: simulation cost, not the device's
            self._pi_to_mcu()
            now = self.now_ns()
            target = time.monotonic_ns()
            limit = self.limit_ns
            if limit is not None:
                target = min(target, max(limit, self._answer_until_ns))
            if now >= target:
                # wait for the wall clock, or at once for bytes from the Pi
                select.select([self._master], [], [], min(0.002, (now - target) * 1e-9 + 0.0005))
                continue
            step_end = min(target, now + self.step_ns)
            with self._lock:
                self.mcu.run_cycles(max(1, (step_end - now) * self.cpu_hz // 1_000_000_000))
                self._collect()
                self._mcu_to_pi()
                self._advanced.notify_all()

    def _pi_to_mcu(self) -> None:
        """Bytes the Pi wrote to its end of the UART go into the MCU's receiver now."""
        try:
            data = os.read(self._master, 4096)
        except (BlockingIOError, OSError):  # nothing written (or no reader attached yet)
            return
        if data:
            with self._lock:
                self.mcu.write(data)
                self._requests_in_flight += data.count(0)
                self._answer_until_ns = self.now_ns() + self.answer_window_ns

    def _mcu_to_pi(self) -> None:
        """What the MCU sent goes to the Pi's end of the UART (kept while the pty is full)."""
        n = self.mcu.in_waiting
        if n:
            out = self.mcu.read(n)
            self._pending_to_pi += out
            # every request frame gets one answer frame
            self._requests_in_flight = max(0, self._requests_in_flight - out.count(0))
            if not self._requests_in_flight:
                self._answer_until_ns = 0
        if self._pending_to_pi:
            try:
                del self._pending_to_pi[: os.write(self._master, self._pending_to_pi)]
            except (BlockingIOError, OSError):
                pass

    def _run_tickers(self) -> None:
        # simulated time never runs ahead of the wall clock, so sleeping the simulated interval
        # is never too long (waiting on the clock's condition instead would wake at every step)
        next_tick = self.now_ns() + self.tick_ns
        while not self._stop.is_set():
            left_ns = next_tick - self.now_ns()
            if left_ns > 0:
                self._stop.wait(left_ns * 1e-9)
                continue
            next_tick += self.tick_ns
            for tick in list(self.tickers):
                tick()

    def wait_until(self, t_ns: int, timeout_s: float) -> bool:
        """Block until simulated time reaches ``t_ns`` (True) or ``timeout_s`` of wall time passed."""
        deadline = time.monotonic() + timeout_s
        with self._advanced:
            while self.now_ns() < t_ns:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._advanced.wait(min(left, 0.01))
        return True

    # the co-MCU
    def reset_mcu(self) -> None:
        """Power-cycle the co-MCU: a new emulator boots the firmware again (reset cause: power-on);
        simulated time goes on. The UART (the pty) stays; bytes in flight are lost."""
        from device.comcu_emulator import SteppedMcuPort

        with self._lock:
            now = self.now_ns() if self.mcu is not None else time.monotonic_ns()
            old = self.mcu
            self.mcu = SteppedMcuPort(self.harness, self.elf, timeout=0.05)
            self._t_base_ns = now - self.mcu.cycle * 1_000_000_000 // self.cpu_hz
            self._rise = None
            self.resets += 1
        if old is not None:
            old.close()

    def open_comcu(self):
        """A CoMcu on the co-MCU's UART (the pty, through pyserial as on a Pi) with the simulated
        clock: what SyncedLaser opens."""
        import serial

        from device.comcu import CoMcu

        try:
            return CoMcu(serial.Serial(self.tty_path, COMCU_BAUDRATE, timeout=0.05), clock_ns=self.now_ns)
        except serial.SerialException as exc:
            raise OSError(str(exc)) from exc

    # the laser pin
    def _collect(self) -> None:
        self.mcu.rx_delims.clear()  # the emulator logs every received delimiter; unused here, unbounded
        edges = self.mcu.edges
        n = len(edges)
        if not n:
            return
        new = edges[:n]
        del edges[:n]
        for cycle, level in new:
            t = self._t_base_ns + cycle * 1_000_000_000 // self.cpu_hz
            latency = 3e-6 + self._rng.exponential(self.gpio_latency_s)
            self._gpio.append((t + int(latency * 1e9), bool(level)))
            if level:
                self._rise = t
            elif self._rise is not None:
                self._windows.append((self._rise, t))
                self._rise = None

    def windows(self, start_ns: int, end_ns: int) -> list[tuple[int, int]]:
        with self._lock:
            self._collect()
            out = [(a, b) for a, b in self._windows if b >= start_ns and a <= end_ns]
            if self._rise is not None and self._rise <= end_ns:
                out.append((self._rise, end_ns))  # still on
            return out

    def laser_on(self) -> bool:
        """The laser pin's level now (simulated time)."""
        with self._lock:
            self._collect()
            return self._rise is not None

    def gpio_edges(self) -> list[tuple[int, bool]]:
        with self._lock:
            self._collect()
            out = list(self._gpio)
            self._gpio.clear()
            return out

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2.0)
        with self._lock:
            self.mcu.close()
        os.close(self._master)
        os.close(self._slave)


# --- the simulated camera, in real time -------------------------------------------------------
class SimCamera:
    """device.process.Camera on simulated hardware: rendered frames delivered when their readout
    ends on the simulated clock (``hw.wait_until``).

    Frame timing from device.sim.timing.CameraClock (its true times are simulated CLOCK_MONOTONIC
    seconds: line-quantised frame length, timestamp latency, dropped frames); a frame is rendered
    ``ready_margin_s`` after its last row is read out, with the laser's on-windows from the
    co-MCU's pin, through the rolling shutter (device/sim/render.py).
    """

    def __init__(self, renderer, hw: SimulatedHardware, timing, *, seed: int = 0, ready_margin_s: float = 0.001):
        self.renderer = renderer
        self.hw = hw
        self.timing = timing
        self.width, self.height = renderer.width, renderer.height
        self.line_time_ns = timing.line_time_s * 1e9
        self.ready_margin_s = ready_margin_s
        self._rng = np.random.default_rng([seed, 0xCA3E])
        self._clock = None
        self._next = None
        self.stall_until_ns = 0  # fault injection: no frame is delivered before this simulated time

    def start(self) -> None:
        from device.sim.timing import CameraClock

        cfg = replace(self.timing, start_time_s=self.hw.now_ns() * 1e-9 + 0.05)
        self._clock = CameraClock(cfg, self._rng)
        self._next = None

    def stop(self) -> None:
        self._clock = None
        self._next = None
        self.hw.limit_ns = None

    def _advance(self):
        while True:
            ft = self._clock.next_frame()
            if not ft.dropped:
                return ft

    def capture(self, timeout_s: float) -> Frame | None:
        from device.sim.render import FrameTiming

        if self._clock is None:
            raise RuntimeError("simulated camera not started")
        ft = self._next or self._advance()
        ready_ns = int((ft.true_start_s + (self.height - 1) * ft.line_time_s + self.ready_margin_s) * 1e9)
        while ready_ns < self.stall_until_ns:  # frames of a stalled camera never arrive
            ft = self._advance()
            ready_ns = int((ft.true_start_s + (self.height - 1) * ft.line_time_s + self.ready_margin_s) * 1e9)
        self.hw.limit_ns = ready_ns + int(ft.frame_duration_s * 1e9)
        if not self.hw.wait_until(ready_ns, timeout_s):
            self._next = ft
            return None
        self._next = None
        t_ns = int(round(ft.true_start_s * 1e9))
        exposure_us = ft.exposure_s * 1e6
        start = t_ns - int(exposure_us * 1e3)
        end = t_ns + int((self.height - 1) * ft.line_time_s * 1e9)
        image, _ = self.renderer.render(FrameTiming(t_ns, exposure_us, ft.line_time_s * 1e9,
                                                    tuple(self.hw.windows(start, end))), self._rng)
        return Frame(image, ft.sequence, ft.sensor_timestamp_ns, exposure_us, ft.frame_duration_s * 1e6,
                     ft.line_time_s * 1e9)


# --- assembly ---------------------------------------------------------------------------------
def sensor_config(config_path: str | None, preset: str) -> SensorConfig:
    return load_config(config_path) if config_path else load_preset(preset)


def laser_limit_mw(cfg: SensorConfig, pulse_s: float, closest_eye_m: float = 0.01) -> float:
    """Class 1 peak power limit (mW) of the configured laser at this pulse width and scan rate
    (device/model/safety.py, eq. 3.45 with the thesis's 1 cm closest eye)."""
    from device.model.safety import PulsedLineLaser, max_power_w

    laser = PulsedLineLaser(cfg.laser.wavelength_m * 1e9, pulse_s, SCAN_RATE_HZ, cfg.laser.fan_angle_rad,
                            cfg.laser.line_height_m, cfg.laser.source_diameter_m)
    return 1e3 * max_power_w(laser, closest_eye_m)


@dataclass
class BuiltSensor:
    """What ``laserpi serve`` runs: the source, its power-on settings, the Class 1 laser limit it
    enforces, what to close at the end, and in simulation the fault injections {name: callable}
    and the simulated hardware."""

    source: SensorSource
    settings: m.ScanSettings
    laser_limit_mw: float
    closers: list
    faults: dict
    hardware: SimulatedHardware | None = None


def build_sensor(args) -> BuiltSensor:
    """The sensor for ``laserpi serve`` (simulated with ``args.simulate``)."""
    from device.sim.timing import CameraTimingConfig
    from device.sync.control import SyncConfig
    from device.synced_laser import SyncedLaser
    from device.vision.pipelines import make_pipeline

    cfg = sensor_config(args.config, args.preset)
    pipeline = make_pipeline(PIPELINE, cfg, *RANGE_M)
    count = args.points or cfg.active_width or cfg.width
    scan = ScanPipeline(pipeline, count)
    g = pipeline.geometry
    row_min, row_max = int(g.roi_lo.min()), int(g.roi_hi.max()) - 1
    # Guards: a 100 us floor and narrowing at most every 5 s keep the controller from re-placing
    # the train for guard changes of tens of microseconds (each new train costs the frames before
    # it, i.e. a scan). Exposure + ROI span + 2 x 1.3 x the 2 ms guard ceiling = 17.3 ms stays
    # inside the firmware's 17.4 ms pulse envelope.
    # (SyncConfig's PING/PONG minimum line times default to device.comcu's 250000 baud.)
    sync = SyncConfig(row_min, row_max, FRAME_DURATION_S, cmd_latency_max_s=COMMAND_LATENCY_S, min_guard_s=100e-6, narrow_interval_s=5.0)
    pulse_s = EXPOSURE_US * 1e-6 + (row_max - row_min) * 18904e-9
    limit = laser_limit_mw(cfg, max(pulse_s, cfg.laser.pulse_s))
    closers = []
    if args.simulate:
        from device.sim.sensor import SensorParams
        from device.sim.render import SceneRenderer
        from device.sim.scene import get_scene

        spec = f"wall:distance={args.distance_m:g}" if args.scene == "wall" else args.scene
        renderer = SceneRenderer(cfg, get_scene(spec), SensorParams(analog_gain=ANALOG_GAIN), seed=args.seed)
        hw = SimulatedHardware(seed=args.seed)
        closers.append(hw.close)
        timing = CameraTimingConfig(frame_duration_s=FRAME_DURATION_S, exposure_s=EXPOSURE_US * 1e-6)
        camera = SimCamera(renderer, hw, timing, seed=args.seed)
        laser = SyncedLaser(hw.open_comcu, sync, gpio_edges=hw.gpio_edges, heartbeat_s=None, clock_ns=hw.now_ns)
        hw.tickers.append(laser.heartbeat)
        clock = lambda: hw.now_ns() * 1e-9  # noqa: E731
        faults = {"comcu-reset": hw.reset_mcu,
                  "camera-stall": lambda: setattr(camera, "stall_until_ns", hw.now_ns() + 1_000_000_000)}
    else:
        import importlib.util

        import serial

        from device.camera.picamera2_camera import Picamera2Camera

        if importlib.util.find_spec("picamera2") is None:
            raise RuntimeError("no camera: picamera2 is not installed (on a Pi: sudo apt install python3-picamera2); "
                               "use --simulate to run the simulated sensor here")
        from device.comcu import CoMcu

        camera = Picamera2Camera(exposure_us=EXPOSURE_US, frame_duration_us=FRAME_DURATION_S * 1e6, analogue_gain=ANALOG_GAIN)

        def open_comcu():
            try:
                return CoMcu(serial.Serial(args.comcu, COMCU_BAUDRATE, timeout=0.05))
            except serial.SerialException as exc:
                raise OSError(str(exc)) from exc

        laser = SyncedLaser(open_comcu, sync)  # GPIO edge timestamps (libgpiod) not wired in yet: pings only
        clock = time.monotonic
        faults, hw = {}, None
    geometry = ScanGeometry(scan.angles.astype(np.float32), *RANGE_M)
    source = SensorSource(camera, laser, scan, geometry, clock=clock)
    power_mw = min(cfg.laser.power_w * 1e3, limit)
    settings = m.ScanSettings(scan_rate_hz=SCAN_RATE_HZ, exposure_us=int(EXPOSURE_US), roi_first=0, roi_count=count,
                              median_window=1, min_quality=0, laser_power_mw=power_mw)
    log.info("sensor %s: %d points, rows %d-%d, pulse %.1f ms, Class 1 limit %.1f mW, %s",
             cfg.name, count, row_min, row_max, pulse_s * 1e3, limit, "simulated" if args.simulate else "on a Pi")
    return BuiltSensor(source, settings, limit, closers, faults, hw)
