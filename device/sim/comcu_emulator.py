"""The real co-MCU firmware running in simavr (firmware_pwm/harness), for tests and simulation.

    with SteppedMcuPort() as port:          # builds nothing; see build_emulator()
        mcu = CoMcu(port)
        mcu.ping()
        port.advance(0.1)                    # 100 ms of simulated time
        port.edges                           # [(cpu_cycle, level), ...] of the true laser pin

SteppedMcuPort is pyserial-like (write, read, in_waiting, timeout) and advances simulated time
only while the host waits for bytes or calls advance(), so runs are deterministic whatever the
load of the machine; its ``timeout`` is in simulated seconds.  The harness's free-running mode
(a pty for pyserial, simulated time paced to the wall clock) is FreeRunningEmulator.  simavr's UART moves bytes in batches, not like a physical line: link
latency is not measured here; pin edges and timer counts are cycle-exact.
"""

from __future__ import annotations

import subprocess
import tempfile
import threading
from pathlib import Path

FIRMWARE_DIR = Path(__file__).resolve().parents[2] / "firmware_pwm"
HARNESS = FIRMWARE_DIR / "build" / "laserpi_harness"
ELF = FIRMWARE_DIR / "build" / "laserpi_pwm.elf"
CPU_HZ = 16_000_000  # the default build's clock; the 8 MHz board's ELF: build_emulator(..., F_CPU=8_000_000)
CYCLES_PER_TICK = 8  # Timer1 prescaler, at every clock: a tick is 0.5 us at 16 MHz, 1 us at 8 MHz


class EmulatorError(RuntimeError):
    """The harness could not be built or stopped answering."""


class HarnessExited(EmulatorError):
    """The harness's process ended: ``returncode`` is its exit status, negative when a signal ended it."""

    def __init__(self, returncode: int, stderr_tail: str):
        super().__init__(f"harness exited ({returncode}): {stderr_tail}")
        self.returncode = returncode


def build_emulator(build_dir: str = "build", **overrides: int) -> tuple[Path, Path]:
    """Builds the firmware ELF and the simavr harness (make -C firmware_pwm all harness).

    Without arguments: the production ELF (the Makefile's envelope, 16 MHz) in firmware_pwm/build.
    Another envelope or clock names a separate ``build_dir`` (relative to firmware_pwm) and the
    Makefile variables to override, given on make's command line (the only way the Makefile takes
    F_CPU), e.g. ``build_emulator("build/test-envelope", MIN_PERIOD_US=300)`` or the 8 MHz board's
    ``build_emulator("build/8mhz", F_CPU=8_000_000)`` (run it with ``cpu_hz=8_000_000``), so that
    the production ELF is never built with them.
    """
    if overrides and build_dir == "build":
        raise ValueError(f"the override {overrides} needs its own build_dir, not the production build")
    args = [f"BUILD={build_dir}"] + [f"{name}={int(value)}" for name, value in overrides.items()]
    proc = subprocess.run(["make", "--no-print-directory", "-C", str(FIRMWARE_DIR), *args, "all", "harness"],
                          capture_output=True, text=True, timeout=300)
    if proc.returncode != 0:
        raise EmulatorError("cannot build the firmware emulator (needs gcc-avr, avr-libc, simavr and "
                            "libsimavr-dev: run `make bootstrap`):\n" + proc.stdout + proc.stderr)
    out = FIRMWARE_DIR / build_dir
    return out / "laserpi_harness", out / "laserpi_pwm.elf"


def _start_harness(args: list[str], **popen) -> tuple[subprocess.Popen, object]:
    """The harness with its stderr in a temporary file: a pipe nobody reads would block it once
    64 KiB were written there (it reports every byte its UART's input queue drops)."""
    err = tempfile.TemporaryFile()
    return subprocess.Popen(args, stderr=err, text=True, bufsize=1, **popen), err


def _stderr_tail(err, limit: int = 4000) -> str:
    """The last ``limit`` bytes the harness wrote to its stderr file."""
    err.flush()
    size = err.seek(0, 2)
    err.seek(max(size - limit, 0))
    return err.read().decode(errors="replace")


class SteppedMcuPort:
    """pyserial-like port onto the firmware in the harness, in lock-step with simulated time.
    ``cpu_hz`` is the clock the ELF was built for (its F_CPU): the harness runs the CPU at it, and
    every conversion between simulated seconds and cycles here uses it."""

    def __init__(self, harness: Path = HARNESS, elf: Path = ELF, *, cpu_hz: int = CPU_HZ, timeout: float = 0.05,
                 step_s: float = 0.0005, boot_s: float = 0.005):
        if not Path(harness).exists() or not Path(elf).exists():
            raise EmulatorError(f"{harness} or {elf} missing: call build_emulator() first")
        self.cpu_hz = cpu_hz
        self.timeout = timeout
        self.step_cycles = int(step_s * cpu_hz)
        self.cycle = 0
        self.edges: list[tuple[int, int]] = []   # (cpu cycle, new level) of the laser pin
        self.rx_delims: list[int] = []           # cpu cycle at which each 0x00 entered the MCU UART
        self.timer_starts: list[int] = []        # cpu cycle of each TCCR1B write (Timer1 start)
        self.resets: list[int] = []              # cpu cycle of each reset()
        self._rx = bytearray()
        self._proc, self._stderr = _start_harness([str(harness), str(elf), "--cpu-hz", str(cpu_hz), "--stepped"],
                                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self.advance(boot_s)  # the UART drops bytes until the firmware has enabled it

    # pyserial-like ---------------------------------------------------------------------------
    def write(self, data: bytes) -> int:
        self._command(f"rx {bytes(data).hex()}")
        return len(data)

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        deadline = self.cycle + int(self.timeout * self.cpu_hz)
        while len(self._rx) < size and self.cycle < deadline:
            self.run_cycles(min(self.step_cycles, deadline - self.cycle))
        out = bytes(self._rx[:size])
        del self._rx[:size]
        return out

    def reset_input_buffer(self) -> None:
        self._rx.clear()

    # simulation ------------------------------------------------------------------------------
    @property
    def seconds(self) -> float:
        return self.cycle / self.cpu_hz

    def timer_count_at(self, cycle: int) -> int:
        """Timer1 count (extended, MCU ticks: CYCLES_PER_TICK cycles at every clock) at a CPU cycle,
        from the last timer start before it."""
        start = max(c for c in self.timer_starts if c <= cycle)
        return (cycle - start) // CYCLES_PER_TICK

    def reset(self, cause: str = "power") -> None:
        """Resets the MCU now as a power-on ("power") or watchdog ("wdt") reset does (its MCUSR
        then reads PORF or WDRF); the laser pin goes low at once, the firmware boots again."""
        if cause not in ("power", "wdt"):
            raise ValueError(f"reset cause must be 'power' or 'wdt', not {cause!r}")
        self._command(f"reset {cause}")
        self.resets.append(self.cycle)

    def advance(self, seconds: float) -> None:
        self.run_cycles(int(round(seconds * self.cpu_hz)))

    def advance_to_tick(self, tick: int) -> None:
        """Runs until this boot's Timer1 count reaches ``tick`` (at once if it has), e.g. past
        ``mcu.Info.first_rise_min_ticks``, before which the firmware lights nothing after a boot."""
        start = self.timer_starts[-1]
        self.run_cycles(max(start + tick * CYCLES_PER_TICK - self.cycle, 0))

    def run_cycles(self, cycles: int) -> None:
        self._command(f"run {int(cycles)}")
        for line in self._proc.stdout:
            kind, _, rest = line.strip().partition(" ")
            if kind == "at":
                self.cycle = int(rest)
                return
            if kind == "tx":
                self._rx += bytes.fromhex(rest)
            elif kind == "edge":
                c, level = rest.split()
                self.edges.append((int(c), int(level)))
            elif kind == "rxdelim":
                self.rx_delims.append(int(rest))
            elif kind == "timer1":
                self.timer_starts.append(int(rest.split()[0]))
            elif kind == "crash":
                raise EmulatorError(f"simulated MCU crashed: {line.strip()}")
        raise HarnessExited(self._proc.wait(), _stderr_tail(self._stderr))

    def _command(self, line: str) -> None:
        try:
            self._proc.stdin.write(line + "\n")
            self._proc.stdin.flush()
        except BrokenPipeError:
            raise HarnessExited(self._proc.wait(), _stderr_tail(self._stderr)) from None

    def close(self) -> None:
        if self._proc.poll() is None:
            try:
                self._proc.stdin.write("quit\n")
                self._proc.stdin.close()
            except BrokenPipeError:
                pass
            try:
                self._proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._proc.stdout.close()
        self._stderr.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class FreeRunningEmulator:
    """The harness with its UART on a pty and simulated time paced to `realtime` x wall clock:
    open ``pty`` with serial.Serial(pty, 250000) like the real link.  A reader thread collects
    the harness's events (``edges``: (cpu cycle, level) of the laser pin); ``cpu_hz`` as for
    SteppedMcuPort."""

    def __init__(self, harness: Path = HARNESS, elf: Path = ELF, realtime: float = 1.0, *, cpu_hz: int = CPU_HZ):
        self._proc, self._stderr = _start_harness([str(harness), str(elf), "--cpu-hz", str(cpu_hz),
                                                   "--realtime", str(realtime)], stdout=subprocess.PIPE)
        self.edges: list[tuple[int, int]] = []
        self.pty = None
        for line in self._proc.stdout:
            kind, _, rest = line.strip().partition(" ")
            if kind == "pty":
                self.pty = rest
                break
        if self.pty is None:
            self._proc.kill()
            self._proc.wait()
            raise EmulatorError(f"harness did not report its pty: {_stderr_tail(self._stderr)}")
        self._reader = threading.Thread(target=self._read_events, daemon=True)
        self._reader.start()

    def _read_events(self) -> None:
        for line in self._proc.stdout:
            kind, _, rest = line.strip().partition(" ")
            if kind == "edge":
                c, level = rest.split()
                self.edges.append((int(c), int(level)))

    def close(self) -> None:
        self._proc.terminate()
        self._proc.wait(timeout=5)
        self._reader.join(timeout=5)
        self._proc.stdout.close()
        self._stderr.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
