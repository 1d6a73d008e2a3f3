"""Laser-trigger edges on a Pi GPIO, timestamped by the kernel (libgpiod v2 edge events).

The co-MCU's laser trigger line is also wired to a Pi GPIO input (``laserpi serve --gpio-edge
CHIP:LINE``, or ``[pi] gpio_edge`` in the configuration). The kernel timestamps each edge in its
interrupt handler with ``ktime_get_ns()``, CLOCK_MONOTONIC, unless the line asks for the realtime
or a hardware clock (torvalds/linux drivers/gpio/gpiolib-cdev.c ``line_event_timestamp``; libgpiod
v2 requests ``Clock.MONOTONIC`` here explicitly). The camera's SensorTimestamp is ``ktime_get_ns()``
too, taken in the CSI-2 receiver's frame-start interrupt (raspberrypi/linux
drivers/media/platform/bcm2835/bcm2835-unicam.c ``unicam_isr``) and passed through by libcamera's
Raspberry Pi pipeline (src/libcamera/pipeline/rpi/vc4/vc4.cpp); libcamera's control description
names CLOCK_BOOTTIME, which differs from CLOCK_MONOTONIC only by time spent suspended, and a
running sensor does not suspend. So pairing these edges with the MCU's own edge ticks maps MCU
time to camera time without the serial link's latency (``device.sync.clock_map``).

``gpiod`` (the libgpiod v2 Python bindings, extra ``laserpi[pi]``) is imported only when a
source is opened, so everything else runs without it.
"""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)


def parse_gpio_edge(spec: str) -> tuple[str, int]:
    """``"gpiochip0:17"`` or ``"/dev/gpiochip0:17"`` -> (``"/dev/gpiochip0"``, 17); ValueError otherwise."""
    chip, sep, line = spec.rpartition(":")
    if not sep or not chip or not line.isdigit():
        raise ValueError(f"a GPIO edge line is CHIP:LINE, e.g. gpiochip0:17 (the BCM number of the pin), got {spec!r}")
    return (chip if chip.startswith("/") else f"/dev/{chip}"), int(line)


class GpioEdgeSource:
    """One requested GPIO line with edge detection on both edges; ``read`` returns (ns, rising)."""

    def __init__(self, chip_path: str, line_offset: int, consumer: str = "laserpi-sync") -> None:
        if line_offset < 0:
            raise ValueError(f"GPIO line offset must be >= 0, got {line_offset}")
        try:
            import gpiod
            from gpiod.line import Clock, Edge
        except ImportError as exc:
            raise RuntimeError("GPIO edge timestamps need the libgpiod v2 Python bindings: "
                               "pip install 'laserpi[pi]' (package gpiod)") from exc
        self._rising = gpiod.EdgeEvent.Type.RISING_EDGE
        settings = gpiod.LineSettings(edge_detection=Edge.BOTH, event_clock=Clock.MONOTONIC)
        self._request = gpiod.request_lines(chip_path, consumer=consumer, config={line_offset: settings})
        self.line_offset = line_offset
        self._last_seqno: int | None = None
        self.lost_events = 0
        log.info("watching laser trigger edges on %s line %d", chip_path, line_offset)

    def read(self, timeout_s: float = 0.0) -> list[tuple[int, bool]]:
        """Edge events waiting in the kernel's buffer: (CLOCK_MONOTONIC ns, rising), in order.

        Waits up to ``timeout_s`` for the first one. Gaps in the line's sequence numbers (the
        kernel buffer overflowed) are counted in ``lost_events``.
        """
        if not self._request.wait_edge_events(timeout_s):
            return []
        out = []
        for ev in self._request.read_edge_events():
            seq = ev.line_seqno
            if self._last_seqno is not None and seq > self._last_seqno + 1:
                self.lost_events += seq - self._last_seqno - 1
            self._last_seqno = seq
            out.append((int(ev.timestamp_ns), ev.event_type == self._rising))
        return out

    def close(self) -> None:
        self._request.release()

    def __enter__(self) -> GpioEdgeSource:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
