"""device.laser.comcu.CoMcu against a scripted port (no emulator): reply matching, NACK reasons,
timeouts, interleaved EDGE reports, boot INFO and damaged frames."""
import pytest

from device.laser.comcu import HEARTBEAT_SEQ, CoMcu, CoMcuError, CoMcuNack, CoMcuTimeout
from protocol import mcu
from protocol.framing import MAX_PAYLOAD_MCU, decode_frame


class ScriptedPort:
    """pyserial-like: every frame written is answered by respond(frame) -> wire bytes."""

    def __init__(self, respond):
        self.respond = respond
        self.rx = bytearray()
        self.requests = []

    def write(self, data):
        for chunk in bytes(data).split(b"\x00"):
            if chunk:
                frame = decode_frame(chunk, max_payload=MAX_PAYLOAD_MCU)
                self.requests.append(mcu.decode_message(frame))
                self.rx += self.respond(frame)
        return len(data)

    @property
    def in_waiting(self):
        return len(self.rx)

    def read(self, size=1):
        out = bytes(self.rx[:size])
        del self.rx[:size]
        return out


def test_ping_returns_mcu_time_bracketed_by_host_times():
    clock = iter([100, 250])
    port = ScriptedPort(lambda f: mcu.encode_message(mcu.Pong(41, 42), f.seq))
    result = CoMcu(port, clock_ns=lambda: next(clock)).ping()
    assert (result.mcu_ticks, result.mcu_rx_ticks, result.host_send_ns, result.host_recv_ns) == (42, 41, 100, 250)
    assert result.round_trip_ns == 150


def test_nack_raises_with_the_reason_and_detail():
    port = ScriptedPort(lambda f: mcu.encode_message(
        mcu.Nack(f.msg_type, mcu.NackReason.ENVELOPE_WIDTH, 34_800), f.seq))
    with pytest.raises(CoMcuNack, match="SCHEDULE refused by the co-MCU: envelope_width") as exc:
        CoMcu(port).schedule(1_000_000, 100_000, 40_000)
    assert exc.value.reason == "envelope_width" and exc.value.detail == 34_800
    assert port.requests == [mcu.Schedule(1_000_000, 100_000, 40_000)]


def test_edges_boot_info_and_stale_or_damaged_frames_are_kept_apart():
    edge = mcu.Edge(4, 1000, 1200, 0)
    boot = mcu.Info(2, 0x08, 50, 34_800, 200_000, 2_000_000, 180_000)

    def respond(f):
        damaged = bytearray(mcu.encode_message(mcu.Ack(0x45, 1), f.seq))
        damaged[2] ^= 0x10
        return (mcu.encode_message(edge, 0) + mcu.encode_message(boot, 0) + bytes(damaged)
                + mcu.encode_message(mcu.Ack(0x45, 7), (f.seq + 5) & 0xFFFF)  # stale reply
                + mcu.encode_message(mcu.Ack(0x45, 1 | (mcu.Fault.HEARTBEAT << 8)), f.seq))

    port = ScriptedPort(respond)
    comcu = CoMcu(port)
    comcu.send_heartbeat()
    assert port.requests == [mcu.Heartbeat()] and comcu.heartbeat_state is None, "written, not waited for"
    assert comcu.edges() == [edge] and comcu.edges() == []
    assert comcu.boot_infos == [boot] and comcu.bad_frames == 1
    assert comcu.heartbeat_state == (mcu.McuState.RUNNING, mcu.Fault.HEARTBEAT) and comcu.heartbeat_acks == 1



@pytest.mark.parametrize("state", list(mcu.McuState))
def test_a_fault_free_heartbeat_ack_counts_as_its_decoded_message_would(state):
    acks = [mcu.Ack(0x45, 1 | (mcu.Fault.LATE << 8)), mcu.Ack(0x45, int(state)), mcu.Ack(0x45, int(state))]
    port = ScriptedPort(lambda f: mcu.encode_message(acks.pop(0), f.seq))
    comcu = CoMcu(port)
    comcu.send_heartbeat()
    comcu.edges()
    assert comcu.heartbeat_state == (mcu.McuState.RUNNING, mcu.Fault.LATE) and comcu.heartbeat_acks == 1
    comcu.send_heartbeat()
    comcu.send_heartbeat()
    assert comcu.edges() == [] and comcu.bad_frames == 0
    assert comcu.heartbeat_state == (state, mcu.Fault(0)) and comcu.heartbeat_acks == 3
    assert type(comcu.heartbeat_state[0]) is mcu.McuState and type(comcu.heartbeat_state[1]) is mcu.Fault

def test_heartbeat_acks_never_answer_a_request_and_a_stop_forgets_their_state():
    seqs = []

    def respond(f):
        seqs.append(f.seq)
        ack = mcu.encode_message(mcu.Ack(f.msg_type, 1 | (mcu.Fault.DUTY << 8)), HEARTBEAT_SEQ)
        return ack + mcu.encode_message(mcu.Ack(f.msg_type, 0), f.seq)  # a heartbeat's ACK first

    comcu = CoMcu(ScriptedPort(respond))
    comcu._seq = HEARTBEAT_SEQ - 2
    assert [comcu.trim(0, 0), comcu.trim(0, 0)] == [0, 0]
    assert seqs == [HEARTBEAT_SEQ - 1, 1], "requests wrap around the heartbeat's sequence number"
    assert comcu.heartbeat_state == (mcu.McuState.RUNNING, mcu.Fault.DUTY) and comcu.heartbeat_acks == 2
    comcu.stop()  # the MCU answers in order: the ACK before the STOP's is of a heartbeat before it
    assert comcu.heartbeat_state is None


def test_silence_is_a_timeout_and_a_wrong_reply_type_an_error():
    with pytest.raises(CoMcuTimeout):
        CoMcu(ScriptedPort(lambda f: b"")).status()
    port = ScriptedPort(lambda f: mcu.encode_message(mcu.Ack(f.msg_type, 0), f.seq))
    with pytest.raises(CoMcuError, match="StatusRequest answered by Ack"):
        CoMcu(port).status()


def test_trim_and_stop_return_the_ack_info():
    port = ScriptedPort(lambda f: mcu.encode_message(mcu.Ack(f.msg_type, 17), f.seq))
    comcu = CoMcu(port)
    assert comcu.trim(phase_ticks=-5, period_ticks=3) == 17
    assert comcu.stop() == 17
    assert port.requests == [mcu.Trim(-5, 3), mcu.Stop()]


def test_train_adapter_replaces_the_train_and_sends_period_differences():
    from device.laser.comcu import CoMcuTrain

    port = ScriptedPort(lambda f: mcu.encode_message(mcu.Ack(f.msg_type, 0), f.seq))
    train = CoMcuTrain(CoMcu(port))
    with pytest.raises(CoMcuError, match="schedule first"):
        train.trim(5, 66_000)
    train.schedule(10_000, 66_667, 20_000, [True, False])
    train.trim(-40, 66_660)
    train.trim(3, 66_661)
    with pytest.raises(ValueError, match="at least one lit"):
        train.schedule(10_000, 66_667, 20_000, [False, False])
    assert port.requests == [mcu.Stop(), mcu.Schedule(10_000, 66_667, 20_000, 0b01, 2, True),
                             mcu.Trim(-40, -7), mcu.Trim(3, 1)]


class FullPort(ScriptedPort):
    """A port whose transmit buffer takes only ``room`` more bytes (a non-blocking write)."""

    def __init__(self, room):
        super().__init__(lambda f: mcu.encode_message(mcu.Pong(1, 2), f.seq))
        self.room = room

    def write(self, data):
        return super().write(bytes(data)) if len(data) <= self.room else self.room


def test_a_frame_the_port_takes_only_part_of_is_a_lost_link():
    comcu = CoMcu(FullPort(room=5))
    with pytest.raises(OSError, match="took 5 of a frame's 14 bytes"):
        comcu.send_heartbeat()
    with pytest.raises(OSError, match="took 5 of"):
        comcu.ping()
    assert comcu.heartbeats_sent == 0
    roomy = CoMcu(FullPort(room=64))
    roomy.send_heartbeat()
    assert roomy.ping().mcu_ticks == 2 and roomy.heartbeats_sent == 1


def test_the_serial_port_is_opened_with_non_blocking_writes():
    import os
    import pty

    from device.laser.comcu import open_comcu

    master, slave = pty.openpty()
    try:
        comcu = open_comcu(os.ttyname(slave))
        assert comcu.port.serial.write_timeout == 0 and comcu.port.timeout == 0.05
        comcu.send_heartbeat()
        assert os.read(master, 64).endswith(mcu.encode_message(mcu.Heartbeat(), HEARTBEAT_SEQ))
        comcu.port.close()
        with pytest.raises(OSError):
            open_comcu("/dev/no-such-serial-port")
    finally:
        os.close(master)
        os.close(slave)


def test_the_uart_port_reads_and_writes_as_pyserial_does():
    """UartPort (open_comcu's port) on a pty: what is there comes at once, a read waits up to its
    timeout for the rest and returns what came, a write returns the bytes taken, and the far end
    gone is an OSError, not an endless run of empty reads."""
    import os
    import pty
    import time

    from device.laser.comcu import open_comcu

    master, slave = pty.openpty()
    try:
        port = open_comcu(os.ttyname(slave)).port
        os.write(master, b"abc")
        time.sleep(0.01)
        assert port.in_waiting == 3 and port.read(3) == b"abc"
        t0 = time.monotonic()
        assert port.read(1) == b"" and 0.04 <= time.monotonic() - t0 < 0.5  # its 0.05 s timeout
        os.write(master, b"de")
        assert port.read(5) == b"de"  # what came within the timeout
        assert port.write(b"xyz") == 3 and os.read(master, 16) == b"xyz"
        os.close(master)
        master = None
        with pytest.raises(OSError):
            port.read(1)
        hold = os.open(os.devnull, os.O_RDONLY)  # takes the closed master's number
        number = port.fd
        port.close()
        other = os.open(os.devnull, os.O_WRONLY)  # the kernel hands out the lowest free number: port's
        try:
            assert other == number
            with pytest.raises(OSError):  # not onto whatever file has the number now
                port.write(b"x")
        finally:
            os.close(other)
            os.close(hold)
    finally:
        if master is not None:
            os.close(master)
        os.close(slave)


def test_the_uart_port_needs_a_read_timeout():
    from device.laser.comcu import UartPort

    class Blocking:
        timeout = None

    with pytest.raises(ValueError, match="finite read timeout, got None"):
        UartPort(Blocking())
