"""The one camera interface every backend implements (picamera2, simulator, replay), and the one
the device process drives (device/scan/source.py)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from .frame import Frame


class CameraError(RuntimeError):
    """A camera that cannot deliver frames; the message says why."""


class CaptureTimeout(CameraError):
    """No frame arrived within the timeout."""


class EndOfRecording(CameraError):
    """A replayed recording has no more frames."""


@runtime_checkable
class Camera(Protocol):
    """Luminance frames with their timing metadata.

    ``width``/``height`` are the frame buffer's size (e.g. 1664 x 928 in mode 5, the active
    1640 x 922 pixels at the top left); ``line_time_ns`` the rolling-shutter row time (the
    sensor mode's, device/camera/modes.py).
    ``set_frame_duration``/``set_exposure`` request new values; a backend applies them as its
    hardware does (on the IMX219 two frames later) and each Frame reports what it got.
    """

    width: int
    height: int
    line_time_ns: float

    def start(self) -> None:
        """Start streaming frames (may be called again after ``stop()`` to restart)."""

    def stop(self) -> None:
        """Stop streaming; must not raise on a camera that has failed."""

    def capture(self, timeout_s: float = 1.0) -> Frame:
        """The next frame; CaptureTimeout if none arrived within ``timeout_s``; raises on a
        camera error."""

    def set_frame_duration(self, frame_duration_us: float) -> None: ...

    def set_exposure(self, exposure_us: float) -> None: ...
