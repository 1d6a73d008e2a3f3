"""Recorded frames: the recording format and a camera that plays it back.

A recording is either one ``.npz`` file (``images`` (N, H, W) uint8 and per-frame arrays
``seq``, ``sensor_timestamp_ns``, ``exposure_us``, ``frame_duration_us``, ``line_time_ns``,
``lit`` (int8: 1 lit, 0 dark, -1 unknown), ``readout_offset_rows`` (absent in older recordings:
0)) or a folder with one PNG per frame and
``frames.json`` (``{"frames": [{"file": ..., "seq": ..., ...}, ...]}``), so that frames recorded
on a Pi can be reprocessed anywhere.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Sequence

import numpy as np

from .base import EndOfRecording
from .frame import Frame

log = logging.getLogger(__name__)
FIELDS = ("seq", "sensor_timestamp_ns", "exposure_us", "frame_duration_us", "line_time_ns")
OPTIONAL_FIELDS = {"readout_offset_rows": 0}  # field: its value in recordings made before it existed
INDEX_FILE = "frames.json"


def _lit_code(lit: bool | None) -> int:
    return -1 if lit is None else int(bool(lit))


def _lit_value(code: int) -> bool | None:
    return None if code < 0 else bool(code)


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
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(tmp, images=np.stack([f.image for f in frames]), **arrays)
        tmp.replace(path)
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


class ReplayCamera:
    """Plays a recording back frame by frame; frame timing is what was recorded.

    ``set_frame_duration``/``set_exposure`` cannot change recorded frames: they are logged and
    ignored. ``capture`` raises EndOfRecording after the last frame (or starts over if ``loop``).
    """

    def __init__(self, path: str | Path, loop: bool = False):
        self.path = Path(path)
        self.loop = loop
        if self.path.suffix == ".npz":
            if not self.path.is_file():
                raise FileNotFoundError(f"{self.path}: no such recording")
            with np.load(self.path) as z:
                missing = [k for k in ("images", "lit", *FIELDS) if k not in z.files]
                if missing:
                    raise ValueError(f"{self.path}: not a recording, missing array(s) {', '.join(missing)}")
                self._images = z["images"]
                keys = FIELDS + ("lit",) + tuple(k for k in OPTIONAL_FIELDS if k in z.files)
                self._meta = [dict(zip(keys, vals)) for vals in zip(*(z[k].tolist() for k in keys))]
            for m in self._meta:
                m["lit"] = _lit_value(m["lit"])
        else:
            index = self.path / INDEX_FILE
            if not index.is_file():
                raise FileNotFoundError(f"{self.path}: no {INDEX_FILE}; not a recording folder")
            try:
                self._meta = json.loads(index.read_text())["frames"]
            except (ValueError, KeyError) as exc:
                raise ValueError(f"{index}: not a frame index ({exc})") from None
            self._images = None
        if not self._meta:
            raise ValueError(f"{self.path}: the recording has no frames")
        shape = self._images.shape[1:] if self._images is not None else self._read_png(0).shape
        self.height, self.width = int(shape[0]), int(shape[1])
        self.line_time_ns = float(self._meta[0]["line_time_ns"])
        self._i = 0

    def __len__(self) -> int:
        return len(self._meta)

    def _read_png(self, i: int) -> np.ndarray:
        import cv2

        name = self.path / self._meta[i]["file"]
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
        if self._i >= len(self._meta):
            if not self.loop:
                raise EndOfRecording(f"{self.path}: end of recording after {len(self._meta)} frames")
            self._i = 0
        i = self._i
        self._i += 1
        m = self._meta[i]
        image = self._images[i] if self._images is not None else self._read_png(i)
        return Frame(image=np.ascontiguousarray(image), seq=int(m["seq"]), sensor_timestamp_ns=int(m["sensor_timestamp_ns"]),
                     exposure_us=float(m["exposure_us"]), frame_duration_us=float(m["frame_duration_us"]),
                     line_time_ns=float(m["line_time_ns"]), lit=m["lit"],
                     readout_offset_rows=int(m.get("readout_offset_rows", OPTIONAL_FIELDS["readout_offset_rows"])))
