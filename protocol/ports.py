"""Byte ports the link server (protocol/server.py) and the replay server run on, besides a
pyserial ``Serial``.

All have the pyserial-like surface the server uses: ``read(size)`` returns the bytes that are
available (up to size), or b"" after a short timeout; ``write(data)`` sends all of data;
a closed or vanished peer raises PortClosed (an OSError) from either.

- PtyLink: a real pseudo-terminal (os.openpty, raw mode) whose slave is symlinked to a path,
  for ``laserpi serve --link PATH`` and ``laserpi replay --link PATH``; its ``port`` is the
  master side.
- pipe_pair(): two connected in-memory ends with a bounded buffer, for ``sim://``.
- PacedPort: wraps a port so that writes take as long as on a UART at ``baudrate`` (8N1, 10 bits
  per byte); ptys and pipes are otherwise instantaneous, which would make host time stamps
  (which subtract the transmission time) wrong.
- NoisyPort: wraps a port so that written bits flip at a given bit error rate (a bad cable),
  for testing that hosts survive corruption.
"""

from __future__ import annotations

import errno
import random
import logging
import math
import os
import select
import threading
import time
from pathlib import Path

from protocol.messages import UART_BITS_PER_BYTE

log = logging.getLogger(__name__)



class PortClosed(OSError):
    """The other end of the port is gone (or this end was closed)."""


class FdPort:
    """A non-blocking file descriptor (a pty master) as a port."""

    def __init__(self, fd: int, timeout_s: float = 0.05):
        self.fd = fd
        self.timeout_s = timeout_s
        self._closed = threading.Event()
        os.set_blocking(fd, False)

    def read(self, size: int = 4096) -> bytes:
        if self._closed.is_set():
            raise PortClosed("port closed")
        ready, _, _ = select.select([self.fd], [], [], self.timeout_s)
        if not ready:
            return b""
        try:
            return os.read(self.fd, size)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:  # no slave side open (pty) - nobody listening right now
                time.sleep(self.timeout_s)
                return b""
            raise PortClosed(str(exc)) from exc

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        while view:
            if self._closed.is_set():
                raise PortClosed("port closed while writing")
            _, ready, _ = select.select([], [self.fd], [], 0.1)
            if not ready:
                continue
            try:
                n = os.write(self.fd, view)
            except BlockingIOError:
                continue
            except OSError as exc:
                if exc.errno == errno.EIO:  # pty without reader: the bytes are lost, like a UART's
                    return len(data)
                raise PortClosed(str(exc)) from exc
            view = view[n:]
        return len(data)

    def close(self) -> None:
        self._closed.set()


class PacedPort:
    """``port`` whose writes last len(data) * 10 / baudrate seconds before the bytes arrive."""

    def __init__(self, port, baudrate: int):
        if baudrate <= 0:
            raise ValueError(f"baudrate must be positive, got {baudrate}")
        self.port = port
        self.baudrate = baudrate

    def read(self, size: int = 4096) -> bytes:
        return self.port.read(size)

    def write(self, data: bytes) -> int:
        time.sleep(len(data) * UART_BITS_PER_BYTE / self.baudrate)
        return self.port.write(data)


class NoisyPort:
    """``port`` whose writes have each bit flipped with probability ``bit_error_rate``."""

    def __init__(self, port, bit_error_rate: float, seed: int | None = None):
        if not 0 <= bit_error_rate < 1:
            raise ValueError(f"bit_error_rate must be in [0, 1), got {bit_error_rate}")
        self.port = port
        self.bit_error_rate = bit_error_rate
        self._rng = random.Random(seed)
        self.bits_flipped = 0

    def read(self, size: int = 4096) -> bytes:
        return self.port.read(size)

    def write(self, data: bytes) -> int:
        out = bytearray(data)
        n_bits = 8 * len(out)
        # geometric gaps between errors: exact Bernoulli per bit without a loop over bits
        pos = self._gap()
        while pos < n_bits:
            out[pos // 8] ^= 1 << (pos % 8)
            self.bits_flipped += 1
            pos += 1 + self._gap()
        return self.port.write(bytes(out))

    def _gap(self) -> int:
        if self.bit_error_rate == 0:
            return 1 << 62
        return int(math.log(1.0 - self._rng.random()) / math.log(1.0 - self.bit_error_rate))


class _PipeEnd:
    def __init__(self, inbox: _Buffer, outbox: _Buffer, timeout_s: float):
        self._inbox, self._outbox, self.timeout_s = inbox, outbox, timeout_s

    def read(self, size: int = 4096, timeout_s: float | None = None) -> bytes:
        return self._inbox.get(size, self.timeout_s if timeout_s is None else timeout_s)

    def write(self, data: bytes) -> int:
        self._outbox.put(bytes(data))
        return len(data)

    @property
    def in_waiting(self) -> int:
        return self._inbox.size()

    def reset_input(self) -> None:
        self._inbox.clear()

    def close(self) -> None:
        self._inbox.close()
        self._outbox.close()


class _Buffer:
    """A bounded byte FIFO; put() blocks while full, like a UART driver's buffer."""

    def __init__(self, capacity: int):
        self.capacity = capacity
        self._data = bytearray()
        self._cond = threading.Condition()
        self._closed = False

    def put(self, data: bytes) -> None:
        view = memoryview(data)
        with self._cond:
            while view:
                if self._closed:
                    raise PortClosed("pipe closed")
                room = self.capacity - len(self._data)
                if room <= 0:
                    self._cond.wait(0.1)
                    continue
                self._data += view[:room]
                view = view[room:]
                self._cond.notify_all()

    def get(self, size: int, timeout_s: float) -> bytes:
        with self._cond:
            if not self._data and not self._closed:
                self._cond.wait(timeout_s)
            if not self._data and self._closed:
                raise PortClosed("pipe closed")
            out = bytes(self._data[:size])
            del self._data[:size]
            self._cond.notify_all()
            return out

    def size(self) -> int:
        with self._cond:
            return len(self._data)

    def clear(self) -> None:
        with self._cond:
            self._data.clear()
            self._cond.notify_all()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()


def pipe_pair(capacity: int = 65536, timeout_s: float = 0.05) -> tuple[_PipeEnd, _PipeEnd]:
    """Two connected ends (host, device); each end's writes are the other's reads."""
    a, b = _Buffer(capacity), _Buffer(capacity)
    return _PipeEnd(a, b, timeout_s), _PipeEnd(b, a, timeout_s)


def open_raw_pty() -> tuple[int, int, str]:
    """A pseudo-terminal in raw mode (no echo, no line discipline: a serial line's bytes as they
    are): (master fd, slave fd, slave path). Keep the slave fd open while the slave may have no
    other user, or reads on the master fail with EIO."""
    import tty  # POSIX only: imported here so that sim:// (pipe_pair) also works on Windows

    master_fd, slave_fd = os.openpty()
    tty.setraw(slave_fd)
    return master_fd, slave_fd, os.ttyname(slave_fd)


class PtyLink:
    """A pseudo-terminal in raw mode with its slave symlinked at ``link_path``.

    Use as a context manager; on exit the symlink is removed and both fds closed. The slave fd is
    kept open here so that the master does not see EIO while no host has the port open.
    """

    def __init__(self, link_path: str | os.PathLike):
        self.link_path = Path(link_path)
        if self.link_path.exists() and not self.link_path.is_symlink():
            raise FileExistsError(f"{self.link_path} exists and is not a symlink; refusing to replace it")
        self.master_fd, self.slave_fd, self.slave_name = open_raw_pty()
        tmp = self.link_path.with_name(f".{self.link_path.name}.{os.getpid()}")
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(self.slave_name)
        os.replace(tmp, self.link_path)  # atomic: a stale link from a crashed run is replaced
        self.port = FdPort(self.master_fd)
        log.info("pty %s linked at %s", self.slave_name, self.link_path)

    def close(self) -> None:
        self.port.close()
        try:
            if self.link_path.is_symlink() and os.readlink(self.link_path) == self.slave_name:
                self.link_path.unlink()
        finally:
            for fd in (self.master_fd, self.slave_fd):
                try:
                    os.close(fd)
                except OSError:
                    pass

    def __enter__(self) -> PtyLink:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
