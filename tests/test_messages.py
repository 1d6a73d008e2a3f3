"""Message codecs: golden vectors (both directions), REP 117 codes, refusal of bad payloads."""

import dataclasses
import math
import struct
from pathlib import Path

import numpy as np
import pytest

from protocol import messages as m
from protocol.framing import decode_frame, encode_frame
from protocol.vectors.generate import VECTORS, wire

VECTOR_DIR = Path(m.__file__).parent / "vectors"


def _fields(msg):
    """Comparable view of a message: arrays as lists with NaN made comparable."""
    out = {}
    for name in msg.__dataclass_fields__:
        v = getattr(msg, name)
        if isinstance(v, np.ndarray):
            v = [("nan" if math.isnan(x) else x) for x in v.astype(np.float64).tolist()]
        out[name] = v
    return out


@pytest.mark.parametrize("name", sorted(VECTORS))
def test_encoder_reproduces_golden_vector(name):
    assert wire(name) == (VECTOR_DIR / f"{name}.bin").read_bytes()


@pytest.mark.parametrize("name", sorted(VECTORS))
def test_decoder_reads_golden_vector(name):
    data = (VECTOR_DIR / f"{name}.bin").read_bytes()
    assert data.endswith(b"\x00") and data.count(0) == 1
    frame = decode_frame(data[:-1])
    seq, expected = VECTORS[name]
    assert (frame.msg_type, frame.seq) == (expected.TYPE, seq)
    got = m.decode_message(frame.msg_type, frame.payload)
    if name.startswith("scan"):
        # the decoder returns what the quantiser made of the ranges
        assert got.ranges_m.dtype == np.float32
        exp = expected.ranges_m
        assert np.array_equal(np.isnan(got.ranges_m), np.isnan(exp))
        fin = np.isfinite(exp)
        assert np.array_equal(got.ranges_m[~fin & ~np.isnan(exp)], exp[~fin & ~np.isnan(exp)])
        assert np.abs(got.ranges_m[fin] - exp[fin]).max() <= m.RANGE_UNIT_M / 2 + 1e-6 * exp[fin].max()
        assert np.array_equal(got.quality, expected.quality)
        for f in ("scan_seq", "device_time_us", "ray_interval_ns", "age_us", "first_index", "boot_id"):
            assert getattr(got, f) == getattr(expected, f)
    else:
        assert _fields(got) == _fields(expected)


def test_scan_vector_byte_layout_by_hand():
    """SPEC.md's table, checked byte by byte: 24-byte header, u16 codes, then u8 qualities."""
    payload = decode_frame((VECTOR_DIR / "scan.bin").read_bytes()[:-1]).payload
    assert len(payload) == m.SCAN_HEADER_SIZE + 3 * 8
    assert payload[:4] == (4000000000).to_bytes(4, "little")
    assert payload[4:12] == (2**40 + 5).to_bytes(8, "little")
    assert payload[20:22] == (2).to_bytes(2, "little") and payload[22:24] == (8).to_bytes(2, "little")
    codes = [int.from_bytes(payload[24 + 2 * i: 26 + 2 * i], "little") for i in range(8)]
    assert codes == [0, 2000, 5000, 0xFFFC, 0xFFFF, 0xFFFE, 0xFFFD, 8001]
    assert list(payload[40:]) == [0, 1, 128, 255, 0, 0, 0, 77]


def test_range_codes_roundtrip_and_reserved():
    r = np.array([0.0, 0.1234, 3.0, 16.383, np.nan, np.inf, -np.inf])
    back = m.decode_ranges(m.encode_ranges(r))
    assert np.isnan(back[4]) and back[5] == np.inf and back[6] == -np.inf
    assert np.allclose(back[:4], r[:4], atol=m.RANGE_UNIT_M / 2 + 1e-6)


@pytest.mark.parametrize("bad", [-0.001, 16.4, 100.0])
def test_unencodable_range_is_refused_not_clipped(bad):
    with pytest.raises(ValueError, match="outside"):
        m.encode_ranges(np.array([1.0, bad]))


def test_scan_quality_must_match_ranges():
    with pytest.raises(ValueError, match="quality"):
        m.ScanMessage(0, 0, 0, 0, 0, np.ones(4), np.ones(3, np.uint8)).encode()


@pytest.mark.parametrize("interval", [2**31, -2**31 - 1])
def test_a_ray_interval_beyond_the_i32_field_is_refused(interval):
    with pytest.raises(ValueError, match="ray_interval_ns .* i32"):
        m.ScanMessage(0, 0, interval, 0, 0, np.ones(4), np.ones(4, np.uint8)).encode()


@pytest.mark.parametrize("msg_type, payload, reason", [
    (m.MsgType.SCAN, bytes(10), "short"),
    (m.MsgType.SCAN, bytes(20) + (5).to_bytes(2, "little") + (100).to_bytes(2, "little") + bytes(30), "short"),
    (m.MsgType.INFO, bytes(3), "short"),
    (m.MsgType.HEALTH, bytes([9]) + bytes(25), "value"),
    (m.MsgType.NACK, bytes([7, 0, 0, 99, 0]), "value"),
    (m.MsgType.SET_CONFIG, (0xFFFF).to_bytes(2, "little") + bytes(18), "value"),
    (m.MsgType.LOG, bytes(9) + b"\x02\xff\xfe", "utf8"),
    (0x3E, b"", "type"),
])
def test_malformed_payload_names_the_problem(msg_type, payload, reason):
    with pytest.raises(m.MessageError) as exc:
        m.decode_message(msg_type, payload)
    assert exc.value.reason == reason


def test_info_with_nan_angle_is_refused():
    _, info = VECTORS["info"]
    angles = info.angles.copy()
    angles[3] = np.nan
    bad = m.Info(1, 0, "x", "y", 10.0, 0.1, 3.0, angles, info.settings, 5.0)
    with pytest.raises(m.MessageError, match="angles"):
        m.Info.decode(bad.encode())


def test_trailing_bytes_from_a_newer_minor_revision_are_ignored():
    _, health = VECTORS["health_minor2"]  # the newest revision; a later one appends after it
    assert m.Health.decode(health.encode() + b"future") == health


def _payload(name: str) -> bytes:
    return decode_frame((VECTOR_DIR / f"{name}.bin").read_bytes()[:-1]).payload


def _decode_health_minor0(payload: bytes) -> tuple:
    """HEALTH as a receiver of protocol minor 0 reads it (SPEC.md, HEALTH up to errors[e]):
    the fields it knows, every byte after them ignored."""
    head = struct.Struct("<BBBxIIIQH")
    *fields, n = head.unpack_from(payload)
    return (*fields, struct.unpack_from(f"<{n}H", payload, head.size))


def test_health_of_minor_1_reads_the_same_in_a_minor_0_receiver():
    """New device, old host: the counters are appended, the minor-0 fields and their bytes unchanged."""
    new, old = _payload("health"), _payload("health_minor0")
    assert new.startswith(old) and len(new) == len(old) + 4 * len(m.Health.MINOR1_FIELDS)
    assert _decode_health_minor0(new) == _decode_health_minor0(old)
    assert _decode_health_minor0(new) == (1, 1, 0, 7, 2, 1000, 123456789, (2,))


def test_health_of_minor_0_reads_in_a_minor_1_receiver_with_counters_absent():
    """Old device, new host: the shorter payload decodes, every minor-1 counter is None."""
    got = m.Health.decode(_payload("health_minor0"))
    assert all(getattr(got, f) is None for f in m.Health.MINOR1_FIELDS)
    assert got == VECTORS["health_minor0"][1]
    new = m.Health.decode(_payload("health"))
    assert [getattr(new, f) for f in m.Health.MINOR1_FIELDS] == [1, 2, 3, 4, 70000, 5, 6]


def test_health_counters_cut_short_are_refused_and_must_be_all_or_none():
    new = _payload("health")
    with pytest.raises(m.MessageError) as exc:
        m.Health.decode(new[:-1])
    assert exc.value.reason == "short" and "minor 1" in str(exc.value)
    _, health = VECTORS["health"]
    with pytest.raises(ValueError, match="comcu_lost"):
        dataclasses.replace(health, comcu_lost=None).encode()
    wrapped = m.Health.decode(dataclasses.replace(health, host_bytes_discarded=2**32 + 9).encode())
    assert wrapped.host_bytes_discarded == 9  # u32 counters wrap, like the minor-0 ones


def test_error_codes_of_the_device_process_are_in_the_protocol():
    assert {e.name: e.value for e in m.ErrorCode} == {
        "SOURCE_FAILED": 1, "SYNC_LOST": 2, "LASER_FAULT": 3, "CAMERA_FAULT": 4, "PIPELINE_FAULT": 5,
        "SYNC_DEGRADED": 6}


def test_settings_merge_keeps_unset_fields():
    base = VECTORS["info"][1].settings
    new = base.merged(m.ScanSettings(laser_power_mw=1.0))
    assert new.laser_power_mw == 1.0 and new.scan_rate_hz == base.scan_rate_hz
    assert m.SetConfig.decode(m.SetConfig(m.ScanSettings(exposure_us=5)).encode()).settings.as_dict() == {"exposure_us": 5}


def test_frame_of_full_scan_fits_max_payload():
    n = 1664
    msg = m.ScanMessage(1, 0, 0, 0, 0, np.full(n, 2.0), np.zeros(n, np.uint8))
    assert len(encode_frame(msg.TYPE, 0, msg.encode())) < 8192 + 64


from hypothesis import given, settings, strategies as st  # noqa: E402

_range = st.one_of(st.floats(0, m.RANGE_MAX_ENCODABLE_M), st.sampled_from([math.nan, math.inf, -math.inf]))


@settings(max_examples=200, deadline=None)
@given(seq=st.integers(0, 2**32 - 1), t=st.integers(0, 2**64 - 1), dt=st.integers(-2**31, 2**31 - 1),  # i32: minor 3
       age=st.integers(0, 2**32 - 1), first=st.integers(0, 2**16 - 1),
       points=st.lists(st.tuples(_range, st.integers(0, 255)), min_size=0, max_size=300))
def test_scan_roundtrip_property(seq, t, dt, age, first, points):
    r = np.array([p[0] for p in points], dtype=np.float64)
    q = np.array([p[1] for p in points], dtype=np.uint8)
    back = m.ScanMessage.decode(m.ScanMessage(seq, t, dt, age, first, r, q).encode())
    assert (back.scan_seq, back.device_time_us, back.ray_interval_ns, back.age_us, back.first_index) == (
        seq, t, dt, age, first)
    assert np.array_equal(np.isnan(back.ranges_m), np.isnan(r))
    inf = np.isinf(r)
    assert np.array_equal(back.ranges_m[inf], r[inf])
    fin = np.isfinite(r)
    assert np.all(np.abs(back.ranges_m[fin] - r[fin]) <= m.RANGE_UNIT_M / 2 + 4e-7 * np.maximum(r[fin], 1))
    assert np.array_equal(back.quality, q)


@settings(max_examples=200, deadline=None)
@given(st.fixed_dictionaries({}, optional={
    "scan_rate_hz": st.floats(0.5, 60, width=32), "exposure_us": st.integers(0, 2**32 - 1),
    "roi_first": st.integers(0, 65535), "roi_count": st.integers(0, 65535), "median_window": st.integers(0, 255),
    "min_quality": st.integers(0, 255), "laser_power_mw": st.floats(0, 100, width=32)}))
def test_settings_roundtrip_property(fields):
    s = m.ScanSettings(**fields)
    assert m.ScanSettings.decode(s.encode()) == s


def test_long_reasons_are_clipped_at_a_character_boundary():
    nack = m.Nack(m.MsgType.SET_CONFIG, 1, m.NackCode.OUT_OF_RANGE, "é" * 200)  # 400 bytes of UTF-8
    back = m.Nack.decode(nack.encode())
    assert back.reason == "é" * 127
    with pytest.raises(ValueError, match="at most 255"):
        m.Info(1, 0, "v" * 300, "s", 10.0, 0.1, 3.0, np.zeros(2, np.float32), VECTORS["info"][1].settings, 1.0).encode()
