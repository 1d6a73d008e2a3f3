"""A fake ``picamera2`` module for tests: Picamera2 as the real one behaves for LaserPi's use.

Each behaviour is the upstream one, cited (raspberrypi/picamera2 at 3e6dff09; raspberrypi/libcamera
at 26bfadc6; raspberrypi/linux drivers/media/platform/bcm2835/bcm2835-unicam.c):

* **Dropped frames when the consumer lags.** picamera2 keeps at most one completed request
  (picamera2.py ``configure_``: ``_max_queue_len = 1`` when ``queue`` and ``buffer_count > 1``;
  ``process_requests``: "while len(self.completed_requests) > self._max_queue_len:
  self.completed_requests.pop(0).release()"), so a frame that completes while the application is
  not waiting replaces the one held, and ``capture_request`` hands out the held one at once.
  The sensor keeps streaming meanwhile, and the frame's sequence number counts sensor frames
  (unicam_isr increments ``unicam->sequence`` per sensor frame, "not the frames dequeued to
  userland"; libcamera FrameMetadata::sequence: "Gaps in the sequence numbers indicate dropped
  frames", taken from the V4L2 buffer in v4l2_videodevice.cpp). Here: the raw stream's buffer
  metadata ``sequence``, as on the Pi.
* **SensorTimestamp at the start of the full sensor readout.** unicam's frame-start interrupt
  stamps the buffer with ``ktime_get_ns()`` (CLOCK_MONOTONIC), "when the first data byte was
  captured, aka frame start", and libcamera's vc4 pipeline copies it to SensorTimestamp
  (vc4.cpp ``unicamBufferDequeue``); the V4L2 timeval keeps microseconds
  (v4l2_videodevice.cpp: ``tv_sec * 1000000000ULL + tv_usec * 1000ULL``). The sensor reads the
  whole mode (1232 rows in the binned mode); the ISP crops afterwards (``ScalerCrop``), so the
  stamp is ``crop top`` rows before image row 0 is read. Plus an interrupt latency.
* **YUV420 with stride padding.** The mapped array of a YUV420 stream (``MappedArray``, below;
  ``make_array`` gives a copy of the same) is a ``(height * 3 // 2, stride)`` uint8 array, the
  padding left in (request.py
  ``_make_array_shared``: "We leave any packing in there"); planes are 32-byte aligned on VC4, so
  the Y stride is a multiple of 64 (picamera2.py ``align_stream``: "all planes are a multiple
  of 32/64 bytes wide. This matches the hardware behaviour").
* **Mapped buffers, recycled on release.** ``MappedArray(request, stream, reshape=True,
  write=True)`` is a context manager whose ``array`` shares the stream's buffer (request.py
  ``MappedArray.__enter__``: ``np.array(b, copy=False)``, a YUV420 buffer reshaped to
  ``(height * 3 // 2, stride)``) while the block runs (``__exit__`` deletes it and ends the
  dma-buf sync); a stream the request does not have is a KeyError (``request.stream_map[stream]``).
  ``release()`` queues the request back to the camera (request.py ``release``:
  ``self.picam2.camera.queue_request``), which fills its buffer with a later frame: here it is
  overwritten at once, so that a frame still sharing it would show it.
* **Sensor-mode information.** After ``configure``, ``camera_controls["ScalerCrop"]`` is
  (min, max, default) with max the mode's crop on the active array and
  ``camera_controls["FrameDurationLimits"][0]`` the mode's shortest frame in microseconds
  (picamera2.py ``sensor_modes`` reads exactly these as ``crop_limits`` and ``fps``;
  libcamera ipa_base.cpp: minFrameLength x minLineLength); ``camera_configuration()["sensor"]``
  has the ``output_size`` (picamera2.py ``_update_stream_config``/``sensor_config``).
  Request metadata carries ``SensorTimestamp``, ``ExposureTime``, ``FrameDuration``,
  ``ScalerCrop``.
* **Tuning.** ``Picamera2(n, tuning=dict)`` and the static ``load_tuning_file(name)`` (RuntimeError
  "Tuning file not found" for a name it does not have) and ``find_tuning_algo(tuning, name)``
  (version 2: the ``algorithms`` list), as picamera2.py has them; the tuning files here hold the
  algorithms and parameters Picamera2Camera changes, named as in libcamera's
  src/ipa/rpi/vc4/data/imx219_noir.json (``rpi.contrast`` with ``ce_enable`` and a gamma curve,
  ``rpi.sharpen``, ``rpi.sdn``), with a two-point stand-in for the real curve.

What the frames show is the test's: ``render(sequence, frame_start_ns, row0_ns, exposure_us,
line_time_ns)`` returns the image (height, width) uint8 of the frame whose image row 0 is read
at ``row0_ns``.
Time is the ``clock``'s (``now_ns()``, ``wait_until(t_ns, timeout_s)``): device/sim/hardware.py's
simulated Pi, or :class:`ManualClock`.
"""

from __future__ import annotations

import json
import sys
import threading
import types
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from device.camera.modes import IMX219_VBLANK_MIN_LINES, SENSOR_MODES
from device.sim.timing import CameraClock, CameraTimingConfig

ACTIVE_ARRAY = (3280, 2464)


class ManualClock:
    """A clock that advances only when told to, or when a wait needs it to (``auto``)."""

    def __init__(self, start_ns: int = 10**9, auto: bool = True):
        self.t, self.auto = start_ns, auto

    def now_ns(self) -> int:
        return self.t

    def advance(self, dt_ns: int) -> None:
        self.t += dt_ns

    def wait_until(self, t_ns: int, timeout_s: float) -> bool:
        if self.auto and t_ns - self.t <= timeout_s * 1e9:
            self.t = max(self.t, t_ns)
        return self.t >= t_ns


@dataclass
class FakeStats:
    frames: int = 0  # sensor frames completed
    delivered: int = 0
    dropped: int = 0  # completed, released by picamera2 before anyone asked for them


class _Stream:
    def __init__(self, name: str):
        self.name = name


class _Buffer:
    def __init__(self, sequence: int, timestamp: int):
        self.metadata = types.SimpleNamespace(sequence=sequence, timestamp=timestamp)


class FakeCompletedRequest:
    def __init__(self, cam: FakePicamera2, yuv: np.ndarray, metadata: dict, sequence: int):
        self._cam, self._yuv, self._meta = cam, yuv, metadata
        self.stream_map = dict(cam.stream_map)
        self.request = types.SimpleNamespace(buffers={self.stream_map["raw"]: _Buffer(sequence, metadata["SensorTimestamp"]),
                                                      self.stream_map["main"]: _Buffer(sequence, metadata["SensorTimestamp"])})
        self.released = False
        self.mappings: list[MappedArray] = []  # the MappedArrays made of this request, in order

    def get_metadata(self) -> dict:
        return dict(self._meta)

    def release(self) -> None:
        if self.released:
            raise RuntimeError("CompletedRequest: lock now has negative ref_count")
        self.released = True
        self._yuv[:] = 0x55  # back to the camera: a later frame is written into this buffer


class MappedArray:
    """picamera2.MappedArray (request.py) over a FakeCompletedRequest; the module docstring."""

    def __init__(self, request: FakeCompletedRequest, stream: str, reshape: bool = True, write: bool = True):
        request.stream_map[stream]  # noqa: B018 -- a KeyError for a stream the request does not have
        self._request, self.write, self._array = request, write, None
        request.mappings.append(self)

    def __enter__(self) -> MappedArray:
        if self._request.released:
            raise RuntimeError("the request was released: its buffer is the camera's again")
        self._array = self._request._yuv
        return self

    def __exit__(self, *exc) -> None:
        del self._array  # as request.py's __exit__: ``array`` is gone (AttributeError) after the block

    @property
    def array(self) -> np.ndarray | None:
        return self._array


class FakePicamera2:
    """picamera2.Picamera2 for the calls Picamera2Camera makes; see the module docstring."""

    def __init__(self, camera_num: int = 0, tuning: dict | None = None, *, clock, render: Callable, timing: CameraTimingConfig,
                 latency_ns: int = 20_000, isp_ns: int = 2_000_000, modes: dict = SENSOR_MODES, seed: int = 0,
                 hold_frames: float = 5.0):
        """``hold_frames``: a test machine's concession, not the camera's: a clock with ``limit_ns``
        (the simulated Pi) is held that many frames beyond the last frame handed out, so that a
        loaded test machine does not drop without end; lags shorter than that drop frames as the
        real camera does."""
        self.hold_frames = hold_frames
        self.tuning = tuning
        self.requests: list[FakeCompletedRequest] = []  # every request handed out, in order
        self.camera_num, self.clock, self.render, self.timing = camera_num, clock, render, timing
        self.latency_ns, self.isp_ns, self.modes = latency_ns, isp_ns, modes
        self.stats = FakeStats()
        self.jobs = 0
        self.controls: dict = {}
        self.started = False
        self.closed = False
        self.stream_map = {"main": _Stream("main"), "raw": _Stream("raw"), "lores": None}
        self._rng = np.random.default_rng(seed)
        self._config: dict | None = None
        self._mode = None
        self._held = None  # the completed request picamera2 keeps (_max_queue_len = 1)
        self._next = None
        self._lock = threading.Lock()

    # --- configuration ------------------------------------------------------------------------
    @property
    def sensor_modes(self) -> list[dict]:
        return [{"format": "SRGGB10_CSI2P", "bit_depth": 10, "size": (m.width, m.height),
                 "fps": round(1 / m.min_frame_duration_s, 2), "crop_limits": self._crop_limits(m)} for m in self.modes.values()]

    @staticmethod
    def _crop_limits(m) -> tuple[int, int, int, int]:
        return (m.crop_left, m.crop_top, m.width * m.binning, m.height * m.binning)

    @property
    def camera_properties(self) -> dict:
        return {"Model": "imx219", "PixelArraySize": (3296, 2480), "PixelArrayActiveAreas": [(8, 8, *ACTIVE_ARRAY)]}

    def create_video_configuration(self, main=None, sensor=None, controls=None, buffer_count=6, colour_space=None):
        return {"main": dict(main or {}), "sensor": dict(sensor or {}), "controls": dict(controls or {}),
                "buffer_count": buffer_count, "queue": True, "raw": {}, "colour_space": colour_space or "Rec709"}

    def configure(self, config: dict) -> None:
        size = tuple(config["sensor"].get("output_size", (1640, 1232)))
        # libcamera picks the closest mode the sensor has; here: that size, else the largest
        mode = next((m for m in self.modes.values() if (m.width, m.height) == size),
                    max(self.modes.values(), key=lambda m: m.width * m.height))
        self._mode, self._config = mode, config
        self.controls = dict(config["controls"])
        w, h = config["main"]["size"]
        self.stride = -(-w // 64) * 64

    def camera_configuration(self) -> dict:
        return {**self._config, "sensor": {"output_size": (self._mode.width, self._mode.height), "bit_depth": 10},
                "main": {**self._config["main"], "stride": self.stride}}

    @property
    def camera_controls(self) -> dict:
        m = self._mode
        shortest_us = int(round(m.min_frame_duration_s * 1e6))
        crop = self._crop_limits(m)
        return {"FrameDurationLimits": (shortest_us, int(m.max_frame_duration_s * 1e6), 33333),
                "ScalerCrop": ((0, 0, 64, 64), crop, crop), "ExposureTime": (1, 66666, 20000)}

    def set_controls(self, controls: dict) -> None:
        self.controls.update(controls)

    # --- streaming ----------------------------------------------------------------------------
    def start(self) -> None:
        if self._mode is None:
            raise RuntimeError("Camera has not been configured")
        d = self.controls.get("FrameDurationLimits", (self.timing.frame_duration_s * 1e6,) * 2)[0] * 1e-6
        e = self.controls.get("ExposureTime", self.timing.exposure_s * 1e6) * 1e-6
        timing = replace(self.timing, frame_duration_s=d, exposure_s=e, drop_probability=0.0, timestamp_jitter_s=0.0,
                         line_time_s=self._mode.line_time_s, active_rows=self._mode.height,
                         vblank_min_lines=IMX219_VBLANK_MIN_LINES, start_time_s=self.clock.now_ns() * 1e-9 + 0.03)
        self._sensor = CameraClock(timing, self._rng)
        self._next = self._sensor.next_frame()
        self._held = None
        self.started = True

    def stop(self) -> None:
        self.started = False
        if hasattr(self.clock, "limit_ns"):
            self.clock.limit_ns = None

    def close(self) -> None:
        self.closed = True

    def _crop(self) -> tuple[int, int, int, int]:
        return tuple(self.controls.get("ScalerCrop", self._crop_limits(self._mode)))

    def _first_row(self) -> int:
        return (self._crop()[1] - self._mode.crop_top) // self._mode.binning

    def _done_ns(self, ft) -> int:
        """When frame ``ft`` is complete: the whole mode read out, then the ISP."""
        frame_start = ft.true_start_s * 1e9
        return int(frame_start + self._mode.height * ft.line_time_s * 1e9) + self.isp_ns

    def _complete_until(self, now_ns: int) -> None:
        """Frames the sensor finished by ``now_ns``: each replaces the one held (picamera2's queue of one)."""
        while self._done_ns(self._next) <= now_ns:
            if self._held is not None:
                self.stats.dropped += 1
            self._held = self._next
            self.stats.frames += 1
            self._next = self._sensor.next_frame()

    def capture_request(self, wait=None):
        self.jobs += 1
        return object()  # a job: picamera2's Job; wait() does the work

    def wait(self, job, timeout=None):
        with self._lock:
            if not self.started:
                raise RuntimeError("Camera is not running")
            self._complete_until(self.clock.now_ns())
            if self._held is None:
                if not self.clock.wait_until(self._done_ns(self._next), 5.0 if timeout is None else timeout):
                    raise TimeoutError("fake picamera2: no frame in time")
                self._complete_until(self.clock.now_ns())
            ft, self._held = self._held, None
            self.stats.delivered += 1
            if hasattr(self.clock, "limit_ns"):
                self.clock.limit_ns = self._done_ns(ft) + int(self.hold_frames * ft.frame_duration_s * 1e9)
            return self._request(ft)

    def _request(self, ft) -> FakeCompletedRequest:
        # CameraClock's T is the start of the readout of the sensor mode's first row here
        lt_ns = ft.line_time_s * 1e9
        frame_start = int(round(ft.true_start_s * 1e9))
        row0 = frame_start + int(round(self._first_row() * lt_ns))
        exposure_us = ft.exposure_s * 1e6
        w, h = self._config["main"]["size"]
        y = self.render(ft.sequence, frame_start, row0, exposure_us, lt_ns)
        if y.shape != (h, w):
            raise AssertionError(f"render gave {y.shape}, the stream is {w}x{h}")
        yuv = np.full((h * 3 // 2, self.stride), 128, dtype=np.uint8)  # chroma: grey
        yuv[:h, :w] = y
        yuv[:h, w:] = 0xEE  # stride padding: not luminance
        stamp = (frame_start + self.latency_ns) // 1000 * 1000  # the V4L2 timeval's microseconds
        meta = {"SensorTimestamp": stamp, "ExposureTime": int(round(exposure_us)),
                "FrameDuration": int(round(ft.frame_duration_s * 1e6)), "ScalerCrop": self._crop(),
                "AnalogueGain": float(self.controls.get("AnalogueGain", 1.0))}
        request = FakeCompletedRequest(self, yuv, meta, ft.sequence)
        self.requests.append(request)
        return request


def _tuning(gamma: list[int]) -> dict:
    return {"version": 2.0, "target": "bcm2835", "algorithms": [
        {"rpi.black_level": {"black_level": 4096}}, {"rpi.sdn": {}},
        {"rpi.contrast": {"ce_enable": 1, "gamma_curve": gamma}},
        {"rpi.sharpen": {"threshold": 0.75, "limit": 0.5, "strength": 1.0}}]}


TUNING_FILES = {"imx219_noir.json": _tuning([0, 0, 32768, 54876, 65535, 65535]),
                "imx219.json": _tuning([0, 0, 32768, 54876, 65535, 65535])}


def fake_modules(*, tuning_files: dict = TUNING_FILES, **kwargs) -> tuple[dict[str, types.ModuleType], list[FakePicamera2]]:
    """``picamera2`` (whose ``Picamera2(n, tuning=None)`` is a FakePicamera2 with ``kwargs``) and the
    ``libcamera`` names it is used with; the list collects the instances made."""
    made: list[FakePicamera2] = []

    def factory(camera_num: int = 0, tuning: dict | None = None) -> FakePicamera2:
        cam = FakePicamera2(camera_num, tuning, **kwargs)
        made.append(cam)
        return cam

    def load_tuning_file(name: str, dir=None) -> dict:
        if name not in tuning_files:
            raise RuntimeError("Tuning file not found")
        return json.loads(json.dumps(tuning_files[name]))

    def find_tuning_algo(tuning: dict, name: str) -> dict:
        if tuning.get("version", 1) == 1:
            return tuning[name]
        return next(algo for algo in tuning["algorithms"] if name in algo)[name]

    factory.load_tuning_file = load_tuning_file
    factory.find_tuning_algo = find_tuning_algo

    def global_camera_info() -> list[dict]:  # picamera2.py: Model, Location, Rotation, Id, Num per camera
        return [{"Model": "imx219", "Location": 2, "Rotation": 180, "Id": "/base/soc/i2c0mux/i2c@1/imx219@10", "Num": 0}]

    factory.global_camera_info = global_camera_info
    module = types.ModuleType("picamera2")
    module.__file__ = "/usr/lib/python3/dist-packages/picamera2/__init__.py"
    module.Picamera2 = factory
    module.MappedArray = MappedArray
    libcamera = types.ModuleType("libcamera")
    libcamera.ColorSpace = types.SimpleNamespace(Sycc=lambda: "Sycc", Rec709=lambda: "Rec709")
    return {"picamera2": module, "libcamera": libcamera}, made


def install_fake(monkeypatch, **kwargs) -> list[FakePicamera2]:
    """Put the fake ``picamera2`` and ``libcamera`` in sys.modules for one test (``fake_modules``)."""
    modules, made = fake_modules(**kwargs)
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, name, module)
    return made


