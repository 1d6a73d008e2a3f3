"""Camera backend for a Raspberry Pi: picamera2 (libcamera), imported only when started.

Configuration (thesis B.1.4, Table B.3, mode 5; ``window`` = device/camera/modes.py MODE5): the
sensor runs its 2x2-binned 1640x1232 mode and the ISP crops the centre 3280x1844 sensor pixels
(``ScalerCrop``, 310 rows off the top and bottom at full resolution) to a 1640x922 YUV420
``main`` stream; only the luminance (Y) plane is used. Auto exposure and auto white balance are
off; exposure time and analogue gain are fixed; the frame rate is set with
``FrameDurationLimits`` (min = max). Each frame's timestamp is the request metadata's
``SensorTimestamp`` (ns), taken, like the Frame record, as the start of the first row's readout;
``ExposureTime`` and ``FrameDuration`` come from the same metadata.

The Y plane is placed at the top left of a zeroed buffer of the configured size (1664x928 for
the thesis configuration, docs/thesis-notes.md N6), so that frames from a Pi and from the simulator have one
layout.
"""

from __future__ import annotations

import importlib
import logging
import threading

import numpy as np

from .base import CameraError, CaptureTimeout
from .frame import Frame
from .modes import MODE5, ImageWindow

log = logging.getLogger(__name__)


class Picamera2Camera:
    """Fixed-exposure luminance frames from picamera2 (see the module docstring)."""

    def __init__(self, width: int = 1664, height: int = 928, exposure_us: float = 40000.0,
                 frame_duration_us: float = 50000.0, analogue_gain: float = 1.0, camera_num: int = 0,
                 window: ImageWindow = MODE5, buffer_count: int = 6):
        """``window``: the sensor mode and the crop of it that the stream delivers (SensorConfig.window)."""
        output_size = (window.width, window.height)
        if output_size[0] > width or output_size[1] > height:
            raise ValueError(f"output {output_size} does not fit the {width}x{height} frame buffer")
        if not 0 < exposure_us <= frame_duration_us:
            raise ValueError(f"exposure_us {exposure_us} must be in (0, frame_duration_us = {frame_duration_us}]")
        self.width, self.height, self.line_time_ns = width, height, window.mode.line_time_ns
        self._exposure_us, self._frame_duration_us, self._gain = float(exposure_us), float(frame_duration_us), analogue_gain
        self._camera_num, self._output = camera_num, output_size
        self._sensor, self._crop = (window.mode.width, window.mode.height), window.scaler_crop
        self._buffer_count = buffer_count
        self._cam = None
        self._pending = None  # capture job still outstanding after a timeout
        self._seq = 0
        self._lock = threading.Lock()

    def _controls(self) -> dict:
        d = int(round(self._frame_duration_us))
        return {
            "AeEnable": False,
            "AwbEnable": False,
            "ExposureTime": int(round(self._exposure_us)),
            "AnalogueGain": float(self._gain),
            "FrameDurationLimits": (d, d),
            "ScalerCrop": self._crop,
        }

    def start(self) -> None:
        if self._cam is not None:
            return
        try:
            picamera2 = importlib.import_module("picamera2")
        except ImportError as exc:
            raise CameraError(f"picamera2 is not installed ({exc}); on a Pi: sudo apt install python3-picamera2") from None
        cam = picamera2.Picamera2(self._camera_num)
        try:
            config = cam.create_video_configuration(
                main={"size": self._output, "format": "YUV420"},
                sensor={"output_size": self._sensor, "bit_depth": 10},
                controls=self._controls(),
                buffer_count=self._buffer_count,
            )
            cam.configure(config)
            cam.set_controls(self._controls())
            cam.start()
        except Exception:
            cam.close()
            raise
        self._cam = cam
        log.info("picamera2 started: %s YUV420 from sensor %s, crop %s", self._output, self._sensor, self._crop)

    def stop(self) -> None:
        cam, self._cam = self._cam, None
        self._pending = None
        if cam is not None:
            try:
                cam.stop()
            finally:
                cam.close()

    def set_frame_duration(self, frame_duration_us: float) -> None:
        if not frame_duration_us >= self._exposure_us:
            raise ValueError(f"frame duration {frame_duration_us} us is shorter than the exposure {self._exposure_us} us")
        self._frame_duration_us = float(frame_duration_us)
        if self._cam is not None:
            d = int(round(frame_duration_us))
            self._cam.set_controls({"FrameDurationLimits": (d, d)})

    def set_exposure(self, exposure_us: float) -> None:
        if not 0 < exposure_us <= self._frame_duration_us:
            raise ValueError(f"exposure {exposure_us} us must be in (0, frame duration {self._frame_duration_us} us]")
        self._exposure_us = float(exposure_us)
        if self._cam is not None:
            self._cam.set_controls({"ExposureTime": int(round(exposure_us))})

    def capture(self, timeout_s: float = 1.0) -> Frame:
        if self._cam is None:
            raise CameraError("camera not started: call start() first")
        # a job that timed out is waited on again next time, so its request is not leaked
        job = self._pending if self._pending is not None else self._cam.capture_request(wait=False)
        try:
            request = self._cam.wait(job, timeout=timeout_s)
        except TimeoutError:
            self._pending = job
            raise CaptureTimeout(f"no frame from picamera2 within {timeout_s} s") from None
        self._pending = None
        try:
            yuv = request.make_array("main")
            meta = request.get_metadata()
        finally:
            request.release()
        w, h = self._output
        if yuv.ndim != 2 or yuv.shape[0] < h * 3 // 2 or yuv.shape[1] < w:
            raise CameraError(f"unexpected YUV420 buffer shape {yuv.shape} for a {w}x{h} stream")
        image = np.zeros((self.height, self.width), dtype=np.uint8)
        image[:h, :w] = yuv[:h, :w]  # the Y plane; U and V follow below it
        try:
            ts = int(meta["SensorTimestamp"])
        except KeyError:
            raise CameraError("request metadata has no SensorTimestamp") from None
        with self._lock:
            seq, self._seq = self._seq, self._seq + 1
        return Frame(image=image, seq=seq, sensor_timestamp_ns=ts,
                     exposure_us=float(meta.get("ExposureTime", self._exposure_us)),
                     frame_duration_us=float(meta.get("FrameDuration", self._frame_duration_us)),
                     line_time_ns=self.line_time_ns, lit=None)
