"""protocol/mcu.py agrees with the firmware's msg.h, and its payloads round-trip."""
import re
from pathlib import Path

import pytest

from protocol import mcu
from protocol.framing import MAX_PAYLOAD_MCU, FrameError, decode_frame, encode_frame

MSG_H = (Path(__file__).resolve().parents[1] / "firmware_pwm" / "src" / "msg.h").read_text()


def _define(name):
    m = re.search(rf"#define {name} (0x[0-9A-Fa-f]+|\d+)", MSG_H)
    assert m, f"{name} not in msg.h"
    return int(m.group(1), 0)


@pytest.mark.parametrize("cls", list(mcu.MESSAGES.values()), ids=lambda c: c.__name__)
def test_numbers_and_sizes_match_the_firmware(cls):
    c_name = re.sub(r"(?<!^)(?=[A-Z])", "_", cls.__name__).upper().replace("STATUS_REQUEST", "STATUS_REQ")
    c_name = c_name.replace("INFO_REQUEST", "INFO_REQ")
    assert _define(f"MSG_{c_name}") == cls.MSG_TYPE
    assert 0x40 <= cls.MSG_TYPE <= 0x7F
    if cls.FORMAT.size:
        assert _define(f"LEN_{c_name}") == cls.FORMAT.size <= MAX_PAYLOAD_MCU


def test_reason_and_flag_codes_match_the_firmware():
    for r in mcu.NackReason:
        assert _define(f"NACK_{r.name}") == r.value
    for f in mcu.Fault:
        assert _define(f"FAULT_{f.name}") == f.value
    for f in mcu.EdgeFlag:
        assert _define(f"EDGE_{f.name}") == f.value
    for s in mcu.McuState:
        assert _define(f"STATE_{s.name}") == s.value


def test_roundtrip_through_the_frame_layer():
    msgs = [mcu.Schedule(2**40 + 5, 66_667, 20_000, 0b01, 2, True), mcu.Trim(-300, 7),
            mcu.Edge(3, 10, 20, mcu.EdgeFlag.CUT), mcu.Nack(0x41, mcu.NackReason.BUSY, 2), mcu.Ping()]
    for i, m in enumerate(msgs):
        wire = mcu.encode_message(m, seq=i)
        assert mcu.decode_message(decode_frame(wire[:-1], max_payload=MAX_PAYLOAD_MCU)) == m


def test_out_of_range_field_is_named():
    with pytest.raises(ValueError, match="Schedule.width_ticks"):
        mcu.Schedule(0, 1000, -1).encode()
    with pytest.raises(ValueError, match="Trim.phase_ticks"):
        mcu.Trim(2**31, 0).encode()


def test_wrong_payload_length_and_unknown_type_are_errors():
    with pytest.raises(FrameError) as e:
        mcu.Pong.decode(b"\x00" * 15)
    assert e.value.reason == "length"
    with pytest.raises(FrameError) as e:
        mcu.decode_message(decode_frame(encode_frame(0x7F, 1, b"")[:-1]))
    assert e.value.reason == "unknown"
