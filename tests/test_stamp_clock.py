"""StampClock: host time of the first ray from arrival time, frame length and device age."""

import numpy as np
import pytest

from host_sdk.scan import StampClock


def test_transmission_time_and_age_are_taken_off_and_jitter_filtered():
    rng = np.random.default_rng(1)
    offset = 123.456  # host clock - device clock, s
    clock = StampClock(921600)
    wire_len, errors = 4976, []
    for k in range(60):
        device_t = 10.0 + 0.1 * k
        age = 0.004 + 0.002 * rng.random()  # device processing, measured by the device
        jitter = rng.exponential(0.002)  # host reads only ever come late
        t_read = device_t + offset + age + wire_len * 10 / 921600 + jitter
        stamp = clock.stamp(t_read, 0, wire_len, int(round(age * 1e6)), int(round(device_t * 1e6)))
        errors.append(stamp - (device_t + offset))
    assert abs(errors[0]) < 0.02  # the first estimate carries its own jitter
    assert np.abs(errors[10:]).max() < 0.0005  # the minimum over the window removes it


def test_bytes_after_the_frame_in_the_same_read_are_accounted():
    clock = StampClock(115200)
    stamp = clock.stamp(t_read=1.0, tail_bytes=1152, wire_len=0, age_us=0, device_time_us=0)
    assert stamp == pytest.approx(1.0 - 0.1)  # 1152 bytes at 11520 bytes/s arrived after it


def test_device_reboot_resets_the_offset():
    clock = StampClock(921600)
    clock.stamp(100.0, 0, 0, 0, 50_000_000)  # offset 50 s
    s = clock.stamp(101.0, 0, 0, 0, 1_000_000)  # device clock restarted: offset now 100 s
    assert s == pytest.approx(101.0)


def test_link_rate_must_be_positive():
    with pytest.raises(ValueError, match="positive"):
        StampClock(0)
