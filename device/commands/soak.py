"""`laserpi soak --minutes 10`: a long run of the simulated sensor, watching memory and lost scans.

Starts ``laserpi serve --simulate`` behind a pty, reads every scan with host_sdk.LaserPi, samples
the device process's resident memory (RSS) every ``--sample-s`` seconds, and at the end asks the
device for its health. Verdict (exit code 0 = PASS):

* memory steady: the least-squares slope of RSS over the second half of the run (after warm-up,
  caches filled) extrapolated over that half is below ``--max-growth-mb``;
* no scans lost beyond those counted: every gap in the scan sequence the host saw is a scan the
  device counted as dropped on a slow link (HEALTH.scans_dropped) or the host's own queue dropped
  (stats.scans_dropped); and no frame arrived corrupted (CRC or decode errors).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from host_sdk.commands.argtypes import positive_float


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--minutes", type=positive_float, default=10.0, help="length of the run (default 10)")
    parser.add_argument("--sample-s", type=positive_float, default=5.0, help="RSS sampling interval")
    parser.add_argument("--max-growth-mb", type=positive_float, default=5.0,
                        help="largest RSS growth over the second half that still counts as steady")
    parser.add_argument("--scene", default="wall", help="simulated scene")
    parser.add_argument("--mock", action="store_true", help="soak the analytic mock instead of the full simulation")
    parser.add_argument("--log", default="out/soak-serve.log", help="where the device process logs")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


@dataclass(frozen=True)
class SoakResult:
    seconds: float
    scans: int
    scans_per_s: float
    seq_gaps: int  # scans missing from the host's sequence
    device_dropped: int  # scans the device dropped on a slow link (counted)
    host_dropped: int  # scans the host queue dropped (counted)
    corrupt_frames: int
    rss_start_mb: float
    rss_end_mb: float
    rss_growth_mb: float  # fitted growth over the second half
    lost_uncounted: int
    memory_steady: bool
    verdict: str


def rss_growth_mb(t_s: np.ndarray, rss_bytes: np.ndarray) -> float:
    """Least-squares RSS growth (MB) over the second half of the samples, across that half's span."""
    t = np.asarray(t_s, dtype=np.float64)
    r = np.asarray(rss_bytes, dtype=np.float64) / 1e6
    if t.shape != r.shape or t.ndim != 1:
        raise ValueError(f"times {t.shape} and rss {r.shape} must be equal 1-D shapes")
    half = t.size // 2
    t, r = t[half:], r[half:]
    if t.size < 2 or t[-1] == t[0]:
        return 0.0
    slope = np.polyfit(t - t[0], r, 1)[0]
    return float(slope * (t[-1] - t[0]))


def verdict(seconds: float, scans: int, seq_gaps: int, device_dropped: int, host_dropped: int, corrupt: int,
            t_s: np.ndarray, rss: np.ndarray, max_growth_mb: float) -> SoakResult:
    growth = rss_growth_mb(t_s, rss)
    lost = max(0, seq_gaps - device_dropped - host_dropped) + corrupt
    steady = growth < max_growth_mb
    ok = steady and lost == 0 and scans > 0
    return SoakResult(seconds, scans, scans / seconds if seconds > 0 else 0.0, seq_gaps, device_dropped, host_dropped,
                      corrupt, float(rss[0]) / 1e6, float(rss[-1]) / 1e6, growth, lost, steady,
                      "PASS" if ok else "FAIL")


def run(args: argparse.Namespace) -> int:
    import host_sdk
    from device.service.child import rss_bytes, start_serve, stop_serve
    from device.sim.scene import SceneError, get_scene

    try:
        get_scene(args.scene)  # named here, as serve would name it, before anything starts
    except SceneError as exc:
        print(f"laserpi soak: {exc}")
        return 2
    serve_args = ["--simulate", "--scene", args.scene] + (["--mock"] if args.mock else [])
    duration = args.minutes * 60.0
    Path(args.log).parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="laserpi-soak-") as tmp:
        link = Path(tmp) / "laserpi"
        try:
            proc = start_serve(link, serve_args, log_path=Path(args.log))
        except RuntimeError as exc:
            print(f"laserpi soak: {exc}")
            return 1
        times, rss = [], []
        scans = 0
        seqs_seen_gap = 0
        try:
            with host_sdk.LaserPi(str(link), timeout_s=5.0) as sensor:
                t0 = time.monotonic()
                next_sample = t0
                last_seq = None
                for scan in sensor.scans():
                    now = time.monotonic()
                    scans += 1
                    if last_seq is not None and scan.seq != last_seq + 1:
                        seqs_seen_gap += (scan.seq - last_seq - 1) & 0xFFFFFFFF
                    last_seq = scan.seq
                    if now >= next_sample:
                        times.append(now - t0)
                        rss.append(rss_bytes(proc.pid))
                        next_sample += args.sample_s
                        if not args.json:
                            print(f"{now - t0:7.1f} s  {scans:6d} scans  RSS {rss[-1] / 1e6:7.1f} MB  "
                                  f"gaps {seqs_seen_gap}", flush=True)
                    if now - t0 >= duration:
                        break
                seconds = time.monotonic() - t0
                health = sensor.health()
                stats = sensor.stats
                host_dropped = stats.scans_dropped
                corrupt = stats.crc_errors + stats.decode_errors
        finally:
            stop_serve(proc)
    result = verdict(seconds, scans, seqs_seen_gap, health.scans_dropped, host_dropped, corrupt,
                     np.array(times), np.array(rss, dtype=np.float64), args.max_growth_mb)
    if args.json:
        print(json.dumps(asdict(result)))
    else:
        print(f"{result.verdict}: {result.scans} scans in {result.seconds:.0f} s ({result.scans_per_s:.2f}/s); "
              f"RSS {result.rss_start_mb:.1f} -> {result.rss_end_mb:.1f} MB, second-half growth "
              f"{result.rss_growth_mb:+.2f} MB (limit {args.max_growth_mb:g}); sequence gaps {result.seq_gaps}, "
              f"counted drops {result.device_dropped} device + {result.host_dropped} host, corrupt frames "
              f"{result.corrupt_frames}, lost beyond counted {result.lost_uncounted}")
    return 0 if result.verdict == "PASS" else 1
