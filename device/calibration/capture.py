"""Capturing a calibration set from a camera backend (live on the Pi, or a recording replayed).

The laser fires on a pattern of frames (docs/thesis-notes.md N10); consecutive lit and unlit frames form a pair.
A pair becomes a pose when the board is found in the unlit frame, it has not moved since the
previous pair (a still board: no motion blur, and lit and unlit show the same pose) and it is
somewhere new (mean corner shift from every pose kept so far). Coverage of the frame by corners
so far is shown as a small grid with a progress bar.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..camera.base import Camera, CameraError, EndOfRecording
from ..camera.frame import Frame
from .intrinsics import CalibrationError, detect_corners
from .pipeline import Pose

log = logging.getLogger(__name__)

#: A board is still when its corners moved less than this between two pairs (pixels).
STILL_PX = 1.5
#: A new pose must differ from every kept one by this mean corner shift (pixels).
NEW_POSE_PX = 40.0


@dataclass(frozen=True)
class Progress:
    kept: int
    wanted: int
    coverage: np.ndarray  # (rows, cols) corner counts per image cell
    message: str


def lit_flag(frame: Frame, lit_parity: int | None) -> bool:
    """Whether a frame is lit: its own flag, else by sequence parity (laser on every other frame)."""
    if frame.lit is not None:
        return frame.lit
    if lit_parity is None:
        raise CalibrationError(
            f"frame {frame.seq} does not say whether the laser was on; give the lit-frame parity (--lit-frames even|odd)"
        )
    return frame.seq % 2 == lit_parity


def coverage_grid(corner_sets: list[np.ndarray], width: int, height: int, cols: int = 6, rows: int = 4) -> np.ndarray:
    grid = np.zeros((rows, cols), int)
    for c in corner_sets:
        ix = np.clip((c[:, 0] * cols / width).astype(int), 0, cols - 1)
        iy = np.clip((c[:, 1] * rows / height).astype(int), 0, rows - 1)
        np.add.at(grid, (iy, ix), 1)
    return grid


def render_progress(p: Progress) -> str:
    """A progress bar and the coverage grid ('#' covered, '+' some corners, '.' none)."""
    bar = "#" * p.kept + "." * max(p.wanted - p.kept, 0)
    cells = ["".join("#" if v >= 20 else "+" if v > 0 else "." for v in row) for row in p.coverage]
    return f"[{bar}] {p.kept}/{p.wanted}  {p.message}\n" + "\n".join(f"  |{r}|" for r in cells)


def capture_poses(
    camera: Camera, count: int, pattern_size: tuple[int, int], lit_parity: int | None = None,
    on_progress: Callable[[Progress], None] | None = None, max_frames: int = 100000,
    on_pose: Callable[[Pose], None] | None = None,
) -> list[Pose]:
    """Read frames until ``count`` poses are kept (or the camera/recording ends). ``on_pose`` is
    called with each pose as it is kept (to save it at once: a camera error later loses nothing)."""
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    kept: list[Pose] = []
    kept_corners: list[np.ndarray] = []
    last_corners = None
    pending: Frame | None = None
    camera.start()
    try:
        for _ in range(max_frames):
            if len(kept) >= count:
                break
            try:
                frame = camera.capture()
            except EndOfRecording:
                break
            if pending is None or lit_flag(pending, lit_parity) == lit_flag(frame, lit_parity):
                pending = frame
                continue
            lit, unlit = (pending, frame) if lit_flag(pending, lit_parity) else (frame, pending)
            pending = None
            det = detect_corners(unlit.image, pattern_size, f"seq_{unlit.seq}")
            if det.corners is None:
                last_corners, message = None, f"no board: {det.reason}"
            else:
                still = last_corners is not None and float(np.mean(np.linalg.norm(det.corners - last_corners, axis=1))) < STILL_PX
                new = all(float(np.mean(np.linalg.norm(det.corners - c, axis=1))) > NEW_POSE_PX for c in kept_corners)
                last_corners = det.corners
                if still and new:
                    kept.append(Pose(f"pose_{len(kept):03d}", lit.image, unlit.image))
                    kept_corners.append(det.corners)
                    if on_pose:
                        on_pose(kept[-1])
                    message = f"kept pose {len(kept)}; move the board somewhere new"
                else:
                    message = "hold the board still" if not still else "pose already captured: move the board"
            if on_progress:
                on_progress(Progress(len(kept), count, coverage_grid(kept_corners, camera.width, camera.height), message))
    finally:
        camera.stop()
    return kept


def run_capture(args, spec) -> int:
    """`laserpi calibrate capture DIR`: the CLI side (camera construction, printing, saving)."""
    import importlib
    import sys

    from .pipeline import save_capture_dir

    module_name, _, cls_name = args.camera.partition(":")
    try:
        cls = getattr(importlib.import_module(module_name), cls_name)
    except (ImportError, AttributeError) as exc:
        print(f"cannot load camera backend {args.camera!r}: {exc}", file=sys.stderr)
        return 2
    camera = cls()
    parity = None if args.lit_frames == "flag" else (0 if args.lit_frames == "even" else 1)

    def show(p: Progress) -> None:
        print("\033[2J\033[H" + render_progress(p) if sys.stdout.isatty() else render_progress(p), flush=True)

    try:
        poses = capture_poses(camera, args.count, spec.pattern_size, parity, show, on_pose=lambda p: save_capture_dir([p], args.dir))
    except CameraError as exc:
        print(f"camera: {exc} (poses kept so far are in {args.dir})", file=sys.stderr)
        return 1
    print(f"{len(poses)} poses written to {args.dir}; now run: laserpi calibrate run {args.dir} --out sensor.toml")
    return 0 if len(poses) >= args.count else 1
