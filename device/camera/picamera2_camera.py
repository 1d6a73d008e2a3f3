"""Camera backend for a Raspberry Pi: picamera2 (libcamera), imported only when started.

Configuration (thesis B.1.4, Table B.3, mode 5; ``window`` = device/camera/modes.py MODE5): the
sensor runs its 2x2-binned 1640x1232 mode and the ISP crops the centre 3280x1844 sensor pixels
(``ScalerCrop``, 310 rows off the top and bottom at full resolution) to a 1640x922 YUV420
``main`` stream; only the luminance (Y) plane is used. Auto exposure and auto white balance are
off; exposure time and analogue gain are fixed; the frame rate is set with
``FrameDurationLimits`` (min = max).

Timing, from what libcamera reports rather than from the mode table (device/camera/modes.py
``readout_geometry``): the line time from the configured mode's shortest frame
(``camera_controls["FrameDurationLimits"]``) and the rows read before image row 0 from each
request's ``ScalerCrop`` against the mode's crop (``camera_controls["ScalerCrop"]`` maximum).
Each frame's ``SensorTimestamp`` is the frame start of the whole readout (device/camera/frame.py
cites the kernel and libcamera sources), so image row r is read at SensorTimestamp +
(crop rows + r) x line time. The frame's sequence number is the raw (Unicam) buffer's
``FrameMetadata.sequence``, which counts sensor frames: a frame picamera2 dropped because this
process lagged is a gap, not a restart (libcamera framebuffer.cpp: "Gaps in the sequence numbers
indicate dropped frames").

What the pipeline sees (``isp="linear"``, the default): the Y plane linear in the light and
full range, as the simulator renders it (device/sim/sensor.py), not what the ISP does by
default (gamma-encoded, contrast-enhanced, sharpened, denoised, limited range 16-235; the
simulator models that too, ``SensorParams.isp = "default"``, and BENCHMARKS.md "ISP" says what it
costs the pipeline). This uses the ISP rather than the raw stream: the ISP still subtracts the
black level, corrects lens shading and bins nothing away, at no CPU cost, where unpacking and
cropping the 10-bit raw Bayer mode on the Pi's CPU would cost it milliseconds per frame. How:

* the sensor's own tuning file (``imx219_noir.json`` for the NoIR module, else ``imx219.json``,
  read with ``Picamera2.load_tuning_file``) with ``rpi.contrast``'s gamma curve made the identity
  and its contrast enhancement (``ce_enable``) off, and ``rpi.sharpen``'s strength 0, handed to
  ``Picamera2(camera_num, tuning=...)`` (picamera2.py ``__init__``: a dict is written to a
  temporary file for ``LIBCAMERA_RPI_TUNING_FILE``) -- see :func:`linear_tuning`;
* the controls ``NoiseReductionMode`` Off (libcamera control_ids_draft.yaml: "No noise reduction
  is applied") and ``Sharpness`` 0.0 (control_ids_core.yaml: "A value of 0.0 means no
  sharpening");
* the colour space ``Sycc``, whose range is full (libcamera color_space.cpp:
  ``ColorSpace::Sycc = {Rec709, Srgb, Rec601, Range::Full}``), instead of the limited-range
  Rec709 picamera2 picks for video of this size.

The Y plane is placed at the top left of a zeroed buffer of the configured size (1664x928 for
the thesis configuration, docs/thesis-notes.md N6), so that frames from a Pi and from the simulator have one
layout. It is copied straight out of the request's buffer, mapped for reading
(picamera2 request.py ``MappedArray(request, "main", write=False)``: the YUV420 buffer as a
``(height * 3 // 2, stride)`` array that shares its memory, after a read sync of the dma-buf),
before the request is released and its buffer goes back to the camera. ``make_array`` would
first copy the whole buffer, chroma and padding included (request.py ``make_array``:
``make_buffer``, "np.array(b, dtype=np.uint8)"), 2.3 MB a frame of which 1.5 MB is needed: on a
Pi Zero 2 W's memory a copy of that size costs milliseconds a frame (not measured here).
"""

from __future__ import annotations

import copy
import importlib
import inspect
import logging

import numpy as np

from .base import CameraError, CaptureTimeout
from .frame import Frame
from .modes import MODE5, ImageWindow, ReadoutGeometry, readout_geometry

log = logging.getLogger(__name__)

#: What to install when the camera stack does not import (Raspberry Pi OS bookworm: picamera2 and
#: libcamera's Python bindings are apt packages, not on PyPI; a venv sees them only when made with
#: --system-site-packages).
CAMERA_STACK_FIX = ("sudo apt install -y python3-picamera2 (libcamera's Python bindings are not on PyPI), and make "
                    "the venv with: python3 -m venv --system-site-packages")


#: What the linear ISP sets in the sensor's tuning (see the module docstring).
LINEAR_GAMMA = [0, 0, 65535, 65535]


def linear_tuning(tuning: dict, find_algo) -> dict:
    """A copy of a Raspberry Pi camera tuning whose Y output is linear: identity gamma curve,
    no contrast enhancement, no sharpening. ``find_algo(tuning, name)`` is picamera2's
    ``Picamera2.find_tuning_algo`` (tuning files of version 1 and 2). KeyError/StopIteration
    when the tuning has no ``rpi.contrast`` (nothing could be made linear)."""
    out = copy.deepcopy(tuning)
    contrast = find_algo(out, "rpi.contrast")
    contrast["ce_enable"] = 0
    contrast["gamma_curve"] = list(LINEAR_GAMMA)
    try:
        find_algo(out, "rpi.sharpen")["strength"] = 0.0
    except (KeyError, StopIteration):
        pass  # no sharpening stage in this tuning
    return out


def camera_stack_problem() -> str | None:
    """Why picamera2 (and the libcamera it imports) cannot be used here, with the fix; None if it can."""
    try:
        picamera2 = importlib.import_module("picamera2")
    except Exception as exc:  # ImportError, or a binding built against another numpy/libcamera
        return f"picamera2 does not import ({type(exc).__name__}: {exc}); {CAMERA_STACK_FIX}"
    # capture maps the buffer for reading only: MappedArray's ``write`` argument came with
    # picamera2 0.3.13 (raspberrypi/picamera2 commit 0ffa131, "Add DmaHeap to allocate frame
    # buffers"; request.py before it: ``MappedArray(request, stream, reshape=True)``), which the
    # first bookworm images may predate
    if "write" not in inspect.signature(picamera2.MappedArray).parameters:
        return (f"picamera2 is older than 0.3.13 (its MappedArray takes no write argument): sudo apt update, "
                f"then {CAMERA_STACK_FIX}")
    return None


class Picamera2Camera:
    """Fixed-exposure luminance frames from picamera2 (see the module docstring)."""

    def __init__(self, width: int = 1664, height: int = 928, exposure_us: float = 40000.0,
                 frame_duration_us: float = 50000.0, analogue_gain: float = 1.0, camera_num: int = 0,
                 window: ImageWindow = MODE5, buffer_count: int = 6, isp: str = "linear"):
        """``window``: the sensor mode and the crop of it that the stream delivers (SensorConfig.window);
        ``isp``: "linear" (the module docstring) or "default" (the ISP as picamera2 sets it up)."""
        if isp not in ("linear", "default"):
            raise ValueError(f"isp must be 'linear' or 'default', got {isp!r}")
        self.isp = isp
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
        self._window = window
        self._cam = None
        self._pending = None  # capture job still outstanding after a timeout
        self._mapped_array = None  # picamera2.MappedArray, once started
        self._mode_crop: tuple[int, int, int, int] | None = None  # the configured mode's crop_limits
        self._shortest_frame_us = 0.0
        self.readout: ReadoutGeometry | None = None  # from the last frame's metadata

    def _controls(self) -> dict:
        d = int(round(self._frame_duration_us))
        controls = {
            "AeEnable": False,
            "AwbEnable": False,
            "ExposureTime": int(round(self._exposure_us)),
            "AnalogueGain": float(self._gain),
            "FrameDurationLimits": (d, d),
            "ScalerCrop": self._crop,
        }
        if self.isp == "linear":
            controls.update(NoiseReductionMode=0, Sharpness=0.0)  # 0: NoiseReductionModeOff
        return controls

    def _open(self, picamera2):
        """Picamera2 for this camera, with the linear tuning if ``isp`` is "linear"."""
        if self.isp == "default":
            return picamera2.Picamera2(self._camera_num), {}
        cls = picamera2.Picamera2
        model = cls.global_camera_info()[self._camera_num].get("Model", "imx219")
        for name in (f"{model}_noir.json", f"{model}.json"):
            try:
                tuning = cls.load_tuning_file(name)
                break
            except RuntimeError:
                continue
        else:
            raise CameraError(f"no tuning file {model}_noir.json or {model}.json for the linear ISP (python3-libcamera "
                              "installs them); or run with isp='default'")
        libcamera = importlib.import_module("libcamera")
        log.info("ISP: %s with a linear gamma, no contrast enhancement, sharpening or noise reduction, full range", name)
        return cls(self._camera_num, tuning=linear_tuning(tuning, cls.find_tuning_algo)), {
            "colour_space": libcamera.ColorSpace.Sycc()}

    def start(self) -> None:
        if self._cam is not None:
            return
        try:
            picamera2 = importlib.import_module("picamera2")
        except ImportError as exc:
            raise CameraError(f"picamera2 is not installed ({exc}); {CAMERA_STACK_FIX}") from None
        self._mapped_array = picamera2.MappedArray  # picamera2/__init__.py: from .request import ..., MappedArray
        cam, extra = self._open(picamera2)
        try:
            config = cam.create_video_configuration(
                main={"size": self._output, "format": "YUV420"},
                sensor={"output_size": self._sensor, "bit_depth": 10},
                controls=self._controls(),
                buffer_count=self._buffer_count,
                **extra,
            )
            cam.configure(config)
            self._read_mode(cam)
            cam.set_controls(self._controls())
            cam.start()
        except Exception:
            cam.close()
            raise
        self._cam = cam
        log.info("picamera2 started: %s YUV420 from sensor %s, crop %s, line time %.1f ns, image row 0 is mode row %d",
                 self._output, self._sensor, self._crop, self.line_time_ns, self.readout.first_row)

    def _read_mode(self, cam) -> None:
        """The configured sensor mode as libcamera reports it: refuse another mode than the
        configuration's; take the line time and crop from it (module docstring)."""
        got = tuple(cam.camera_configuration()["sensor"]["output_size"])
        if got != self._sensor:
            raise CameraError(f"the camera runs sensor mode {got[0]}x{got[1]}, not the configured "
                              f"{self._window.mode.name} ([image] sensor_mode)")
        controls = cam.camera_controls
        self._mode_crop = tuple(controls["ScalerCrop"][1])
        self._shortest_frame_us = float(controls["FrameDurationLimits"][0])
        self.readout = readout_geometry(self._sensor, self._mode_crop, self._shortest_frame_us, self._crop)
        table = self._window.mode.line_time_ns
        if abs(self.readout.line_time_ns - table) > 1e-3 * table:
            log.warning("line time %.1f ns from libcamera differs from the %s mode table's %.1f ns; using libcamera's",
                        self.readout.line_time_ns, self._window.mode.name, table)
        self.line_time_ns = self.readout.line_time_ns

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
        w, h = self._output
        try:
            # no view of the mapped array may outlive the block: an allocator whose sync closes
            # its mmap on exit refuses while one exists (BufferError), hiding any error here
            with self._mapped_array(request, "main", write=False) as mapped:  # the module docstring
                shape = mapped.array.shape
                fits = len(shape) == 2 and shape[0] >= h * 3 // 2 and shape[1] >= w
                if fits:
                    image = np.zeros((self.height, self.width), dtype=np.uint8)
                    image[:h, :w] = mapped.array[:h, :w]  # the Y plane; U and V follow below it
            if not fits:
                raise CameraError(f"unexpected YUV420 buffer shape {shape} for a {w}x{h} stream")
            meta = request.get_metadata()
            # the raw stream's buffer is Unicam's: its sequence counts the sensor's frames
            seq = int(request.request.buffers[request.stream_map["raw"]].metadata.sequence)
        finally:
            request.release()
        try:
            ts = int(meta["SensorTimestamp"])
        except KeyError:
            raise CameraError("request metadata has no SensorTimestamp") from None
        self.readout = readout_geometry(self._sensor, self._mode_crop, self._shortest_frame_us,
                                        tuple(meta.get("ScalerCrop", self._crop)))
        return Frame(image=image, seq=seq, sensor_timestamp_ns=ts,
                     exposure_us=float(meta.get("ExposureTime", self._exposure_us)),
                     frame_duration_us=float(meta.get("FrameDuration", self._frame_duration_us)),
                     line_time_ns=self.readout.line_time_ns, lit=None, readout_offset_rows=self.readout.first_row)
