"""`laserpi bench protocol`: scan encode/decode throughput, bytes per point, wire budget.

One thread (one core). Full rate is the thesis's sensor: 10 Hz x 1640 points = 16 400 points/s;
the goal is decoding at >= 100x that. Variants, timed in one run on the same scans:
  receiver     the host's whole receive path (bytes -> StreamDecoder -> message -> Scan), what
               LaserPi.scans() and replay() run
  frames+msg   StreamDecoder and ScanMessage.decode without building Scan objects
  msg only     ScanMessage.decode of payloads (no COBS, no CRC)
  ranges: lut  u16 codes -> metres by a 64 Ki-entry table (what messages.decode_ranges does)
  ranges: math the same by multiply + np.where for the reserved codes (the alternative)
  encode       ScanMessage.encode + encode_frame (the device side)
Error beside speed: the largest quantisation error of the range codes over the bench's ranges.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from host_sdk.commands.argtypes import positive_float

FULL_RATE_HZ = 10.0
FULL_POINTS = 1640
LINKS = {"UART 460800": 460800, "UART 921600": 921600, "USB CDC (full speed, ~8 Mbit/s usable)": 8_000_000}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.add_argument("--seconds", type=positive_float, default=1.0, help="time per variant")


def _rate(fn, seconds: float) -> float:
    """Calls of fn per second, best of three runs of ~seconds/3."""
    fn()
    best = 0.0
    for _ in range(3):
        n, t0 = 0, time.perf_counter()
        while True:
            fn()
            n += 1
            dt = time.perf_counter() - t0
            if dt >= seconds / 3:
                break
        best = max(best, n / dt)
    return best


def _ranges_math(codes: np.ndarray) -> np.ndarray:
    from protocol import messages as m

    r = (codes * m.RANGE_UNIT_M).astype(np.float32)  # float64 product, as the table is built
    r = np.where(codes == m.RANGE_CODE_NAN, np.nan, r)
    r = np.where(codes == m.RANGE_CODE_POS_INF, np.inf, r)
    return np.where(codes == m.RANGE_CODE_NEG_INF, -np.inf, r).astype(np.float32)


def measure(seconds: float = 1.0) -> dict:
    from host_sdk.receiver import Receiver
    from protocol import messages as m
    from protocol.framing import encode_frame
    from protocol.stream import StreamDecoder

    rng = np.random.default_rng(0)
    k = 10  # scans per chunk: one second of full-rate data
    ranges = rng.uniform(0.1, 3.0, (k, FULL_POINTS))
    ranges[:, ::50] = np.inf
    ranges[:, 7::97] = np.nan
    quality = rng.integers(0, 256, (k, FULL_POINTS), dtype=np.uint8)
    msgs = [m.ScanMessage(i, 1000 * i, 0, 500, 0, ranges[i], quality[i]) for i in range(k)]
    payloads = [x.encode() for x in msgs]
    info = m.Info(1, 0, "bench", "B", FULL_RATE_HZ, 0.1, 3.0, np.linspace(0.9, -0.9, FULL_POINTS, dtype=np.float32),
                  m.ScanSettings(10.0, 1000, 0, FULL_POINTS, 1, 0, 1.0), 5.0)
    wire = b"".join(encode_frame(m.MsgType.SCAN, i, p) for i, p in enumerate(payloads))
    codes = m.encode_ranges(ranges[0])

    def receiver():
        rx = Receiver(921600)
        rx.set_info(info)  # as LaserPi does with the INFO it asked for
        rx.feed(b"\x00", 0.0)  # the delimiter before the first frame (as after an INFO)
        assert sum(1 for _ in rx.feed(wire, 0.0)) == k

    def frames_msg():
        dec = StreamDecoder(synced=True)
        for rec in dec.feed(wire):
            m.ScanMessage.decode(rec.frame.payload)

    def msg_only():
        for p in payloads:
            m.ScanMessage.decode(p)

    def encode():
        for i, x in enumerate(msgs):
            encode_frame(m.MsgType.SCAN, i, x.encode())

    full_pts = FULL_RATE_HZ * FULL_POINTS
    variants = {}
    for name, fn, pts in (("receiver", receiver, k * FULL_POINTS), ("frames+msg", frames_msg, k * FULL_POINTS),
                          ("msg only", msg_only, k * FULL_POINTS),
                          ("ranges: lut", lambda: m.decode_ranges(codes), FULL_POINTS),
                          ("ranges: math", lambda: _ranges_math(codes), FULL_POINTS),
                          ("encode", encode, k * FULL_POINTS)):
        pps = _rate(fn, seconds) * pts
        variants[name] = {"points_per_s": pps, "x_full_rate": pps / full_pts}
    assert np.array_equal(m.decode_ranges(codes), _ranges_math(codes), equal_nan=True)
    fin = np.isfinite(ranges)
    decoded = np.stack([m.ScanMessage.decode(p).ranges_m for p in payloads])
    quant_err = float(np.abs(decoded[fin] - ranges[fin]).max())
    frame_bytes = m.scan_wire_bytes(FULL_POINTS)
    bytes_per_s = frame_bytes * FULL_RATE_HZ
    budget = {}
    for link, bps in LINKS.items():
        capacity = bps / m.UART_BITS_PER_BYTE
        budget[link] = {"capacity_bytes_per_s": capacity, "utilisation": bytes_per_s / capacity,
                        "headroom": 1 - bytes_per_s / capacity,
                        "max_rate_hz_30pct_headroom": 0.7 * capacity / frame_bytes}
    return {"points_per_scan": FULL_POINTS, "full_rate_points_per_s": full_pts, "variants": variants,
            "wire_bytes_per_scan": frame_bytes, "bytes_per_point": frame_bytes / FULL_POINTS,
            "range_quantisation_error_max_m": quant_err, "budget": budget}


def run(args: argparse.Namespace) -> int:
    res = measure(args.seconds)
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    print(f"scan of {res['points_per_scan']} points: {res['wire_bytes_per_scan']} bytes on the wire, "
          f"{res['bytes_per_point']:.3f} bytes/point; range quantisation error <= "
          f"{res['range_quantisation_error_max_m'] * 1e3:.3f} mm")
    base = res["variants"]["receiver"]["points_per_s"]
    print(f"{'variant':<14} {'Mpoints/s':>10} {'x full rate':>12} {'vs receiver':>12}")
    for name, v in res["variants"].items():
        print(f"{name:<14} {v['points_per_s'] / 1e6:>10.2f} {v['x_full_rate']:>12.0f} {v['points_per_s'] / base:>12.2f}")
    print(f"\n{'link':<40} {'utilisation':>11} {'headroom':>9} {'max Hz @30% headroom':>21}")
    for link, b in res["budget"].items():
        print(f"{link:<40} {b['utilisation']:>10.0%} {b['headroom']:>9.0%} {b['max_rate_hz_30pct_headroom']:>21.1f}")
    return 0
