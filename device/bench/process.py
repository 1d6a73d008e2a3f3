"""`laserpi bench process`: CPU time per scan of the device process, and Pi Zero 2 W headroom.

Runs ``laserpi serve --simulate --stats-file`` behind a pty, reads its scans with the host SDK,
and takes the process's CPU time (getrusage: all its threads) between a snapshot after warm-up
and the one it writes at exit. What the simulation itself costs is subtracted, because a Pi does
not pay it: rendering the frames (the simulated camera's capture), stepping the co-MCU emulator
(the simulated clock thread; the emulator is a separate process anyway), the simulated
hardware's ticker thread waiting for simulated time (the heartbeats it runs are counted), and
its simulated GPIO edge queue (a libgpiod read on a Pi, not measured here). The simulated serve
runs OpenCV on one thread (device/service/assembly.py), so that every OpenCV call's CPU is the
calling thread's (the renderer's, or the pipeline's), not that of worker threads no per-thread
figure can attribute. What remains
is the device: the pipeline, the synchronisation and co-MCU link, pairing, the scan link
(encoding, writing), and the orchestration around them.

Not included: the Pi's own camera capture path (picamera2 hands over the Y plane of each frame in
its own thread); it is not simulated, so not measured here.

Measured beside it, not in the device figure: a Pi's heartbeat thread waking every HEARTBEAT_S
(device/laser/synced.py ``_heartbeat_loop``). In simulation the heartbeats run on the simulated
clock's ticker thread, whose waiting is subtracted, so a thread of this process does that
thread's timed wait over the measured span (``heartbeat_wait_cpu``), without its write (the
write is the serve's, and counted); its CPU a scan is ``heartbeat_wait_ms_per_scan``. A timed
wake-up costs a KVM guest more than it may cost a Pi on the metal (the timer's exits to the
hypervisor), so the estimate is given with and without it.

On a Pi, ``--stats FILE`` measures the real figure instead: it reads the stats file of a running
``laserpi serve --stats-file FILE`` (streaming scans to a host meanwhile) at the start and the end
of ``--seconds`` and reports the CPU per scan of that process, camera capture included, as a
measurement on that machine (its model from the device tree). That, not the estimate below, is
the number to quote for a Pi.

Headroom on a Pi Zero 2 W (4 x Cortex-A53 at 1 GHz) is an estimate: device CPU per scan here
times ``--slowdown`` (default 15: clock 1 GHz against ~3 GHz, about 2.5x lower IPC of the in-order
A53, and half the SIMD width of NEON against AVX2 for the numpy/OpenCV-heavy parts; plausible
range 8-25), against the time a scan may take at its rate on one core.

``--scan-rate-hz``: the thesis preset made to run at that rate (device/design/report.py
sensor_at_rate: its laser at the Class 1 power of the rate's firmware envelope) with the co-MCU
firmware built with that envelope (in firmware_pwm/build/rate-<min period us>), serving the
same 1640 points per scan on a link paced like USB CDC (LINK_BAUD) where 921600 baud would not
carry them (protocol/SPEC.md section 5).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import threading
import time
from pathlib import Path

from host_sdk.commands.argtypes import positive_float

PRESET = "thesis-calibrated"
#: The pty's pacing where the 921600 baud UART cannot carry the scans: USB CDC full speed, ~8 Mbit/s.
LINK_BAUD = 8_000_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seconds", type=positive_float, default=20.0, help="measured span after warm-up")
    parser.add_argument("--warmup", type=float, default=6.0, help="seconds before the first snapshot")
    parser.add_argument("--slowdown", type=float, default=15.0, help="Cortex-A53 @ 1 GHz per-core slowdown vs here")
    parser.add_argument("--scan-rate-hz", type=float, default=None,
                        help=f"scans/s (default: the {PRESET} preset's 10; another rate runs the co-MCU firmware "
                             "built for it)")
    parser.add_argument("--stats", metavar="JSON", default=None,
                        help="measure a running `laserpi serve --stats-file JSON` (on a Pi: the real figure) instead "
                             "of a simulated one")
    parser.add_argument("--json", action="store_true")


def machine() -> str:
    """The board's model (device tree, as on a Pi) or the CPU architecture."""
    import platform

    model = Path("/proc/device-tree/model")
    return model.read_text().rstrip("\x00\n") if model.exists() else f"{platform.machine()} ({platform.node()})"


def measure_running(stats: Path, seconds: float) -> dict:
    """CPU per scan of a running serve from its stats file, ``seconds`` apart: all of it is the device's."""
    if not stats.exists():
        raise FileNotFoundError(f"{stats}: no stats file; run `laserpi serve ... --stats-file {stats}` with a host reading scans")
    first = json.loads(stats.read_text())
    time.sleep(seconds)
    last = json.loads(stats.read_text())
    return cost_per_scan(first, last, simulated=False)


def cost_per_scan(a: dict, b: dict, simulated: bool = True) -> dict:
    """CPU ms per scan between two stats snapshots of `laserpi serve --stats-file`; ``simulated``:
    the simulation's share (rendering as the camera, the emulator's clock) is subtracted, else
    the camera's capture is the device's own."""
    scans = b["source"]["scans_made"] - a["source"]["scans_made"]
    if scans <= 0:
        raise ValueError("no scans between the snapshots")

    def d(key, sub=None):
        return (b[sub][key] - a[sub][key]) if sub else (b[key] - a[key])

    process = d("cpu_process_s")
    render = d("cpu_camera_s", "source") if simulated else 0.0
    hardware = d("cpu_sim_hardware_s")  # the simulated hardware's own threads and its GPIO queue (0 on a Pi)
    device = process - render - hardware
    laser = d("cpu_laser_s", "source") - d("cpu_sim_gpio_s")  # the laser step read the simulated GPIO queue
    # the simulated sensor's time falls behind the wall clock where this machine cannot simulate
    # in real time (device/sim/hardware.py _run_clock); its frames then come that much later.
    # Absent (a Pi's serve, or an older stats file): none
    behind = d("sim_lag_s") if "sim_lag_s" in a and "sim_lag_s" in b else 0.0
    return {
        "scans": scans,
        "scan_rate_hz": scans / d("monotonic_s"),
        "sensor_scan_rate_hz": scans / (d("monotonic_s") - behind),
        "simulation_behind_pct": 100 * behind / d("monotonic_s"),
        "process_ms_per_scan": 1e3 * process / scans,
        "simulation_ms_per_scan": 1e3 * (render + hardware) / scans,
        "device_ms_per_scan": 1e3 * device / scans,
        "pipeline_ms_per_scan": 1e3 * d("cpu_pipeline_s", "source") / scans,
        "laser_sync_ms_per_scan": 1e3 * laser / scans,
        "other_ms_per_scan": 1e3 * (device - d("cpu_pipeline_s", "source") - laser) / scans,
    }


def rate_arguments(rate_hz: float, tmp: Path) -> list[str]:
    """`laserpi serve` arguments for the preset at ``rate_hz`` scans/s (module doc)."""
    from device.config import load_preset, save_config
    from device.design.report import sensor_at_rate
    from device.model.envelope import parse_makefile_envelope
    from device.sim.comcu_emulator import FIRMWARE_DIR, build_emulator
    from protocol import messages as m

    cfg, envelope = sensor_at_rate(load_preset(PRESET), rate_hz)
    save_config(cfg, tmp / "sensor.toml")
    args = ["--config", str(tmp / "sensor.toml")]
    if envelope != parse_makefile_envelope((FIRMWARE_DIR / "Makefile").read_text()):
        _, elf = build_emulator(envelope.build_dir, MAX_PULSE_US=envelope.max_pulse_us,
                                MAX_DUTY_PPM=envelope.max_duty_ppm, MIN_PERIOD_US=envelope.min_period_us)
        args += ["--firmware", str(elf)]
    if m.link_budget_refusal(cfg.active_width or cfg.width, rate_hz, 921_600) is not None:
        args += ["--baud", str(LINK_BAUD)]
    return args


def run(args: argparse.Namespace) -> int:
    if args.stats:
        try:
            r = measure_running(Path(args.stats), args.seconds)
        except (OSError, ValueError, KeyError) as exc:
            print(f"laserpi bench process: {exc}")
            return 2
        r.update(measured_on=machine(), cores_at_scan_rate=r["device_ms_per_scan"] * r["scan_rate_hz"] / 1e3)
        lines = [f"MEASURED on {r['measured_on']}: {r['scans']} scans at {r['scan_rate_hz']:.2f} Hz, "
                 f"{r['device_ms_per_scan']:.1f} ms CPU per scan (pipeline {r['pipeline_ms_per_scan']:.1f}, laser/sync "
                 f"{r['laser_sync_ms_per_scan']:.1f}, other incl. capture {r['other_ms_per_scan']:.1f}) = "
                 f"{r['cores_at_scan_rate']:.2f} cores"]
    else:
        r = simulated_cost(args.warmup, args.seconds, args.scan_rate_hz)
        rate_hz = 10.0 if args.scan_rate_hz is None else args.scan_rate_hz
        pi_ms = r["device_ms_per_scan"] * args.slowdown
        pi_hb_ms = (r["device_ms_per_scan"] + r["heartbeat_wait_ms_per_scan"]) * args.slowdown
        r.update(slowdown=args.slowdown, pi_zero2w_ms_per_scan=pi_ms, pi_zero2w_cores_at_rate=pi_ms * rate_hz / 1e3,
                 pi_zero2w_cores_at_rate_with_heartbeat_wait=pi_hb_ms * rate_hz / 1e3)
        lines = [f"{r['scans']} scans at {r['scan_rate_hz']:.2f} Hz ({r['sensor_scan_rate_hz']:.2f} Hz in the simulated "
                 f"sensor's time: the simulation fell {r['simulation_behind_pct']:.1f} % behind the wall clock)",
                 f"process {r['process_ms_per_scan']:.1f} ms CPU/scan = "
                 f"simulation {r['simulation_ms_per_scan']:.1f} + device {r['device_ms_per_scan']:.1f} "
                 f"(pipeline {r['pipeline_ms_per_scan']:.1f}, laser/sync {r['laser_sync_ms_per_scan']:.1f}, "
                 f"other {r['other_ms_per_scan']:.1f})",
                 f"Pi Zero 2 W ESTIMATE, not a measurement (x{args.slowdown:g}): {pi_ms:.0f} ms CPU per scan, "
                 f"{100 * r['pi_zero2w_cores_at_rate']:.0f} % of one of its 4 cores at {rate_hz:g} Hz; on the Pi, `laserpi bench process "
                 "--stats FILE` measures it",
                 f"not in it: a Pi's heartbeat thread's timed wake-ups, {r['heartbeat_wait_ms_per_scan']:.2f} ms CPU/scan here "
                 f"(its wait, measured beside the serve); with them {100 * r['pi_zero2w_cores_at_rate_with_heartbeat_wait']:.0f} %"]
    print(json.dumps(r) if args.json else "\n".join(lines))
    return 0


def heartbeat_wait_cpu(stop: threading.Event, interval_s: float) -> tuple[float, float, int]:
    """The heartbeat thread's wait (SyncedLaser._heartbeat_loop: its ``pause_between_heartbeats``)
    until ``stop`` is set, without its write: (thread CPU s, wall s, wake-ups)."""
    from device.laser.synced import pause_between_heartbeats

    cpu, wall, wakeups = time.thread_time(), time.monotonic(), 0
    while not pause_between_heartbeats(stop, interval_s):
        wakeups += 1
    return time.thread_time() - cpu, time.monotonic() - wall, wakeups


def simulated_cost(warmup_s: float, seconds: float, scan_rate_hz: float | None = None) -> dict:
    """CPU per scan of ``laserpi serve --simulate`` read by the host SDK (the module docstring)."""
    import host_sdk
    from device.laser.synced import HEARTBEAT_S
    from device.service.child import start_serve, stop_serve

    probe_stop, probe = threading.Event(), []
    prober = threading.Thread(target=lambda: probe.append(heartbeat_wait_cpu(probe_stop, HEARTBEAT_S)),
                              name="heartbeat-wait", daemon=True)

    with tempfile.TemporaryDirectory(prefix="laserpi-bench-") as tmp:
        link, stats = Path(tmp) / "laserpi", Path(tmp) / "stats.json"
        rate = [] if scan_rate_hz is None else rate_arguments(scan_rate_hz, Path(tmp))
        proc = start_serve(link, ["--simulate", "--scene", "wall", "--stats-file", str(stats), *rate],
                           log_path=Path(tmp) / "serve.log")
        try:
            with host_sdk.LaserPi(str(link), timeout_s=15.0) as sensor:
                it = sensor.scans()
                end = time.monotonic() + warmup_s
                while time.monotonic() < end:
                    next(it)
                first = json.loads(stats.read_text())
                prober.start()
                end = time.monotonic() + seconds
                while time.monotonic() < end:
                    next(it)
                probe_stop.set()
                prober.join()
        finally:
            probe_stop.set()
            stop_serve(proc)
        last = json.loads(stats.read_text())
    r = cost_per_scan(first, last)
    cpu_s, wall_s, wakeups = probe[0]
    r.update(heartbeat_wait_ms_per_scan=1e3 * cpu_s / wall_s / r["scan_rate_hz"], heartbeat_wakeups_per_s=wakeups / wall_s)
    return r
