"""SyncedLaser tells a co-MCU reset from a lost co-MCU, against a fake co-MCU (the real firmware
runs in tests/test_serve_sim.py): HEALTH.comcu_resets depends on it."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from device.camera.frame import Frame
from device.camera.modes import MODE5
from device.laser.base import LaserError
from device.laser.comcu import CoMcuTimeout, PingResult
from device.laser.synced import UNANSWERED_HEARTBEATS, LockedComcu, SyncedLaser
from device.sync.control import SyncConfig
from protocol import mcu


class FakeComcu:
    """Answers pings with its clock (ticks since its boot); ``answering`` False = every request times out."""

    def __init__(self):
        self.ticks = 1_000_000
        self.ticks_per_second = 2_000_000  # the 16 MHz firmware's
        self.boot_infos: list[mcu.Info] = []
        self.answering = True
        self.heartbeat_state = None  # as CoMcu: from the heartbeats' ACKs
        self.heartbeats_sent = self.heartbeat_acks = 0

    def _request(self) -> None:
        if not self.answering:
            raise CoMcuTimeout("co-MCU did not answer before the port timeout")

    def reboot(self, announced: bool) -> None:
        """Restart its clock; its boot announcement arrives, or is garbled on the line."""
        self.ticks = 500
        if announced:
            self.boot_infos.append(mcu.Info(1, 0x01, 100, 20000, 100000, 2_000_000, 1000))

    def ping(self) -> PingResult:
        self._request()
        self.ticks += 1000
        return PingResult(self.ticks, 0, 1000, self.ticks - 10)

    def stop(self) -> int:
        self._request()
        return 0

    def info(self) -> mcu.Info:
        self._request()
        return mcu.Info(2, 0x01, 50, 17_400, 200_000, self.ticks_per_second, 90_000)

    def edges(self) -> list:
        return []

    def send_heartbeat(self) -> None:
        self.heartbeats_sent += 1
        if self.answering:
            self.heartbeat_acks += 1


@pytest.fixture
def laser_and_mcu():
    fake = FakeComcu()
    now = {"ns": 0}

    def clock_ns() -> int:
        now["ns"] += 100_000_000  # every call 0.1 s later: frame_lit always pings
        return now["ns"]

    laser = SyncedLaser(lambda: fake, SyncConfig(0, 10, 0.05), heartbeat_s=None, clock_ns=clock_ns)
    return laser, fake


FRAME = Frame(np.zeros((2, 2), np.uint8), 0, 0, 1000.0, 50_000.0, MODE5.mode.line_time_ns)


def frame_lit_error(laser) -> LaserError:
    """The LaserError that ``frame_lit`` raises (the test fails if it raises none)."""
    with pytest.raises(LaserError) as exc:
        laser.frame_lit(FRAME)
    return exc.value


def test_the_sync_runs_on_the_tick_rate_the_comcu_reports(laser_and_mcu):
    """The 8 MHz firmware counts 1 MHz ticks and says so in INFO: the controller converts with
    that rate, not SyncConfig's default (the 16 MHz firmware's 2 MHz)."""
    laser, fake = laser_and_mcu
    laser.start(FRAME)
    assert laser.controller.cfg.tick_hz == 2_000_000
    laser.stop()
    fake.ticks_per_second = 1_000_000  # reflashed with the 8 MHz build
    laser.start(FRAME)
    assert laser.controller.cfg.tick_hz == 1_000_000 and laser.sync.tick_hz == 2e6


def test_a_fresh_link_is_no_reset_even_when_the_mcu_announces_its_boot(laser_and_mcu):
    laser, fake = laser_and_mcu
    fake.reboot(announced=True)  # its power-on announcement
    assert laser.start(FRAME) is False
    laser.stop()
    assert laser.start(FRAME) is False


def test_a_request_unanswered_after_a_boot_announcement_is_a_reset_not_a_loss(laser_and_mcu):
    laser, fake = laser_and_mcu
    laser.start(FRAME)
    fake.reboot(announced=True)
    fake.answering = False  # the request reached it while it restarted
    err = frame_lit_error(laser)
    assert err.reason == "reset" and "announced a new boot" in str(err)
    fake.answering = True
    assert laser.start(FRAME) is False  # reported once, not again on the re-sync


def test_a_reboot_whose_announcement_was_garbled_is_found_by_its_clock_on_restart(laser_and_mcu):
    laser, fake = laser_and_mcu
    laser.start(FRAME)
    fake.answering = False
    err = frame_lit_error(laser)
    assert err.reason == "lost"
    fake.reboot(announced=False)
    fake.answering = True
    assert laser.start(FRAME) is True  # its clock went back: it rebooted during the outage
    laser.stop()
    assert laser.start(FRAME) is False


def test_a_clock_gone_back_while_answering_is_a_reset(laser_and_mcu):
    laser, fake = laser_and_mcu
    laser.start(FRAME)
    fake.reboot(announced=False)
    err = frame_lit_error(laser)
    assert err.reason == "reset" and "clock went back" in str(err)
    assert laser.start(FRAME) is False


def test_an_outage_without_a_reboot_is_only_a_loss(laser_and_mcu):
    laser, fake = laser_and_mcu
    laser.start(FRAME)
    fake.answering = False
    err = frame_lit_error(laser)
    assert err.reason == "lost"
    fake.answering = True
    assert laser.start(FRAME) is False


def test_a_fault_in_a_heartbeat_ack_is_raised_by_the_frame_loop(laser_and_mcu):
    laser, fake = laser_and_mcu
    laser.start(FRAME)
    laser.heartbeat()
    assert fake.heartbeats_sent == 1
    fake.heartbeat_state = (mcu.McuState.FAULT, mcu.Fault.HEARTBEAT)
    err = frame_lit_error(laser)
    assert err.reason == "fault" and "HEARTBEAT" in str(err)


def test_heartbeats_nobody_answers_are_a_lost_link(laser_and_mcu):
    laser, fake = laser_and_mcu
    laser.start(FRAME)
    for _ in range(5):
        fake.send_heartbeat()
    laser.frame_lit(FRAME)  # answered so far
    fake.answering = False
    fake.ping = lambda: PingResult(fake.ticks, 0, 1000, fake.ticks - 10)  # only the heartbeats go unanswered
    for _ in range(UNANSWERED_HEARTBEATS):
        fake.send_heartbeat()
    laser.frame_lit(FRAME)
    fake.send_heartbeat()
    err = frame_lit_error(laser)
    assert err.reason == "lost" and f"none of the last {UNANSWERED_HEARTBEATS + 1} heartbeats" in str(err)


def test_pings_are_rarer_while_the_clock_map_runs_on_the_gpio_edges(laser_and_mcu):
    laser, fake = laser_and_mcu
    laser.start(FRAME)
    pings, ping = [], fake.ping
    fake.ping = lambda: pings.append(1) or ping()
    for _ in range(10):
        laser.frame_lit(FRAME)  # (the fake clock moves 0.1 s per reading: more than ping_interval_s)
    on_pings = len(pings)
    laser.controller.clock = lambda: SimpleNamespace(source="gpio")
    laser.ping_interval_gpio_s = 2.0  # (the fake clock reads ~0.4 s later per frame)
    for _ in range(10):
        laser.frame_lit(FRAME)
    assert on_pings == 10 and len(pings) - on_pings < 5


def test_a_co_mcu_whose_envelope_is_not_class_1_for_this_laser_lights_nothing():
    fake = FakeComcu()
    seen = []

    def refusal(info):
        seen.append(info)
        return "the co-MCU's envelope keeps a laser Class 1 only up to 25.6 mW"

    laser = SyncedLaser(lambda: fake, SyncConfig(0, 10, 0.05), heartbeat_s=None, envelope_refusal=refusal)
    with pytest.raises(LaserError) as exc:
        laser.start(FRAME)
    assert exc.value.reason == "refused" and "25.6 mW" in str(exc.value)
    assert seen == [fake.info()] and laser.controller is None and not laser.locked


def test_the_heartbeat_thread_beats_while_frames_are_serviced_and_is_gone_before_the_stop():
    """The Pi's heartbeat thread (heartbeat_s set; in simulation the simulated clock's ticker
    beats instead): it writes heartbeats while the frame loop services frames, none once the
    frame loop has been silent for watchdog_s (so a hung frame loop lets the firmware switch the
    laser off), and ``stop`` ends it before the STOP goes out: no heartbeat after the STOP."""
    fake, written = FakeComcu(), []
    beat, stop = fake.send_heartbeat, fake.stop
    fake.send_heartbeat = lambda: written.append("heartbeat") or beat()
    fake.stop = lambda: written.append("stop") or stop()
    laser = SyncedLaser(lambda: fake, SyncConfig(0, 10, 0.05), heartbeat_s=0.01, watchdog_s=0.1)
    laser.start(FRAME)
    try:
        end = time.monotonic() + 0.3
        while time.monotonic() < end:
            laser.frame_lit(FRAME)
            time.sleep(0.02)
        assert fake.heartbeats_sent >= 10  # ~30 at 10 ms; a loaded machine wakes the thread late, not never
        time.sleep(0.1 + 0.15)  # the watchdog's 0.1 s since the last frame, and a late wake-up
        silent = fake.heartbeats_sent
        time.sleep(0.15)
        assert fake.heartbeats_sent == silent  # the frame loop is silent: so are the heartbeats
        laser.frame_lit(FRAME)  # frames again: heartbeats again
        deadline = time.monotonic() + 2.0
        while fake.heartbeats_sent == silent and time.monotonic() < deadline:
            time.sleep(0.005)
        assert fake.heartbeats_sent > silent
    finally:
        laser.stop()
    assert not any(t.name == "comcu-heartbeat" for t in threading.enumerate())
    assert written[-1] == "stop" and written.count("stop") == 2  # start's STOP of an older schedule, and this one
    time.sleep(0.05)
    assert written[-1] == "stop"


def test_locked_comcu_holds_the_lock_over_each_call_and_sees_the_comcu_as_it_is_now():
    fake = FakeComcu()
    shared = LockedComcu(fake)
    held = []
    fake.send_heartbeat = lambda: held.append(shared.lock.locked())
    shared.send_heartbeat()
    assert shared.send_heartbeat is shared.send_heartbeat  # made once, kept (no closure per call)
    fake.send_heartbeat = lambda: held.append("replaced")  # a method replaced later is the one called
    shared.send_heartbeat()
    assert held == [True, "replaced"] and not shared.lock.locked()
    fake.heartbeats_sent = 7  # a value is read at every access, never kept
    assert shared.heartbeats_sent == 7
    fake.heartbeats_sent = 8
    assert shared.heartbeats_sent == 8
