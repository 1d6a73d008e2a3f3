"""Which frames make one scan: a lit frame and its unlit neighbours (issue 16).

The laser lights every other frame (docs/thesis-notes.md N10). A scan is made of a lit frame and
the unlit frames right before and after it (consecutive sequence numbers): the pipeline takes the
background from both (device.vision.fast, step 0), so that a background that moved between them
(the robot turned, a person walked by) or flickered is not mistaken for the laser line. A lit
frame without an unlit frame right after it (a dropped frame, the stream's end) is paired with
the one before it alone; one with neither gives no scan.

Latency: the scan of a lit frame is made when the frame after it arrives, one frame period
(50 ms at 20 frames/s) after the lit frame. Pairing a lit frame with only the unlit frame after
it costs the same; pairing it with only the one before it, as the device did before, saved that
frame period in one of the two phases the laser can have.

The same rules run on the device (device.scan.source.SensorSource) and over a recording
(``laserpi evaluate --recording``).
"""

from __future__ import annotations

from dataclasses import dataclass

from device.camera.frame import Frame


@dataclass(frozen=True)
class Neighbours:
    """A lit frame, its nearest unlit neighbour (the one after it if there is one) and the other
    (the unlit frame before it, when ``unlit`` is the one after; else None)."""

    lit: Frame
    unlit: Frame
    other_unlit: Frame | None


class NeighbourPairing:
    """Feed frames in order with whether each was lit; get a lit frame's :class:`Neighbours`
    once the frame after it has arrived (``push``), or at the end of a stream (``flush``)."""

    def __init__(self) -> None:
        self._last: tuple[Frame, bool] | None = None
        self._before: tuple[Frame, bool] | None = None

    def reset(self) -> None:
        """Forget every frame (the stream broke: camera restarted, laser re-synchronised)."""
        self._last = self._before = None

    def push(self, frame: Frame, lit: bool) -> Neighbours | None:
        last, before = self._last, self._before
        self._before, self._last = last, (frame, lit)
        if last is None or not last[1]:
            return None
        after = frame if not lit and frame.seq == last[0].seq + 1 else None
        return _neighbours(last[0], before, after)

    def flush(self) -> Neighbours | None:
        """The last frame's Neighbours if it was lit (with the unlit frame before it only)."""
        last, before = self._last, self._before
        self.reset()
        return _neighbours(last[0], before, None) if last is not None and last[1] else None


def _neighbours(lit: Frame, before: tuple[Frame, bool] | None, after: Frame | None) -> Neighbours | None:
    prev = before[0] if before is not None and not before[1] and before[0].seq + 1 == lit.seq else None
    if after is not None:
        return Neighbours(lit, after, prev)
    return Neighbours(lit, prev, None) if prev is not None else None
