"""The simulated Pi's hardware for the device process (``laserpi serve --simulate``): its clock
and its co-MCU, the shipped firmware ELF in the simavr harness, stepped cycle-exactly, whose cycle
count is also the simulated Pi's clock. Its UART is a pty that CoMcu opens through pyserial, as it
opens /dev/serial0 on a Pi. The laser pin's edges become the pulses that light the rendered rows
(the simulated camera, device/sim/camera.py, reads them) and, with a simulated kernel latency, the
GPIO edge events of the laser trigger line for the clock map.

Why the emulator is stepped by the simulated clock and not free-running (the harness's own pty
mode, paced to the wall clock): on this shared 2-core machine the free-running emulator lagged
the wall clock by 10-180 ms, so its MCU clock wandered by thousands of ppm and heartbeats
arrived late; in simulated time nothing depends on how busy the machine is (it only runs slower
than real time then). The pty between the two is the same either way.
"""

from __future__ import annotations

import collections
import logging
import os
import select
import signal
import threading
import time
from pathlib import Path

import numpy as np

from device.laser.comcu import BAUDRATE, open_comcu
from device.laser.synced import HEARTBEAT_S
from device.sim.comcu_emulator import CPU_HZ, ELF, HARNESS, HarnessExited, SteppedMcuPort, build_emulator
from protocol import mcu
from protocol.framing import MAX_PAYLOAD_MCU, FrameError, decode_frame
from protocol.ports import open_raw_pty

log = logging.getLogger(__name__)
#: signals that stop the emulator in an orderly way (its process group stopped), not a crash
STOP_SIGNALS = {signal.SIGTERM, signal.SIGINT, signal.SIGHUP}


#: The Pi's UART receiver, the PL011 of the BCM2835/BCM2837 (Pi Zero 2 W, Pi 3: their uart0 in
#: raspberrypi/linux arch/arm/boot/dts/bcm283x.dtsi, in newer trees under arch/arm/boot/dts/broadcom/,
#: has arm,primecell-periphid 0x00241011, revision 2, so drivers/tty/serial/amba-pl011.c
#: get_fifosize_arm sizes its FIFOs at 16 bytes; the BCM2835 ARM Peripherals manual, 13.1, says 16
#: too), interrupts the kernel when its receive FIFO reaches half of that (amba-pl011.c vendor_arm:
#: .ifls = UART011_IFLS_RX4_8), or when bytes wait and none came for 32 bit periods (the receive
#: timeout interrupt: ARM PrimeCell UART (PL011) TRM, DDI 0183, UARTRTINTR); the driver's handler
#: drains the FIFO into the tty, which wakes the reader once. So a Pi's reader gets a co-MCU reply
#: of ~20 bytes in three pieces, not a byte at a time. (A Pi 4's BCM2711 PL011 is r1p5, 32 bytes
#: deep, interrupting at 16: "ARM: dts: bcm2711: PL011 UARTs are actually r1p5"; not modelled.)
PL011_RX_TRIGGER_BYTES = 8
PL011_RX_TIMEOUT_BITS = 32


def ended_frames(partial: bytearray, data: bytes) -> list[bytes]:
    """The frames (COBS-encoded, without their delimiter) that ``data`` ends after the unfinished
    frame in ``partial``, which then holds the new unfinished rest. Empty frames are none: the Pi
    writes a delimiter before every frame (device.laser.comcu), which the MCU does not answer.
    Not protocol.stream.StreamDecoder: that drops a garbled frame, and the MCU answers one (NACK),
    so the count of requests in flight must keep it."""
    partial += data
    *frames, rest = partial.split(b"\x00")
    partial[:] = rest
    return [bytes(f) for f in frames if f]


def answers_a_request(encoded: bytes) -> bool:
    """Whether a frame from the MCU answers a request (each request gets one answer, a garbled
    one a NACK): all but its unsolicited EDGE reports and boot announcements (INFO of sequence 0)."""
    try:
        frame = decode_frame(encoded, max_payload=MAX_PAYLOAD_MCU)
    except FrameError:
        return True
    return not (frame.msg_type == mcu.Edge.MSG_TYPE or (frame.msg_type == mcu.Info.MSG_TYPE and frame.seq == 0))


class SimulatedHardware:
    """The simulated Pi's CLOCK_MONOTONIC and its co-MCU: the shipped firmware ELF (or ``elf``, a
    build with another envelope, e.g. 20 scans/s: `laserpi design` gives its make line) running in
    the simavr harness (device/sim/comcu_emulator.SteppedMcuPort), cycle-exact, behind a pty.

    Time: simulated CLOCK_MONOTONIC = ``t_base + emulator cycles / CPU_HZ``; a clock thread keeps
    it at the wall clock's rate (it advances the emulator, never ahead of the wall clock, and
    never faster than the wall clock to make up time it fell behind) but not past
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
    Each step is a round trip to the emulator's process, so while the Pi waits for no answer the
    clock advances in steps of at least ``min_step_s`` (the Pi's clock reads the same value
    meanwhile, as the MCU's: bytes it writes enter the MCU at that time); while it waits for one,
    in steps as small as the wall clock allows, as fast as the MCU answers.
    The laser pin's edges (CPU cycles, exact) become the laser's on-windows that light the
    rendered rows (``windows``, a device.sim.pulses.PulseSource) and, plus a simulated kernel
    latency (3 us + exponential, mean ``gpio_latency_s``), the GPIO edge events of the trigger
    line that the clock map uses (``gpio_edges``).
    """

    def __init__(self, *, seed: int = 0, gpio_latency_s: float = 20e-6, tick_s: float = HEARTBEAT_S,
                 history_s: float = 2.0, step_s: float = 0.002, min_step_s: float = 0.001, answer_window_s: float = 0.05,
                 elf: Path | None = None):
        if not HARNESS.exists() or (elf is None and not ELF.exists()):
            build_emulator()  # the harness and the production ELF (the Makefile's envelope)
        elf = ELF if elf is None else Path(elf)
        if not elf.exists():
            raise FileNotFoundError(f"no firmware ELF {elf}: build it with make -C firmware_pwm BUILD=build/NAME "
                                    "<the envelope's variables>")
        self.harness, self.elf, self.cpu_hz = HARNESS, elf, CPU_HZ
        self.gpio_latency_s = gpio_latency_s
        if not 0 < min_step_s <= step_s:
            raise ValueError(f"min_step_s must be in (0, step_s = {step_s}], got {min_step_s}")
        self.tick_ns, self.step_ns, self.min_step_ns = int(tick_s * 1e9), int(step_s * 1e9), int(min_step_s * 1e9)
        self.answer_window_ns = int(answer_window_s * 1e9)
        self.tickers: list = []
        self._rng = np.random.default_rng([seed, 0x6910])
        self._lock = threading.RLock()  # the emulator: one command at a time
        self._advanced = threading.Condition(self._lock)
        self._awaited_ns: list[int] = []  # the simulated times wait_until's callers wait for
        self._windows: collections.deque[tuple[int, int]] = collections.deque(maxlen=int(64 * history_s))
        self._gpio: collections.deque[tuple[int, bool]] = collections.deque(maxlen=1024)
        self._rise: int | None = None
        self.mcu = None
        # this simulated hardware's own CPU (the bench subtracts it: a Pi does not pay it): the clock
        # thread (stepping the emulator), the ticker thread's waiting for simulated time (not the
        # tickers' work), and the simulated kernel's GPIO edge queue (gpio_edges; a libgpiod read on a Pi)
        self.clock_cpu_s = self.ticker_wait_cpu_s = self.gpio_cpu_s = 0.0
        self.limit_ns: int | None = None  # the clock does not pass this (the camera's consumer lags)
        self._answer_until_ns = 0  # requests are in flight: the MCU's time may pass limit_ns until then
        self._requests_in_flight = 0  # frames the Pi sent that the MCU has not answered
        self._partial_from_pi, self._partial_from_mcu = bytearray(), bytearray()  # unfinished frames on the UART
        self.resets = -1
        # the UART: the Pi's end is the pty's slave (raw, like a serial port), the MCU's the master
        self._master, self._slave, self.tty_path = open_raw_pty()
        os.set_blocking(self._master, False)
        self._pending_to_pi = bytearray()
        self._rx_fifo = bytearray()  # the MCU's bytes in the Pi's UART receiver, not yet handed over
        self._rx_last_ns = 0  # when the newest of them arrived (simulated time)
        self._rx_timeout_ns = PL011_RX_TIMEOUT_BITS * 1_000_000_000 // BAUDRATE
        self._t_base_ns = time.monotonic_ns()
        self._lag_ns = 0  # how far simulated time has fallen behind the wall clock for good
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
        try:
            self._step_clock()
        except HarnessExited as exc:
            if -exc.returncode not in STOP_SIGNALS:
                raise  # an exit of its own, or a crash (SIGSEGV, SIGABRT, the OOM killer's SIGKILL)
            # stopping the process group (timeout, systemd stop, Ctrl-C) signals it and this process at once
            log.warning("the co-MCU emulator was ended by %s; the simulated clock stops",
                        signal.Signals(-exc.returncode).name)

    def _step_clock(self) -> None:
        while not self._stop.is_set():
            self.clock_cpu_s = time.thread_time()  # stepping the emulator: simulation cost, not the device's
            self._pi_to_mcu()
            now = self.now_ns()
            target = time.monotonic_ns() - self._lag_ns
            if target - now > self.step_ns:
                # behind the wall clock (held at limit_ns, or this thread was descheduled): the
                # simulated world falls behind for good instead of racing to catch up, which
                # would hand the device a burst of frames faster than real time, and the host
                # link (paced in wall time) a burst of scans it cannot carry
                self._lag_ns += target - now - self.step_ns
                target = now + self.step_ns
            limit = self.limit_ns
            # bytes in the Pi's UART receiver are handed over after its timeout, held or not
            rx_due = self._rx_last_ns + self._rx_timeout_ns if self._rx_fifo else 0
            end = target if limit is None else min(target, max(limit, self._answer_until_ns, rx_due))
            # each step is a round trip to the emulator's process: at least min_step_ns of simulated
            # time, unless the Pi waits for an answer or for the receiver's timeout, or the step
            # reaches the limit
            quantum = 0 if self._requests_in_flight or rx_due or end < target else self.min_step_ns
            if end - now <= quantum:
                # wait for the wall clock, or at once for bytes from the Pi
                select.select([self._master], [], [], min(0.002, max((now - end + quantum) * 1e-9, 0.0005)))
                continue
            step_end = min(end, now + self.step_ns)
            with self._lock:
                self.mcu.run_cycles(max(1, (step_end - now) * self.cpu_hz // 1_000_000_000))
                self._collect()
                self._mcu_to_pi()
                if self._awaited_ns and self.now_ns() >= min(self._awaited_ns):
                    self._advanced.notify_all()  # not at every step: a waiter wakes when its time has come

    def _pi_to_mcu(self) -> None:
        """Bytes the Pi wrote to its end of the UART go into the MCU's receiver now."""
        try:
            data = os.read(self._master, 4096)
        except (BlockingIOError, OSError):  # nothing written (or no reader attached yet)
            return
        if data:
            with self._lock:
                self.mcu.write(data)
                requests = len(ended_frames(self._partial_from_pi, data))
                if requests:
                    self._requests_in_flight += requests
                    self._answer_until_ns = self.now_ns() + self.answer_window_ns

    def _mcu_to_pi(self) -> None:
        """What the MCU sent goes to the Pi's end of the UART as the Pi's UART hands it over
        (PL011_RX_TRIGGER_BYTES, PL011_RX_TIMEOUT_BITS; kept while the pty is full). A request
        counts as answered when its answer reaches the Pi: until then the clock steps finely."""
        now = self.now_ns()
        n = self.mcu.in_waiting
        if n:
            self._rx_fifo += self.mcu.read(n)
            self._rx_last_ns = now
        if self._rx_fifo and (len(self._rx_fifo) >= PL011_RX_TRIGGER_BYTES or now - self._rx_last_ns >= self._rx_timeout_ns):
            out = bytes(self._rx_fifo)
            self._rx_fifo.clear()
            self._pending_to_pi += out
            answers = sum(map(answers_a_request, ended_frames(self._partial_from_mcu, out)))
            self._requests_in_flight = max(0, self._requests_in_flight - answers)
            if not self._requests_in_flight:
                self._answer_until_ns = 0
        if self._pending_to_pi:
            try:
                del self._pending_to_pi[: os.write(self._master, self._pending_to_pi)]
            except (BlockingIOError, OSError):
                pass

    def _run_tickers(self) -> None:
        # woken by the clock thread when simulated time reaches the tick (wait_until), not by
        # sleeping the interval in wall time: the clock lags the wall clock by up to a step, and
        # polling for it would wake several times a tick
        next_tick = self.now_ns() + self.tick_ns
        work_s = 0.0
        while not self._stop.is_set():
            self.ticker_wait_cpu_s = time.thread_time() - work_s
            if not self.wait_until(next_tick, 0.1):
                continue
            next_tick += self.tick_ns
            started = time.thread_time()
            for tick in list(self.tickers):
                tick()
            work_s += time.thread_time() - started

    def wait_until(self, t_ns: int, timeout_s: float) -> bool:
        """Block until simulated time reaches ``t_ns`` (True) or ``timeout_s`` of wall time passed."""
        deadline = time.monotonic() + timeout_s
        with self._advanced:
            self._awaited_ns.append(t_ns)
            try:
                while self.now_ns() < t_ns:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        return False
                    self._advanced.wait(left)  # the clock thread notifies when t_ns has come
            finally:
                self._awaited_ns.remove(t_ns)
        return True

    # the co-MCU
    def reset_mcu(self) -> None:
        """Power-cycle the co-MCU: a new emulator boots the firmware again (reset cause: power-on);
        simulated time goes on. The UART (the pty) stays; bytes in flight are lost."""
        with self._lock:
            now = self.now_ns() if self.mcu is not None else time.monotonic_ns()
            old = self.mcu
            self.mcu = SteppedMcuPort(self.harness, self.elf, timeout=0.05)
            self._t_base_ns = now - self.mcu.cycle * 1_000_000_000 // self.cpu_hz
            self._rise = None
            self._requests_in_flight, self._answer_until_ns = 0, 0  # the old MCU answers none of them
            self._partial_from_mcu.clear()
            self._rx_fifo.clear()
            self.resets += 1
        if old is not None:
            old.close()

    def open_comcu(self):
        """A CoMcu on the co-MCU's UART (the pty, through pyserial as on a Pi) with the simulated
        clock: what SyncedLaser opens."""
        return open_comcu(self.tty_path, clock_ns=self.now_ns)

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
        started = time.thread_time()
        with self._lock:
            self._collect()
            out = list(self._gpio)
            self._gpio.clear()
        self.gpio_cpu_s += time.thread_time() - started
        return out

    @property
    def lag_s(self) -> float:
        """How far simulated time has fallen behind the wall clock for good (_run_clock): the
        simulated sensor's frames, and so its scans, come that much later than a real one's."""
        return self._lag_ns * 1e-9

    @property
    def cpu_s(self) -> float:
        """This simulated hardware's own CPU time so far (see __init__)."""
        return self.clock_cpu_s + self.ticker_wait_cpu_s + self.gpio_cpu_s

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2.0)
        with self._lock:
            self.mcu.close()
        os.close(self._master)
        os.close(self._slave)
