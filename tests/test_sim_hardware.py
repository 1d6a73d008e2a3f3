"""The simulated Pi's clock thread (device/sim/hardware.py): which UART frames it counts as
requests and answers, and how often it steps the emulator."""

from __future__ import annotations

import time

import pytest

from device.laser.comcu import HEARTBEAT_SEQ
from device.sim.hardware import SimulatedHardware, answers_a_request, ended_frames
from protocol import mcu
from protocol.framing import MAX_PAYLOAD_MCU, decode_frame


def wire(msg, seq: int) -> bytes:
    return mcu.encode_message(msg, seq)


def test_a_request_is_a_frame_not_a_delimiter():
    """The Pi writes a delimiter before every frame (CoMcu): two zero bytes, one request."""
    partial = bytearray()
    ping = wire(mcu.Ping(), 7)
    assert ended_frames(partial, b"\x00" + ping) == [ping[:-1]]
    assert ended_frames(partial, b"\x00") == [] and partial == b""
    # a frame split across two reads counts once, when its delimiter arrives
    hb = b"\x00" + wire(mcu.Heartbeat(), HEARTBEAT_SEQ)
    assert ended_frames(partial, hb[:5]) == []
    assert ended_frames(partial, hb[5:] + b"\x00" + ping[:3]) == [hb[1:-1]]
    assert ended_frames(partial, ping[3:]) == [ping[:-1]] and partial == b""


def test_edge_reports_and_boot_announcements_answer_no_request():
    info = mcu.Info(1, 1, 50, 17_400, 100_000, 2_000_000, 40_000)
    answers = [wire(mcu.Ack(mcu.Heartbeat.MSG_TYPE, 2), HEARTBEAT_SEQ), wire(mcu.Pong(1, 2), 9),
               wire(info, 3), wire(mcu.Nack(0, 1, 0), 0), b"\x05garbled"]
    unsolicited = [wire(mcu.Edge(4, 100, 200, 0), 0), wire(info, 0)]
    assert all(answers_a_request(f.rstrip(b"\x00")) for f in answers)
    assert not any(answers_a_request(f[:-1]) for f in unsolicited)


@pytest.fixture
def hardware():
    hw = SimulatedHardware(seed=5)
    yield hw
    hw.close()


def counted_steps(hw: SimulatedHardware) -> list[int]:
    """Cycles of every emulator step from now on."""
    steps: list[int] = []
    run = hw.mcu.run_cycles

    def counting(cycles: int) -> None:
        steps.append(cycles)
        run(cycles)

    hw.mcu.run_cycles = counting
    return steps


def test_answered_requests_leave_the_clock_stepping_in_whole_quanta(hardware):
    """Once every request is answered, the clock advances at most one step per ``min_step_s`` of
    simulated time (each step is a round trip to the emulator's process; stepping whenever the
    wall clock moved on was ~30 000 a second), and stops at ``limit_ns``: the answer window is over."""
    comcu = hardware.open_comcu()
    try:
        for _ in range(3):
            comcu.ping()
            comcu.send_heartbeat()
        assert hardware.wait_until(hardware.now_ns() + 10_000_000, 2.0)
        comcu.edges()
        assert comcu.heartbeat_acks == 3
        steps = counted_steps(hardware)
        t0 = hardware.now_ns()
        time.sleep(0.3)
        ran_ns = hardware.now_ns() - t0
        assert ran_ns > 0.1e9
        assert len(steps) <= ran_ns / hardware.min_step_ns + 1, (len(steps), ran_ns)
        # held at a limit: it stops there, not up to the answer window past it
        hardware.limit_ns = hardware.now_ns() + 3_000_000
        assert hardware.wait_until(hardware.limit_ns, 2.0)
        time.sleep(0.1)
        # within what simavr runs at once: a whole instruction (at most 4 cycles: CALL, RET, RETI)
        # plus an interrupt's entry (4 cycles), ATmega328P datasheet, Instruction Set Summary and
        # 'Interrupt Response Time' (it once ran 2 cycles past)
        assert 0 <= hardware.now_ns() - hardware.limit_ns <= 8 * 1e9 / hardware.cpu_hz + 1
        # a request while held is answered (the answer window lets the MCU's time run on)
        assert comcu.ping().mcu_ticks > 0 and hardware.now_ns() > hardware.limit_ns
    finally:
        comcu.port.close()


def test_the_pis_uart_hands_over_the_co_mcus_bytes_as_a_pl011_does(hardware):
    """The co-MCU's replies reach the Pi's reader as its PL011 receiver hands them over: in pieces
    of PL011_RX_TRIGGER_BYTES (its FIFO's interrupt level), the last piece of a reply after the
    line fell silent (PL011_RX_TIMEOUT_BITS); not byte by byte as the emulator sends them."""
    import math
    import os
    import select

    from device.sim.hardware import PL011_RX_TRIGGER_BYTES

    comcu = hardware.open_comcu()
    comcu.ping()  # the boot announcement and whatever came before are read
    fd = comcu.port.fd
    try:
        for seq in range(1, 9):
            os.write(fd, b"\x00" + wire(mcu.Ping(), seq))
            pieces = []
            while not pieces or not pieces[-1].endswith(b"\x00"):
                assert select.select([fd], [], [], 2.0)[0], "no answer"
                pieces.append(os.read(fd, 4096))
            reply = b"".join(pieces)
            assert isinstance(mcu.decode_message(decode_frame(reply.strip(b"\x00"), max_payload=MAX_PAYLOAD_MCU)), mcu.Pong)
            assert len(reply) > PL011_RX_TRIGGER_BYTES
            assert all(len(p) >= PL011_RX_TRIGGER_BYTES for p in pieces[:-1]), [len(p) for p in pieces]
            assert len(pieces) <= math.ceil(len(reply) / PL011_RX_TRIGGER_BYTES), [len(p) for p in pieces]
    finally:
        comcu.port.close()


def test_a_clock_held_back_falls_behind_the_wall_clock_for_good_and_says_how_far(hardware):
    """Held at ``limit_ns`` (the camera's consumer lags), simulated time stops while the wall
    clock goes on; released, it goes on from there at the wall clock's pace instead of racing to
    catch up, and ``lag_s`` (what `bench process` takes off the wall time of a scan rate) is the
    time it lost."""
    assert hardware.wait_until(hardware.now_ns() + 5_000_000, 2.0)
    before = hardware.lag_s
    assert before < 0.05
    held_at = time.monotonic()
    hardware.limit_ns = hardware.now_ns() + 1_000_000
    time.sleep(0.3)
    hardware.limit_ns = None
    t_wall, t_sim = time.monotonic(), hardware.now_ns()
    time.sleep(0.2)
    ran_s = (hardware.now_ns() - t_sim) * 1e-9
    # at the wall clock's pace, no burst (a descheduled clock thread only loses more)
    assert 0.1 < ran_s <= time.monotonic() - t_wall + 0.01
    assert 0.29 - 0.01 < hardware.lag_s - before <= time.monotonic() - held_at


def test_a_waiter_is_woken_when_its_time_has_come_not_at_every_step(hardware):
    """wait_until's callers (the simulated camera waiting for its next frame, the ticker thread
    waiting for its tick) are notified once the clock reaches the time one of them waits for,
    not at each of the ~50 steps before it. Judged notification by notification (a waiter was
    due), not by their number: a waiter the machine's load keeps from running is still due at
    the steps after its time, and is rightly notified again (a count bounded by the ticker's
    ticks failed under load: 7 against 6)."""
    notified: list[tuple[int, bool]] = []
    steps = counted_steps(hardware)
    notify_all = hardware._advanced.notify_all

    def counting() -> None:  # the clock thread, holding the condition's lock that guards _awaited_ns
        now = hardware.now_ns()
        notified.append((now, bool(hardware._awaited_ns) and now >= min(hardware._awaited_ns)))
        notify_all()

    hardware._advanced.notify_all = counting
    target = hardware.now_ns() + 50_000_000
    assert hardware.wait_until(target, 2.0)
    assert hardware.now_ns() >= target
    assert notified and all(due for _, due in notified), notified
    assert max(t for t, _ in notified) >= target
    assert len(steps) > 2 * len(notified), (len(steps), len(notified))  # most steps notify no one


def test_heartbeats_reach_the_firmware_at_their_interval_far_inside_its_timeout(hardware):
    """The simulated heartbeat thread (the tickers) writes every tick_s of simulated time; the
    clock's quanta delay a heartbeat's arrival at the MCU by at most a step, so the firmware
    (timeout: its INFO's heartbeat_timeout_ms, 50 ms) sees them ~15 ms apart, never near 50."""
    comcu = hardware.open_comcu()
    arrived: list[int] = []  # simulated ns at which a heartbeat's bytes entered the MCU's UART
    write = hardware.mcu.write
    heartbeat = mcu.encode_message(mcu.Heartbeat(), HEARTBEAT_SEQ)

    def recording(data: bytes) -> int:
        if heartbeat in bytes(data):
            arrived.append(hardware.now_ns())
        return write(data)

    hardware.mcu.write = recording
    try:
        timeout_ns = comcu.info().heartbeat_timeout_ms * 1_000_000
        hardware.tickers.append(comcu.send_heartbeat)
        assert hardware.wait_until(hardware.now_ns() + 1_000_000_000, 5.0)
        hardware.tickers.clear()
        gaps = [b - a for a, b in zip(arrived, arrived[1:])]
        assert len(gaps) >= 50
        assert sorted(gaps)[len(gaps) // 2] == pytest.approx(hardware.tick_ns, abs=hardware.step_ns)
        assert max(gaps) <= hardware.tick_ns + 2 * hardware.step_ns + 10_000_000 < timeout_ns, max(gaps) / 1e6
        comcu.edges()
        assert comcu.heartbeat_acks >= len(arrived) - 2 and comcu.heartbeat_state[1] == mcu.Fault(0)
    finally:
        comcu.port.close()


@pytest.mark.parametrize("signame, orderly", [("SIGTERM", True), ("SIGSEGV", False)])
def test_an_emulator_ended_by_a_signal_stops_the_clock_with_one_log_line(hardware, caplog, monkeypatch, signame, orderly):
    """Stopping serve's process group (timeout, systemd stop) signals the emulator too: the clock
    thread ends with a warning, not an exception out of the thread. A crash (SIGSEGV) is not an
    orderly stop: it is raised out of the thread."""
    import signal
    import threading

    raised = []
    monkeypatch.setattr(threading, "excepthook", raised.append)
    clock = next(t for t in hardware._threads if t.name == "sim-clock")
    hardware.mcu._proc.send_signal(getattr(signal, signame))
    clock.join(timeout=5)
    logged = [r.getMessage() for r in caplog.records if r.name == "device.sim.hardware"]
    assert not clock.is_alive()
    if orderly:
        assert raised == [] and logged == [f"the co-MCU emulator was ended by {signame}; the simulated clock stops"]
    else:
        assert len(raised) == 1 and logged == []
