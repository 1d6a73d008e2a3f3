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
        assert (got.ray_times_us is None) == (expected.ray_times_us is None)
        if got.ray_times_us is not None:
            assert np.array_equal(got.ray_times_us, expected.ray_times_us, equal_nan=True)
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
        "SYNC_DEGRADED": 6, "SATURATED": 7}


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


# --- protocol minor 4: ray times -------------------------------------------------------------
def test_scan_minor4_time_block_byte_layout_by_hand():
    """SPEC.md's SCAN table: after the boot id, u16 count, i32 base (µs from device_time_us), u16 µs per ray."""
    payload = _payload("scan_minor4")
    block = 24 + 3 * 3 + 4
    assert len(payload) == block + 6 + 2 * 3
    assert payload[block:block + 2] == (3).to_bytes(2, "little")
    assert payload[block + 2:block + 6] == (-300).to_bytes(4, "little", signed=True)  # the earliest ray
    offsets = [int.from_bytes(payload[block + 6 + 2 * i:block + 8 + 2 * i], "little") for i in range(3)]
    assert offsets == [1800, m.RAY_TIME_NONE, 0]
    # a receiver of minor 2 or 3 reads the same scan and ignores the block
    assert payload[:block] == m.ScanMessage(9, 2**40 + 9, -12500, 61000, 2, np.array([0.5, math.nan, 1.0]),
                                            np.array([200, 0, 90], np.uint8), boot_id=0xCAFEF00D).encode()


def test_settings_ray_times_is_mask_bit_7_with_its_value_after_the_request_id():
    payload = _payload("set_config_minor4")
    assert int.from_bytes(payload[:2], "little") == 1 << 7  # a device of minor < 4 refuses the unknown bit
    assert len(payload) == m.SETTINGS_SIZE + 2 + 1 and payload[-1] == 1
    assert payload[m.SETTINGS_SIZE:m.SETTINGS_SIZE + 2] == (0x1239).to_bytes(2, "little")
    # without a request id the id's place is still taken (0), so the value stays where it is read
    off = m.SetConfig(m.ScanSettings(ray_times=False)).encode()
    assert off[m.SETTINGS_SIZE:] == bytes([0, 0, 0])
    assert m.SetConfig.decode(off) == m.SetConfig(m.ScanSettings(ray_times=False))
    # INFO: the value after the fields of minor 2; needs them
    info = VECTORS["info_minor4"][1]
    assert _payload("info_minor4")[-1] == 1
    with pytest.raises(ValueError, match="minor 2"):
        dataclasses.replace(info, **{n: None for n in m.Info.MINOR2_FIELDS}).encode()


@pytest.mark.parametrize("payload, what", [
    (_payload("set_config_minor4")[:-1], "ray_times"),  # the mask says it is there, the value is not
    (_payload("set_config_minor4")[:-1] + b"\x02", "neither 0"),
    (_payload("info_minor4")[:-1], "ray_times"),
])
def test_settings_ray_times_missing_or_not_a_bool_is_refused(payload, what):
    with pytest.raises(m.MessageError, match=what):
        (m.Info if len(payload) > 40 else m.SetConfig).decode(payload)


def _scan_minor4(**change) -> bytes:
    """scan_minor4's payload with the time block's count, base or offsets changed."""
    payload = bytearray(_payload("scan_minor4"))
    block = 24 + 3 * 3 + 4
    if "count" in change:
        payload[block:block + 2] = change["count"].to_bytes(2, "little")
    if "base" in change:
        payload[block + 2:block + 6] = change["base"].to_bytes(4, "little", signed=True)
    if "device_time_us" in change:  # SCAN's head: seq u32, then device_time_us u64
        payload[4:12] = change["device_time_us"].to_bytes(8, "little")
    for i, v in change.get("offsets", {}).items():
        payload[block + 6 + 2 * i:block + 8 + 2 * i] = v.to_bytes(2, "little")
    return bytes(payload[:len(payload) - change.get("cut", 0)])


@pytest.mark.parametrize("payload, reason, what", [
    (_scan_minor4(count=2), "value", "2 times for 3 rays"),  # the wrong length
    (_scan_minor4(count=4), "value", "4 times for 3 rays"),
    (_scan_minor4(cut=1), "short", "ray time block of 3 rays"),
    (_scan_minor4(cut=8), "short", "ray time block"),  # inside the block's head
    (_scan_minor4(offsets={1: m.RAY_TIME_SPAN_MAX_US + 1}), "value", "ray 1's time 65001 µs .* outside one frame"),
    (_scan_minor4(offsets={0: 0xFFFE}), "value", "ray 0's time 65534 µs"),
    (_scan_minor4(device_time_us=1000, base=-5000), "value", "base_us -5000 puts its rays before device time 0"),
])
def test_a_scan_whose_time_block_lies_is_refused_naming_what_is_wrong(payload, reason, what):
    with pytest.raises(m.MessageError, match=what) as exc:
        m.decode_message(m.MsgType.SCAN, payload)
    assert exc.value.reason == reason


def test_an_empty_time_block_is_no_times_and_later_minors_append_after_the_block():
    got = m.ScanMessage.decode(_scan_minor4(count=0, cut=6))
    assert got.ray_times_us is None
    newer = m.ScanMessage.decode(_payload("scan_minor4") + b"future")
    assert np.array_equal(newer.ray_times_us, VECTORS["scan_minor4"][1].ray_times_us, equal_nan=True)


def test_ray_times_roundtrip_to_the_microsecond_and_unencodable_ones_are_refused():
    t0 = 10**12 + 123
    times = t0 + np.array([1500.4, np.nan, -299.6, 40_000.0])
    msg = m.ScanMessage(1, t0, 1000, 0, 0, np.ones(4), np.ones(4, np.uint8), 7, times)
    back = m.ScanMessage.decode(msg.encode()).ray_times_us
    assert np.isnan(back[1]) and np.abs(back[[0, 2, 3]] - times[[0, 2, 3]]).max() <= 0.5
    all_none = m.ScanMessage.decode(dataclasses.replace(msg, ray_times_us=np.full(4, np.nan)).encode())
    assert np.isnan(all_none.ray_times_us).all()
    with pytest.raises(ValueError, match="span 65001 µs"):
        dataclasses.replace(msg, ray_times_us=t0 + np.array([0.0, 65_001.0, 1.0, 2.0])).encode()
    with pytest.raises(ValueError, match="boot id"):
        dataclasses.replace(msg, boot_id=None).encode()
    with pytest.raises(ValueError, match="4 finite times"):
        dataclasses.replace(msg, ray_times_us=times[:3]).encode()
    with pytest.raises(ValueError, match="i32"):
        dataclasses.replace(msg, ray_times_us=times + 2.0**32).encode()


def test_the_link_budget_counts_the_ray_times_and_says_so():
    """1640 points with ray times on a 921600-baud UART: 10 scans/s fit, 15 and 20 do not (SPEC.md 5)."""
    assert m.scan_wire_bytes(1640, ray_times=True) == m.scan_wire_bytes(1640) + 6 + 2 * 1640 + 13  # + COBS
    assert m.link_budget_refusal(1640, 10.0, 921600, ray_times=True) is None
    assert m.link_budget_refusal(1640, 15.0, 921600) is None
    at15 = m.link_budget_refusal(1640, 15.0, 921600, ray_times=True)
    assert "with ray times (ray_times)" in at15 and "ray_times off" in at15
    at20 = m.link_budget_refusal(1640, 20.0, 921600, ray_times=True)
    assert "with ray times" in at20 and "ray_times off" not in at20  # off does not fit at 20/s either
    points = int(at15.split("use at most ")[1].split()[0])
    assert m.scan_wire_bytes(points, True) * 15 * 10 <= 921600 < m.scan_wire_bytes(points + 1, True) * 15 * 10
    msg = m.ScanMessage(0, 0, 0, 0, 0, np.full(1640, 2.0), np.zeros(1640, np.uint8), 1, np.zeros(1640))
    assert len(msg.encode()) == 24 + 5 * 1640 + 4 + 6 == 8234  # above 8192: host frames may be longer from minor 4
    assert len(encode_frame(msg.TYPE, 0, msg.encode())) <= m.scan_wire_bytes(1640, ray_times=True)


@settings(max_examples=100, deadline=None)
@given(fields=st.fixed_dictionaries({}, optional={"scan_rate_hz": st.floats(0.5, 60, width=32),
                                                  "ray_times": st.booleans()}),
       request_id=st.integers(0, 65535))
def test_set_config_with_ray_times_roundtrip_property(fields, request_id):
    msg = m.SetConfig(m.ScanSettings(**fields), request_id)
    assert m.SetConfig.decode(msg.encode()) == msg
