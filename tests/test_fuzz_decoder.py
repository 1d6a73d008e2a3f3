"""Fuzzing the receive path (the Receiver that LaserPi.scans() and replay() run): it never
raises, never yields a scan that was not sent exactly so, and yields every intact frame."""

import random

import numpy as np
from hypothesis import HealthCheck, given, settings, strategies as st

import host_sdk
from host_sdk.receiver import Receiver
from protocol import messages as m
from protocol.framing import encode_frame
from protocol.mock_wall import wall_ranges

N_ANGLES = 48
INFO = m.Info(1, 0, "fuzz", "F-1", 10.0, 0.1, 3.0, np.linspace(0.6, -0.6, N_ANGLES, dtype=np.float32),
              m.ScanSettings(10.0, 1000, 0, N_ANGLES, 1, 0, 1.0), 5.0)
SPECIAL = np.array([np.nan, np.inf, -np.inf], dtype=np.float32)


def make_scan(rng: random.Random, seq: int) -> m.ScanMessage:
    n = rng.randrange(1, N_ANGLES + 1)
    first = rng.randrange(0, N_ANGLES - n + 1)
    nprng = np.random.default_rng(rng.randrange(1 << 30))
    r = nprng.uniform(0.0, 16.0, n)
    r[nprng.random(n) < 0.1] = np.nan
    r[nprng.random(n) < 0.1] = np.inf
    r[nprng.random(n) < 0.1] = -np.inf
    q = nprng.integers(0, 256, n, dtype=np.uint8)
    # what the receiver should return is the quantised scan
    return m.ScanMessage.decode(m.ScanMessage(seq, 1000 * seq, 5, 0, first, r, q).encode())


def same(a, b) -> bool:
    return (a.seq == b.scan_seq and a.device_time == b.device_time_us * 1e-6 and a.ranges.size == b.ranges_m.size
            and np.array_equal(a.ranges, b.ranges_m, equal_nan=True)
            and np.array_equal(a.intensities, b.quality.astype(np.float32))
            and np.array_equal(a.angles, INFO.angles[b.first_index:b.first_index + b.ranges_m.size]))


def mutate(rng: random.Random, frame: bytes) -> bytes:
    b = bytearray(frame)
    kind = rng.choice(["flip", "drop", "insert", "truncate", "zeros", "oversize", "dup_delim"])
    i = rng.randrange(len(b))
    if kind == "flip":
        b[i] ^= 1 << rng.randrange(8)
    elif kind == "drop":
        del b[i]
    elif kind == "insert":
        b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 6)))
    elif kind == "truncate":
        b = b[:i]
    elif kind == "zeros":
        b[i:i + rng.randrange(1, 8)] = bytes(rng.randrange(1, 8))
    elif kind == "oversize":
        b[i:i] = bytes(rng.randrange(1, 256) for _ in range(9000))
    else:
        b[i:i] = b"\x00"
    return bytes(b)


def run(stream: bytes, rng: random.Random) -> list:
    rx = Receiver(921600)
    rx.set_info(INFO)  # as LaserPi does with the INFO it asked for (the stream's own INFO changes nothing)
    out, pos = [], 0
    while pos < len(stream):
        step = rng.choice([1, 3, 64, 500, 5000])
        out += [x for x in rx.feed(stream[pos:pos + step], 0.0) if isinstance(x, host_sdk.Scan)]
        pos += step
    return out, rx


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 12), p_bad=st.floats(0, 1))
def test_per_frame_damage(seed, n, p_bad):
    rng = random.Random(seed)
    scans = [make_scan(rng, seq) for seq in range(n)]
    stream = bytearray(b"\x00" + encode_frame(INFO.TYPE, 0, INFO.encode()))
    intact = set()
    for s in scans:
        frame = encode_frame(s.TYPE, s.scan_seq + 1, s.encode())
        if rng.random() < p_bad:
            frame = mutate(rng, frame)
        elif stream[-1] == 0:  # unchanged and after a delimiter: must come out
            intact.add(s.scan_seq)
        stream += frame
        if rng.random() < 0.2:  # junk between frames, which may swallow the next delimiter
            stream += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 20)))
    out, rx = run(bytes(stream), rng)
    by_seq = {s.scan_seq: s for s in scans}
    for scan in out:
        assert same(scan, by_seq[scan.seq]), "yielded a scan that was not sent like this"
    got = {s.seq for s in out}
    assert intact <= got, "an intact frame was not yielded"
    assert rx.stats.frames_ok >= 1 + len(intact)


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), flips=st.integers(0, 40))
def test_random_bit_flips_anywhere(seed, flips):
    rng = random.Random(seed)
    scans = [make_scan(rng, seq) for seq in range(10)]
    frames = [b"\x00" + encode_frame(INFO.TYPE, 0, INFO.encode())]
    frames += [encode_frame(s.TYPE, s.scan_seq + 1, s.encode()) for s in scans]
    stream = bytearray(b"".join(frames))
    hit = {rng.randrange(1, len(stream)) for _ in range(flips)}
    for i in hit:
        stream[i] ^= 1 << rng.randrange(8)
    out, rx = run(bytes(stream), rng)
    by_seq = {s.scan_seq: s for s in scans}
    for scan in out:
        assert same(scan, by_seq[scan.seq])
    # a scan frame is intact if neither its bytes nor the delimiter before it were hit
    starts = np.cumsum([0] + [len(f) for f in frames])
    info_ok = not any(starts[0] <= i < starts[1] for i in hit)
    expected = set()
    if info_ok:
        for k, s in enumerate(scans, start=1):
            lo, hi = starts[k] - 1, starts[k + 1]
            if not any(lo <= i < hi for i in hit):
                expected.add(s.scan_seq)
    assert expected <= {s.seq for s in out}
    assert rx.stats.frames_ok >= len(expected)


@given(st.binary(max_size=3000))
@settings(max_examples=300, deadline=None)
def test_arbitrary_bytes_never_raise(data):
    rx = Receiver(921600)
    rx.set_info(INFO)
    rx.feed(encode_frame(INFO.TYPE, 0, INFO.encode()), 0.0)
    for cut in (0, len(data) // 3, len(data)):
        rx.feed(data[:cut], 0.0)
        rx.feed(data[cut:], 0.0)
    assert rx.stats.frames_ok >= 0  # reaching here is the point: no exception


def test_scans_survive_a_noisy_line_end_to_end():
    """LaserPi.scans() over sim:// with a bit error rate: it keeps going, counts the damage and
    every scan it yields is exactly the (noise-free) wall."""
    with host_sdk.LaserPi("sim://wall?distance=1.0&points=200&noise=0&rate=30&ber=3e-5&seed=2",
                          timeout_s=2.0) as s:
        it = s.scans()
        scans = [next(it) for _ in range(25)]
        stats = s.stats
    assert stats.crc_errors + stats.decode_errors > 0 and stats.scans_missing > 0
    truth = wall_ranges(scans[0].angles, 1.0)
    truth = np.where(truth > 3.0, np.inf, truth)
    for scan in scans:
        np.testing.assert_allclose(scan.ranges, truth, atol=m.RANGE_UNIT_M)
