"""Health and link counters as diagnostic_msgs/DiagnosticStatus entries, without I/O.

Each entry is ``(name, level, message, values)``: the fields of diagnostic_msgs/msg/DiagnosticStatus
(levels OK=0, WARN=1, ERROR=2, STALE=3, as that message defines them; values are its KeyValue
pairs, strings), so that a ROS node can publish them as they are in a DiagnosticArray
(hardware_id, the serial number, is among the values). Counters are judged by how much they grew
since the previous report: a link that had noise an hour ago is not WARN now.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

from protocol import messages as m

OK, WARN, ERROR, STALE = 0, 1, 2, 3  # diagnostic_msgs/DiagnosticStatus levels

#: Active error codes that mean no valid scans now (ERROR); the others degrade them (WARN).
_ERROR_CODES = {m.ErrorCode.SOURCE_FAILED, m.ErrorCode.LASER_FAULT, m.ErrorCode.CAMERA_FAULT}
#: Link counters whose growth means bytes were damaged or lost on the wire.
_LINK_DAMAGE = ("crc_errors", "decode_errors", "oversize_frames", "frames_missing", "zero_runs")


class DiagnosticStatus(NamedTuple):
    name: str
    level: int
    message: str
    values: dict[str, str]


def _code_name(code: int) -> str:
    return m.ErrorCode(code).name if code in m.ErrorCode._value2member_map_ else str(code)


def device_status(health: m.Health | None, hardware_id: str, failure: str = "") -> DiagnosticStatus:
    """The device's own report (HEALTH); STALE with ``failure`` when it did not answer."""
    if health is None:
        return DiagnosticStatus("LaserPi device", STALE, f"no health report: {failure}", {"hardware_id": hardware_id})
    values = {"hardware_id": hardware_id}
    for name in (f.name for f in dataclasses.fields(health)):  # the instance's fields (its ClassVars are not)
        v = getattr(health, name)
        if v is not None:
            values[name] = ",".join(_code_name(e) for e in v) if name == "errors" else str(getattr(v, "name", v))
    codes = set(health.errors)
    if health.state == m.DeviceState.FAULT or codes & _ERROR_CODES:
        level = ERROR
    elif codes:
        level = WARN
    else:
        level = OK
    errors = ", ".join(_code_name(e) for e in health.errors)
    message = health.state.name.lower() + (f": {errors}" if errors else "") + (", laser on" if health.laser_on else "")
    return DiagnosticStatus("LaserPi device", level, message, values)


def _grown(now: dict, before: dict | None, names) -> dict[str, int]:
    before = before or {}
    return {n: now[n] - before.get(n, 0) for n in names if now[n] - before.get(n, 0) > 0}


def link_status(stats: dict, before: dict | None, hardware_id: str) -> DiagnosticStatus:
    """What the host made of the device's bytes since ``before`` (a Stats.as_dict() snapshot)."""
    values = {"hardware_id": hardware_id, **{k: str(v) for k, v in stats.items()}}
    before = before or {}
    got = stats["bytes_received"] - before.get("bytes_received", 0)
    frames = stats["frames_ok"] - before.get("frames_ok", 0)
    damage = _grown(stats, before, _LINK_DAMAGE)
    if got and not frames:
        return DiagnosticStatus("LaserPi link", ERROR, f"{got} bytes and no intact frame: wrong baud rate or a bad "
                                "cable", values)
    if damage:
        return DiagnosticStatus("LaserPi link", WARN, "since the last report: " + ", ".join(
            f"{n} +{v}" for n, v in damage.items()), values)
    return DiagnosticStatus("LaserPi link", OK, f"{frames} intact frames since the last report", values)


def scan_status(stats: dict, before: dict | None, hardware_id: str, *, streaming: bool, scan_age_s: float | None,
                timeout_s: float) -> DiagnosticStatus:
    """Whether scans come, and what was lost or restarted since ``before``."""
    values = {"hardware_id": hardware_id, "streaming": str(streaming),
              "last_scan_age_s": "none" if scan_age_s is None else f"{scan_age_s:.3f}"}
    values.update({k: str(stats[k]) for k in ("scans", "scans_missing", "scans_dropped", "scans_without_info",
                                              "device_restarts", "stamp_outliers", "reconnects")})
    if not streaming:
        return DiagnosticStatus("LaserPi scans", OK, "not streaming", values)
    if scan_age_s is None or scan_age_s > timeout_s:
        return DiagnosticStatus("LaserPi scans", STALE, "no scan yet" if scan_age_s is None
                                else f"no scan for {scan_age_s:.1f} s", values)
    grown = _grown(stats, before, ("device_restarts", "scans_missing", "scans_dropped", "scans_without_info",
                                   "stamp_outliers"))
    if grown:
        return DiagnosticStatus("LaserPi scans", WARN, "since the last report: " + ", ".join(
            f"{n} +{v}" for n, v in grown.items()), values)
    return DiagnosticStatus("LaserPi scans", OK, f"last scan {scan_age_s * 1e3:.0f} ms ago", values)
