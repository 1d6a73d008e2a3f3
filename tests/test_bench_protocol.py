"""`laserpi bench protocol` runs and reports the budget it is meant to (no timing is asserted)."""

import json

from device.cli import main
from protocol import messages as m


def test_bench_protocol_json(capsys):
    assert main(["bench", "protocol", "--json", "--seconds", "0.03"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert set(res["variants"]) == {"receiver", "frames+msg", "msg only", "ranges: lut", "ranges: math", "encode"}
    assert all(v["points_per_s"] > 0 for v in res["variants"].values())
    assert res["wire_bytes_per_scan"] == m.scan_wire_bytes(1640)
    assert res["range_quantisation_error_max_m"] <= m.RANGE_UNIT_M / 2 + 1e-7


def test_full_rate_fits_921600_baud_with_30_percent_headroom():
    """The issue's budget: 10 Hz x 1640 points at 921600 baud (8N1) with >= 30 % headroom."""
    per_point_payload = m.BYTES_PER_POINT
    assert per_point_payload <= 3
    utilisation = 10 * m.scan_wire_bytes(1640) * m.UART_BITS_PER_BYTE / 921600
    assert utilisation <= 0.70
