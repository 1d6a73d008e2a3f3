"""Recorded frames: the recording format and a camera that plays it back.

A recording is either one ``.npz`` file (``images`` (N, H, W) uint8 and per-frame arrays
``seq``, ``sensor_timestamp_ns``, ``exposure_us``, ``frame_duration_us``, ``line_time_ns``,
``lit`` (1 lit, 0 dark, -1 unknown), ``readout_offset_rows`` (absent in older recordings:
0)) or a folder with one PNG per frame and
``frames.json`` (``{"frames": [{"file": ..., "seq": ..., ..., "lit": true/false/null or 1/0/-1}, ...]}``), so
that frames recorded on a Pi can be reprocessed anywhere.

A recording may come from elsewhere (another renderer, another camera stack), so its metadata is
checked whole when opened (:func:`check_frames`, and an .npz's images): what no camera could have
produced is refused, naming the frame and the field, before a frame is processed. A folder's
PNGs are read, and checked, frame by frame.
"""

from __future__ import annotations

import json
import logging
import zipfile
import zlib
from pathlib import Path
from typing import Sequence

import numpy as np

from .base import EndOfRecording
from .frame import Frame

log = logging.getLogger(__name__)
FIELDS = ("seq", "sensor_timestamp_ns", "exposure_us", "frame_duration_us", "line_time_ns")
#: field: its value in recordings made before it existed (or elsewhere), and what taking it means
OPTIONAL_FIELDS = {"readout_offset_rows": (0, "image row 0 is taken as the sensor's first row read: where the frames "
                                              "are a crop of the sensor's rows, every row's time is early by the rows "
                                              "above the crop")}
INDEX_FILE = "frames.json"
#: what reading a damaged or foreign .npz raises (numpy and zipfile, not ours): its wrong CRC,
#: header or deflate stream, an unknown compression method or zip version, an encrypted member;
#: ValueError: numpy's refusal of an array of Python objects, a .npy's header
NPZ_READ_ERRORS = (OSError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError, RuntimeError, ValueError)
#: ``lit`` as recorded -> Frame.lit (JSON's true/false/null are 1/0/-1)
LIT_CODES = {1: True, 0: False, -1: None}
#: per-frame fields that count (frames, nanoseconds, rows): whole numbers
WHOLE_FIELDS = ("seq", "sensor_timestamp_ns", "readout_offset_rows")
#: per-frame durations: finite and positive
DURATION_FIELDS = ("exposure_us", "frame_duration_us", "line_time_ns")


def _lit_code(lit: bool | None) -> int:
    return -1 if lit is None else int(bool(lit))


def save_npz(path: str | Path, **arrays: np.ndarray) -> None:
    """Write ``arrays`` to the .npz ``path`` whole or not at all: into a temporary file beside it,
    then renamed over it (a full disk or a killed process leaves no truncated file)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp.npz")
    try:
        np.savez_compressed(tmp, **arrays)
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


def save_recording(path: str | Path, frames: Sequence[Frame]) -> None:
    """Write frames as ``.npz`` (path ends in .npz) or as a folder of PNGs with frames.json."""
    path = Path(path)
    if not frames:
        raise ValueError("no frames to record")
    shapes = {f.image.shape for f in frames}
    if len(shapes) != 1:
        raise ValueError(f"all frames of a recording must have one size, got {sorted(shapes)}")
    if path.suffix == ".npz":
        arrays = {k: np.array([getattr(f, k) for f in frames]) for k in (*FIELDS, *OPTIONAL_FIELDS)}
        arrays["lit"] = np.array([_lit_code(f.lit) for f in frames], dtype=np.int8)
        save_npz(path, images=np.stack([f.image for f in frames]), **arrays)
        return
    import cv2

    path.mkdir(parents=True, exist_ok=True)
    index = []
    for f in frames:
        name = f"frame_{f.seq:06d}.png"
        if not cv2.imwrite(str(path / name), f.image):
            raise OSError(f"could not write {path / name}")
        index.append({"file": name, **{k: getattr(f, k) for k in (*FIELDS, *OPTIONAL_FIELDS)}, "lit": f.lit})
    (path / INDEX_FILE).write_text(json.dumps({"frames": index}, indent=1))


class NpzUnreadable(ValueError):
    """A file numpy cannot read as an archive of arrays; its message is numpy's or zipfile's."""


def read_npz(path, keys: Sequence[str]) -> dict[str, np.ndarray]:
    """The arrays ``keys`` that the .npz at ``path`` holds (the others absent), read whole; a file
    that is no such archive (a .npy, a damaged or foreign file) raises :class:`NpzUnreadable`."""
    try:
        loaded = np.load(path)
        if not isinstance(loaded, np.lib.npyio.NpzFile):  # a .npy's one array
            raise ValueError(f"one {type(loaded).__name__}, not an archive of arrays")
        with loaded as z:
            return {k: z[k] for k in keys if k in z.files}
    except NPZ_READ_ERRORS as exc:
        raise NpzUnreadable(str(exc)) from None


def check_frames(where: str, fields: dict[str, np.ndarray], height: int) -> None:
    """Refuse per-frame metadata no camera produces (ValueError naming the first frame and field
    at fault). ``fields``: every field of FIELDS and OPTIONAL_FIELDS and ``lit`` (its codes,
    LIT_CODES), each an (N,) array in the recording's order; ``height``: the image's rows.

    What a camera's frames satisfy (device/camera/frame.py says where each comes from):
    - ``seq`` increases frame by frame: it counts the sensor's frames (picamera2_camera.py:
      Unicam's buffer sequence), so a dropped frame is a gap, and the recording is in time order;
    - ``sensor_timestamp_ns`` (the frame start, CLOCK_MONOTONIC ns) advances by the frame
      period times the frames the seq advanced, within half a frame: a frame starts the earlier
      frame's length after it (libcamera's FrameDuration is frameLength x lineLength,
      raspberrypi/libcamera src/ipa/rpi/common/ipa_base.cpp ``reportMetadata``), so the period of
      either frame is taken (a recording may label a frame with the length before it);
    - exposure shorter than the frame: the IMX219 exposes at most the frame length less 4 lines
      (device/camera/modes.py: imx219.c, exposure_max = height + vblank - 4);
    - the image's rows read within the frame: (readout_offset_rows + height) line times at most
      the frame's length (its rows are a crop of the mode's, and the frame is at least the
      mode's rows plus vertical blanking: modes.py).
    """
    def fail(k: int, what: str) -> None:
        raise ValueError(f"{where}: frame {k} (seq {fields['seq'][k].item()!r}): {what}")

    for name, v in fields.items():  # real numbers (a lit flag may be a bool)
        if not (np.issubdtype(v.dtype, np.integer) or np.issubdtype(v.dtype, np.floating)
                or (name == "lit" and v.dtype == bool)):
            raise ValueError(f"{where}: {name} must be numbers, got {v.dtype}")
    for name in WHOLE_FIELDS:
        v = fields[name]
        # below 2**63: the frames' int64 (a larger uint64 would wrap negative; 2**63 ns are 292 years)
        bad = ~(np.isfinite(v) & (v == np.round(v)) & (v >= 0) & (v < 2.0**63))
        if bad.any():
            fail(int(np.argmax(bad)), f"{name} is {v[np.argmax(bad)].item()!r}: a count must be a whole number >= 0 "
                                      "and below 2**63")
    for name in DURATION_FIELDS:
        v = fields[name]
        bad = ~(np.isfinite(v) & (v > 0))
        if bad.any():
            fail(int(np.argmax(bad)), f"{name} is {v[np.argmax(bad)].item()!r}: a duration must be finite and positive")
    bad = ~np.isin(fields["lit"], list(LIT_CODES))
    if bad.any():
        fail(int(np.argmax(bad)), f"lit is {fields['lit'][np.argmax(bad)].item()!r}: 1 (lit), 0 (dark) or -1 (unknown)")
    seq, t = fields["seq"].astype(np.int64), fields["sensor_timestamp_ns"].astype(np.int64)
    frame_ns = fields["frame_duration_us"] * 1e3
    bad = fields["exposure_us"] * 1e3 >= frame_ns
    if bad.any():
        k = int(np.argmax(bad))
        fail(k, f"exposure_us {fields['exposure_us'][k]:g} is not shorter than its frame, frame_duration_us "
                f"{fields['frame_duration_us'][k]:g}")
    readout_ns = (fields["readout_offset_rows"] + height) * fields["line_time_ns"]
    bad = readout_ns > frame_ns
    if bad.any():
        k = int(np.argmax(bad))
        fail(k, f"its {height} rows (read from row {int(fields['readout_offset_rows'][k])} of the sensor, "
                f"line_time_ns {fields['line_time_ns'][k]:g}) take {readout_ns[k] / 1e6:.3f} ms to read, longer "
                f"than the frame, frame_duration_us {fields['frame_duration_us'][k]:g}")
    if seq.size < 2:
        return
    dseq, dt = np.diff(seq), np.diff(t)
    bad = dseq <= 0
    if bad.any():
        k = int(np.argmax(bad)) + 1
        fail(k, f"seq does not increase from {seq[k - 1]} before it: a recording holds frames in time order, seq "
                "counting the sensor's frames")
    expected = dseq * frame_ns[:-1]
    tol = np.minimum(frame_ns[:-1], frame_ns[1:]) / 2
    bad = (np.abs(dt - expected) > tol) & (np.abs(dt - dseq * frame_ns[1:]) > tol)
    if bad.any():
        k = int(np.argmax(bad)) + 1
        fail(k, f"it starts {dt[k - 1] / 1e6:.3f} ms after the frame before (sensor_timestamp_ns), where seq and "
                f"frame_duration_us say {expected[k - 1] / 1e6:.3f} ms ({int(dseq[k - 1])} frame(s) later): timestamps are "
                "CLOCK_MONOTONIC ns, durations us, and seq counts the sensor's frames (a dropped frame is a gap)")


class ReplayCamera:
    """Plays a recording back frame by frame; frame timing is what was recorded.

    ``set_frame_duration``/``set_exposure`` cannot change recorded frames: they are logged and
    ignored. ``capture`` raises EndOfRecording after the last frame (or starts over if ``loop``).
    ``assumed``: the optional fields the recording lacks -> (the value taken, what that means).
    """

    def __init__(self, path: str | Path, loop: bool = False):
        self.path = Path(path)
        self.loop = loop
        if self.path.suffix == ".npz":
            self._images, fields = self._open_npz()
            self._files = None
        else:
            self._images = None
            self._files, fields = self._open_folder()
        if not fields["seq"].size:
            raise ValueError(f"{self.path}: the recording has no frames")
        self.assumed = {k: v for k, v in OPTIONAL_FIELDS.items() if k not in fields}
        for k, (value, meaning) in self.assumed.items():
            fields[k] = np.full(fields["seq"].size, value)
            log.info("%s: no %s recorded, taken as %s: %s", self.path, k, value, meaning)
        shape = self._images.shape[1:] if self._images is not None else self._read_png(0).shape
        self.height, self.width = int(shape[0]), int(shape[1])
        check_frames(str(self.path), fields, self.height)
        self._fields = fields
        self.line_time_ns = float(fields["line_time_ns"][0])
        self._i = 0

    def _open_npz(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        if not self.path.is_file():
            raise FileNotFoundError(f"{self.path}: no such recording")
        if not zipfile.is_zipfile(self.path):
            raise ValueError(f"{self.path}: not an .npz recording (not a zip archive of arrays)")
        try:
            fields = read_npz(self.path, ("images", *FIELDS, "lit", *OPTIONAL_FIELDS))
        except NpzUnreadable as exc:
            pickled = "allow_pickle" in str(exc)  # numpy refuses an array of Python objects so
            raise ValueError(f"{self.path}: " + ("an array holds Python objects, not numbers" if pickled else
                                                 "not a readable .npz recording") + f" ({exc})") from None
        missing = [k for k in ("images", "lit", *FIELDS) if k not in fields]
        if missing:
            raise ValueError(f"{self.path}: not a recording, missing array(s) {', '.join(missing)}")
        images = fields.pop("images")
        if images.ndim != 3 or images.dtype != np.uint8:
            raise ValueError(f"{self.path}: images must be (frames, height, width) uint8 luminance (the Y plane), got "
                             f"{images.shape} {images.dtype}" + ("; colour frames: convert them to luminance first"
                                                                 if images.ndim == 4 else ""))
        for k, v in fields.items():
            if v.shape != images.shape[:1]:
                raise ValueError(f"{self.path}: {k} has shape {v.shape}, one value per frame of the {images.shape[0]} "
                                 "images expected")
        return images, fields

    def _open_folder(self) -> tuple[list[str], dict[str, np.ndarray]]:
        index = self.path / INDEX_FILE
        if not index.is_file():
            raise FileNotFoundError(f"{self.path}: no {INDEX_FILE}; not a recording folder")
        try:
            frames = json.loads(index.read_text())["frames"]
            if not isinstance(frames, list):
                raise TypeError(f"'frames' is a {type(frames).__name__}, not a list")
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{index}: not a frame index ({exc})") from None
        required = ("file", *FIELDS, "lit")
        for k, f in enumerate(frames):
            missing = [n for n in required if not isinstance(f, dict) or n not in f]
            if missing:
                raise ValueError(f"{index}: frame {k} has no {', '.join(missing)}")
            if not (f["lit"] is None or isinstance(f["lit"], int)):  # JSON's true/false are ints here too
                raise ValueError(f"{index}: frame {k}: lit is {f['lit']!r}: true, false or null (or 1, 0, -1)")
        present = []
        for k in OPTIONAL_FIELDS:  # every frame has it, or none (a mix would drop the recorded values)
            without = [i for i, f in enumerate(frames) if k not in f]
            if without and len(without) < len(frames):
                raise ValueError(f"{index}: frame {without[0]} has no {k}, other frames have one")
            present += [] if without else [k]
        try:
            fields = {n: np.array([f[n] for f in frames]) for n in (*FIELDS, *present)}  # JSON's ints stay int64
        except ValueError as exc:
            raise ValueError(f"{index}: a per-frame value is not a number ({exc})") from None
        fields["lit"] = np.array([-1 if f["lit"] is None else int(f["lit"]) for f in frames])
        return [str(f["file"]) for f in frames], fields

    def __len__(self) -> int:
        return self._fields["seq"].size

    def _read_png(self, i: int) -> np.ndarray:
        import cv2

        name = self.path / self._files[i]
        if not name.is_file():
            raise FileNotFoundError(f"{name}: no such frame image ({INDEX_FILE} lists it)")
        img = cv2.imread(str(name), cv2.IMREAD_UNCHANGED)
        if img is None or img.ndim != 2 or img.dtype != np.uint8:
            raise ValueError(f"{name}: not an 8-bit single-channel PNG")
        return img

    def start(self) -> None:
        self._i = 0

    def stop(self) -> None:
        pass

    def set_frame_duration(self, frame_duration_us: float) -> None:
        log.debug("replay: frame duration request %s us ignored (recorded timing)", frame_duration_us)

    def set_exposure(self, exposure_us: float) -> None:
        log.debug("replay: exposure request %s us ignored (recorded timing)", exposure_us)

    def capture(self, timeout_s: float = 1.0) -> Frame:
        if self._i >= len(self):
            if not self.loop:
                raise EndOfRecording(f"{self.path}: end of recording after {len(self)} frames")
            self._i = 0
        i = self._i
        self._i += 1
        image = self._images[i] if self._images is not None else self._read_png(i)
        if image.shape != (self.height, self.width):
            raise ValueError(f"{self.path / self._files[i]}: {image.shape[1]}x{image.shape[0]}, the recording's first "
                             f"frame {self.width}x{self.height}")
        v = {k: a[i] for k, a in self._fields.items()}
        return Frame(image=np.ascontiguousarray(image), seq=int(v["seq"]), sensor_timestamp_ns=int(v["sensor_timestamp_ns"]),
                     exposure_us=float(v["exposure_us"]), frame_duration_us=float(v["frame_duration_us"]),
                     line_time_ns=float(v["line_time_ns"]), lit=LIT_CODES[int(v["lit"])],
                     readout_offset_rows=int(v["readout_offset_rows"]))
