import zlib

import pytest

from protocol.framing import FrameError, decode_frame, encode_frame, MAX_PAYLOAD_MCU


def test_roundtrip_and_no_zero_inside():
    wire = encode_frame(0x21, 70000, b"\x00\x01\x00payload", flags=3)
    assert wire.endswith(b"\x00") and b"\x00" not in wire[:-1]
    f = decode_frame(wire[:-1])
    assert (f.msg_type, f.seq, f.flags, f.payload) == (0x21, 70000 & 0xFFFF, 3, b"\x00\x01\x00payload")


def test_crc_is_zlib_crc32_little_endian():
    from cobs import cobs
    body = cobs.decode(encode_frame(1, 2, b"abc")[:-1])
    assert body[-4:] == zlib.crc32(body[:-4]).to_bytes(4, "little")


@pytest.mark.parametrize("mutate, reason", [
    (lambda w: w[:3] + bytes([w[3] ^ 0x40]) + w[4:], "crc"),
    (lambda w: w[:5], None),
])
def test_corruption_is_rejected(mutate, reason):
    wire = encode_frame(1, 2, b"hello world")[:-1]
    with pytest.raises(FrameError) as exc:
        decode_frame(mutate(wire))
    if reason:
        assert exc.value.reason == reason


def test_oversize_refused_both_ways():
    with pytest.raises(FrameError, match="oversize"):
        encode_frame(1, 0, bytes(MAX_PAYLOAD_MCU + 1), max_payload=MAX_PAYLOAD_MCU)
    wire = encode_frame(1, 0, bytes(100))[:-1]
    with pytest.raises(FrameError, match="oversize"):
        decode_frame(wire, max_payload=MAX_PAYLOAD_MCU)
