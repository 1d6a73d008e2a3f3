"""Write the golden vectors: one file per message, the complete wire bytes of one frame.

    python -m protocol.vectors.generate        # rewrites protocol/vectors/*.bin

Run it only on purpose (a deliberate, versioned change of the wire format): the tests check
that today's encoder reproduces these bytes and today's decoder reads them back to VECTORS.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from protocol import messages as m
from protocol.framing import encode_frame

HERE = Path(__file__).parent

_SETTINGS = m.ScanSettings(scan_rate_hz=10.0, exposure_us=800, roi_first=0, roi_count=8,
                           median_window=3, min_quality=10, laser_power_mw=4.0)

#: name -> (frame sequence number, message). Values are exact in float32 on purpose.
VECTORS: dict[str, tuple[int, object]] = {
    "get_info": (1, m.GetInfo(1, 0)),
    "info": (2, m.Info(1, 0, "0.1.0", "LP-000042", 10.0, 0.125, 3.0,
                       np.linspace(0.5, -0.5, 8, dtype=np.float32), _SETTINGS, 5.5)),
    "get_health": (3, m.GetHealth()),
    "health": (4, m.Health(m.DeviceState.SCANNING, True, False, 7, 2, 1000, 123456789,
                           (m.ErrorCode.SYNC_LOST,), camera_restarts=1,
                           comcu_resets=2, comcu_lost=3, pipeline_errors=4, host_bytes_discarded=70000,
                           host_frames_rejected=5, host_sessions=6)),
    # the same message from a device of protocol minor 0 (no counters): tests the compatibility rule
    "health_minor0": (4, m.Health(m.DeviceState.SCANNING, True, False, 7, 2, 1000, 123456789,
                                  (m.ErrorCode.SYNC_LOST,))),
    "start": (5, m.Start()),
    "stop": (6, m.Stop()),
    "set_config": (7, m.SetConfig(m.ScanSettings(scan_rate_hz=5.0, laser_power_mw=2.5))),
    "ack": (8, m.Ack(m.MsgType.START, 5)),
    "nack": (9, m.Nack(m.MsgType.SET_CONFIG, 7, m.NackCode.EYE_SAFETY,
                       "laser_power_mw 9 exceeds the Class 1 limit 5.5")),
    "log": (10, m.Log(30, 987654321, "sync lost")),
    # every kind of range: zero, finite, the largest finite code, NaN, +inf, -inf
    "scan": (65535, m.ScanMessage(4000000000, 2**40 + 5, 12500, 61000, 2,
                                  np.array([0.0, 0.5, 1.25, m.RANGE_MAX_ENCODABLE_M, math.nan,
                                            math.inf, -math.inf, 2.00025], dtype=np.float64),
                                  np.array([0, 1, 128, 255, 0, 0, 0, 77], dtype=np.uint8))),
    # protocol minor 2: request ids echoed, boot id, the geometry in chunks, heartbeats
    "get_info_minor2": (11, m.GetInfo(1, 2, request_id=0x1234)),
    "info_minor2": (12, m.Info(1, 2, "0.2.0", "LP-000042", 10.0, 0.125, 3.0, np.zeros(0, np.float32), _SETTINGS, 5.5,
                               request_id=0x1234, boot_id=0xCAFEF00D, n_columns=8,
                               angles_crc=m.angles_crc(np.linspace(0.5, -0.5, 8, dtype=np.float32)),
                               startup_s=5.0, host_timeout_s=5.0)),
    "get_angles": (13, m.GetAngles(4, 256, request_id=0x1235)),
    "angles": (14, m.Angles(0x1235, 0xCAFEF00D, m.angles_crc(np.linspace(0.5, -0.5, 8, dtype=np.float32)), 8, 4,
                            np.linspace(0.5, -0.5, 8, dtype=np.float32)[4:])),
    "heartbeat": (15, m.Heartbeat()),
    "set_config_minor2": (16, m.SetConfig(m.ScanSettings(scan_rate_hz=5.0, laser_power_mw=2.5), request_id=0x1236)),
    "ack_minor2": (17, m.Ack(m.MsgType.SET_CONFIG, 16, request_id=0x1236)),
    "nack_minor2": (18, m.Nack(m.MsgType.SET_CONFIG, 16, m.NackCode.EYE_SAFETY,
                               "laser_power_mw 9 exceeds the Class 1 limit 5.5", request_id=0x1236)),
    "health_minor2": (19, m.Health(m.DeviceState.SCANNING, True, False, 7, 2, 1000, 123456789,
                                   (m.ErrorCode.SYNC_LOST,), camera_restarts=1, comcu_resets=2, comcu_lost=3,
                                   pipeline_errors=4, host_bytes_discarded=70000, host_frames_rejected=5,
                                   host_sessions=6, request_id=0x1237, boot_id=0xCAFEF00D, host_timeouts=1)),
    "scan_minor2": (20, m.ScanMessage(7, 2**40 + 5, 12500, 61000, 2, np.array([0.5, math.inf], dtype=np.float64),
                                      np.array([200, 0], dtype=np.uint8), boot_id=0xCAFEF00D)),
    # protocol minor 3: the ray interval is signed (rays measured latest first)
    "scan_minor3": (21, m.ScanMessage(8, 2**40 + 9, -12500, 61000, 2, np.array([0.5, -math.inf], dtype=np.float64),
                                      np.array([200, 0], dtype=np.uint8), boot_id=0xCAFEF00D)),
    # protocol minor 4: ray times on request (settings bit 7, its value after the message's fields)
    "get_info_minor4": (22, m.GetInfo(1, 4, request_id=0x1238)),
    "set_config_minor4": (23, m.SetConfig(m.ScanSettings(ray_times=True), request_id=0x1239)),
    "info_minor4": (24, m.Info(1, 4, "0.3.0", "LP-000042", 10.0, 0.125, 3.0, np.zeros(0, np.float32),
                               dataclasses.replace(_SETTINGS, ray_times=True), 5.5, request_id=0x1238,
                               boot_id=0xCAFEF00D, n_columns=8,
                               angles_crc=m.angles_crc(np.linspace(0.5, -0.5, 8, dtype=np.float32)),
                               startup_s=5.0, host_timeout_s=5.0)),
    # a ray 1.5 ms after device_time, one without a time (NaN: the line's), one 0.3 ms before it
    "scan_minor4": (25, m.ScanMessage(9, 2**40 + 9, -12500, 61000, 2, np.array([0.5, math.nan, 1.0], dtype=np.float64),
                                      np.array([200, 0, 90], dtype=np.uint8), boot_id=0xCAFEF00D,
                                      ray_times_us=np.array([2**40 + 9 + 1500, math.nan, 2**40 + 9 - 300]))),
}


def wire(name: str) -> bytes:
    seq, msg = VECTORS[name]
    return encode_frame(msg.TYPE, seq, msg.encode())


def main() -> None:
    for name in VECTORS:
        (HERE / f"{name}.bin").write_bytes(wire(name))
        print(f"wrote {name}.bin")


if __name__ == "__main__":
    main()
