"""The frame record every camera backend produces (picamera2, simulator, replay)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Frame:
    """One luminance frame and its metadata.

    ``image``: (height, width) uint8 luminance (the Y plane of YUV420 on a Pi).
    ``sensor_timestamp_ns``: libcamera's SensorTimestamp T on CLOCK_MONOTONIC: the frame start of
    the sensor's whole readout (on a Pi the CSI-2 receiver's frame-start interrupt, ``ktime_get_ns()``
    in raspberrypi/linux drivers/media/platform/bcm2835/bcm2835-unicam.c ``unicam_isr``: "Timestamp is
    to be when the first data byte was captured, aka frame start"; passed through unchanged as the
    V4L2 buffer timestamp by raspberrypi/libcamera src/libcamera/pipeline/rpi/vc4/vc4.cpp
    ``unicamBufferDequeue``, to the microsecond of the V4L2 timeval). That is the Pi's, not
    libcamera's documented meaning ("the time when the first row of the image sensor active
    array is exposed", on CLOCK_BOOTTIME: src/libcamera/control_ids_core.yaml ``SensorTimestamp``):
    the implementation is what a Pi's frames carry, so it is what is modelled (CLOCK_BOOTTIME and
    CLOCK_MONOTONIC differ only by time suspended, which a running sensor never is). The IMX219
    sends one line of embedded data after the frame start before its first pixel row
    (raspberrypi/linux drivers/media/i2c/imx219.c ``IMX219_NUM_EMBEDDED_LINES``): image rows are
    read one line time (~19 us) later than modelled here; left out (0.002 deg at 90 deg/s).
    ``readout_offset_rows``: the sensor-mode rows read before image row 0 (the ISP's ScalerCrop
    starts that far down the mode: 155 in mode 5, device/camera/modes.py), so image row r is read
    at T + (readout_offset_rows + r) * line_time and exposed during the ``exposure`` before that
    (rolling shutter).
    ``lit``: whether the laser was scheduled to fire in this frame (docs/thesis-notes.md N10), None if unknown.
    """

    image: np.ndarray
    seq: int
    sensor_timestamp_ns: int
    exposure_us: float
    frame_duration_us: float
    line_time_ns: float
    lit: bool | None = None
    readout_offset_rows: int = 0

    def __post_init__(self) -> None:
        if self.image.ndim != 2 or self.image.dtype != np.uint8:
            raise ValueError(f"frame image must be (height, width) uint8, got {self.image.shape} {self.image.dtype}")

    def row_exposure_ns(self, row: int | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(start, end) of the exposure of image row(s) ``row``, CLOCK_MONOTONIC ns."""
        end = self.sensor_timestamp_ns + (self.readout_offset_rows + np.asarray(row, dtype=np.float64)) * self.line_time_ns
        return end - self.exposure_us * 1e3, end
