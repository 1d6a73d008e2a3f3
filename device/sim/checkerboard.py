"""Checkerboard calibration frames with ground truth (thesis section 4.2: camera and laser plane
from the same frames).

Each pose gives an *unlit* and a *lit* frame. Rendering is per pixel through the project's camera
model: every pixel's ray (backward projection with :func:`undistort_robust`, so lens distortion
is exact) is intersected with the board plane, giving board coordinates; the checker pattern is
then box-filtered over the pixel's footprint analytically (the integral of a square wave is a
triangle wave), so edges are anti-aliased and a corner's 50 % level sits exactly on the true
corner - corner detection sees an honest image. The lit frame adds the laser: board irradiance
is a Gaussian in the distance of the board point to the laser plane (sheet thickness
``line_sigma_m``), integrated over the pixel footprint with erf, falling off as 1/range (a fan
laser) and scaled by the board's reflectance. A Gaussian optical blur (PSF) is applied to both,
then the sensor model (:func:`device.sim.sensor.sensor_frame`, IMX219 mode 5: shot and read
noise, full well, 10-bit ADC, 8-bit Y) turns expected electrons into a noisy uint8 frame.

Ground truth per pose: the board pose (board -> camera) and the true laser points (the segment
of the laser plane crossing the checker area), in camera-frame metres.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..calibration.target import BoardSpec
from ..model.camera import CameraModel, pixel_grid, project_points, undistort_robust
from ..model.triangulation import LaserPlane
from .sensor import IMX219_MODE5, SensorParams, sensor_frame
from .special import erf


@dataclass(frozen=True)
class BoardPose:
    """Board -> camera: X_cam = rotation @ X_board + translation (metres)."""

    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,)

    def to_camera(self, pts: np.ndarray) -> np.ndarray:
        return np.asarray(pts) @ self.rotation.T + self.translation

    def plane(self) -> tuple[np.ndarray, float]:
        """Board plane n . X = d in the camera frame (n = board z axis)."""
        n = self.rotation[:, 2]
        return n, float(n @ self.translation)


@dataclass(frozen=True)
class Scene:
    """Photometry of a calibration shot, in expected electrons per pixel per frame."""

    ambient_e: float = 6000.0  # a white (reflectance 1) surface in the unlit frame (~85 Y codes)
    laser_e_at_1m: float = 4500.0  # line-centre peak on a white surface 1 m from the camera
    line_sigma_m: float = 0.001  # laser sheet thickness (Gaussian sigma), thesis Table 4.4: 4 mm line
    white: float = 0.8
    black: float = 0.12  # printer toner still reflects some 808 nm light
    background: float = 0.3  # the wall behind the board
    psf_sigma_px: float = 0.6  # optical blur
    laser_on: bool = True


@dataclass(frozen=True)
class Shot:
    """One rendered pose: the frames and their ground truth."""

    unlit: np.ndarray  # (H, W) uint8
    lit: np.ndarray  # (H, W) uint8
    pose: BoardPose
    laser_points: np.ndarray  # (M, 3) true laser points on the checker area, camera frame


@functools.lru_cache(maxsize=4)
def _rays(cam: CameraModel, width: int, height: int) -> np.ndarray:
    """(H, W, 3) ray (x_n, y_n, 1) of every pixel centre; NaN where backward projection fails."""
    un = undistort_robust(pixel_grid(width, height), cam)
    xy = un.xy
    rays = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
    rays.setflags(write=False)
    return rays


def _filtered_square_wave(u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Box filter of width w (in squares) of the wave +1 on [0,1), -1 on [1,2) (period 2)."""

    def tri(x):  # integral of the square wave
        return 1.0 - np.abs(np.mod(x, 2.0) - 1.0)

    w = np.maximum(w, 1e-6)
    return (tri(u + w / 2) - tri(u - w / 2)) / w


def _filtered_box(u: np.ndarray, w: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Fraction of [u - w/2, u + w/2] inside [lo, hi]."""
    w = np.maximum(w, 1e-6)
    return np.clip((np.minimum(u + w / 2, hi) - np.maximum(u - w / 2, lo)) / w, 0.0, 1.0)


def _footprint(a: np.ndarray) -> np.ndarray:
    """Extent of a quantity over one pixel: |da/dx| + |da/dy| (central differences)."""
    gy, gx = np.gradient(a)
    return np.abs(gx) + np.abs(gy)


def board_coordinates(cam: CameraModel, width: int, height: int, pose: BoardPose, spec: BoardSpec):
    """Per pixel: board coordinates (u, v) in squares from the first inner corner, the camera-frame
    point on the board plane (H, W, 3) and whether the ray meets the board's front side."""
    rays = _rays(cam, width, height)
    n, d = pose.plane()
    denom = rays @ n
    with np.errstate(invalid="ignore", divide="ignore"):
        t = d / denom
    hit = np.isfinite(t) & (t > 0)
    t = np.where(hit, t, np.nan)
    pts = rays * t[..., None]
    local = (pts - pose.translation) @ pose.rotation  # R^T (X - t)
    return local[..., 0] / spec.square_m, local[..., 1] / spec.square_m, pts, hit


def reflectance(u: np.ndarray, v: np.ndarray, hit: np.ndarray, spec: BoardSpec, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-footprint-averaged reflectance of board, mount and background, and the fraction of
    each pixel covered by the board (checker area and mount)."""
    uu, vv = np.where(hit, u, 0.0), np.where(hit, v, 0.0)
    wu, wv = _footprint(uu), _footprint(vv)
    # square (i, j) with i + j even (i = floor(u) + 1 counting from the board edge) is black
    checker = 0.5 + 0.5 * _filtered_square_wave(uu + 1.0, wu) * _filtered_square_wave(vv + 1.0, wv)
    inside = _filtered_box(uu, wu, -1.0, spec.squares_x - 1.0) * _filtered_box(vv, wv, -1.0, spec.squares_y - 1.0)
    m = spec.margin_squares
    mount = _filtered_box(uu, wu, -1.0 - m, spec.squares_x - 1.0 + m) * _filtered_box(vv, wv, -1.0 - m, spec.squares_y - 1.0 + m)
    pattern = scene.white + (scene.black - scene.white) * (1.0 - checker)
    board = inside * pattern + (mount - inside) * scene.white
    mount = np.where(hit, mount, 0.0)
    return np.where(hit, board + (1.0 - mount) * scene.background, scene.background), mount


def laser_irradiance(pts: np.ndarray, hit: np.ndarray, plane: LaserPlane, scene: Scene) -> np.ndarray:
    """Laser light on the board plane per pixel, electrons on a white surface (before reflectance).

    Gaussian in the point-to-plane distance (sheet thickness), averaged over the pixel's footprint
    in that distance with erf, peak falling off as 1/range from the camera (fan laser)."""
    n = np.asarray(plane.normal)
    dist = np.where(hit, pts @ n - plane.distance, np.inf)
    finite = np.where(np.isfinite(dist), dist, 1e3)
    w = np.maximum(_footprint(finite), 1e-9)
    s = scene.line_sigma_m * math.sqrt(2.0)
    mean_profile = np.maximum((erf((finite + w / 2) / s) - erf((finite - w / 2) / s)) / (2 * w) * s * math.sqrt(math.pi), 0.0)
    rng_m = np.linalg.norm(np.where(hit[..., None], pts, 1.0), axis=-1)
    return np.where(hit, scene.laser_e_at_1m * mean_profile / np.maximum(rng_m, 1e-3), 0.0)


def _blur(img: np.ndarray, sigma_px: float) -> np.ndarray:
    if sigma_px <= 0:
        return img
    import cv2

    return cv2.GaussianBlur(img, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT)


def true_laser_points(pose: BoardPose, plane: LaserPlane, spec: BoardSpec, count: int = 200) -> np.ndarray:
    """(M, 3) points of the laser plane on the checker area (camera frame), empty if none."""
    n_b, d_b = pose.plane()
    n_l = np.asarray(plane.normal)
    direction = np.cross(n_b, n_l)
    if np.linalg.norm(direction) < 1e-9:
        return np.empty((0, 3))
    # a point on both planes, nearest the board origin
    a = np.stack([n_b, n_l, direction])
    p0 = np.linalg.solve(a, np.array([d_b, plane.distance, direction @ pose.translation]))
    half = spec.square_m * (spec.squares_x + spec.squares_y)
    s = np.linspace(-half, half, 4 * count)
    line = p0 + s[:, None] * direction / np.linalg.norm(direction)
    local = (line - pose.translation) @ pose.rotation / spec.square_m
    keep = (local[:, 0] > -1) & (local[:, 0] < spec.squares_x - 1) & (local[:, 1] > -1) & (local[:, 1] < spec.squares_y - 1)
    return line[keep]


def render_shot(
    cam: CameraModel,
    width: int,
    height: int,
    plane: LaserPlane,
    pose: BoardPose,
    rng: np.random.Generator,
    spec: BoardSpec = BoardSpec(),
    scene: Scene = Scene(),
    motion_blur_px: float = 0.0,
    sensor: SensorParams = IMX219_MODE5,
) -> Shot:
    """Unlit and lit frames of one board pose. ``motion_blur_px`` adds an extra Gaussian blur
    (a shaken board or a lens out of focus) for the failure tests."""
    u, v, pts, hit = board_coordinates(cam, width, height, pose, spec)
    refl, on_board = reflectance(u, v, hit, spec, scene)
    blur = math.hypot(scene.psf_sigma_px, motion_blur_px)
    unlit_e = _blur(refl * scene.ambient_e, blur)
    # the wall behind is far and the line there is not part of the calibration: light on the board only
    laser_e = laser_irradiance(pts, hit, plane, scene) * (refl - (1.0 - on_board) * scene.background) if scene.laser_on else np.zeros_like(refl)
    lit_e = unlit_e + _blur(laser_e, blur)
    return Shot(sensor_frame(unlit_e, rng, sensor), sensor_frame(lit_e, rng, sensor), pose, true_laser_points(pose, plane, spec))


# ---------------------------------------------------------------- poses
def _rodrigues_xyz(rx: float, ry: float, rz: float) -> np.ndarray:
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
    rot_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    rot_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rot_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rot_z @ rot_y @ rot_x


def _facing(direction: np.ndarray) -> np.ndarray:
    """Rotation whose z axis is ``direction`` and whose x axis stays horizontal (camera x-z plane)."""
    z = direction / np.linalg.norm(direction)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def pose_at(center_cam: np.ndarray, tilt_x: float, tilt_y: float, roll: float, spec: BoardSpec, face_camera: bool = True) -> BoardPose:
    """Board whose checker-area centre is at ``center_cam``, facing the camera (its normal along the
    line of sight, as a person holds it; else along the optical axis), then tilted about its x and
    y axes and rolled in its plane (radians)."""
    center_cam = np.asarray(center_cam, float)
    rot = (_facing(center_cam) if face_camera else np.eye(3)) @ _rodrigues_xyz(tilt_x, tilt_y, roll)
    centre_local = np.array([(spec.squares_x - 2) / 2, (spec.squares_y - 2) / 2, 0.0]) * spec.square_m
    return BoardPose(rot, center_cam - rot @ centre_local)


def _in_view(cam: CameraModel, width: int, height: int, pose: BoardPose, spec: BoardSpec, margin_px: float) -> bool:
    px = project_points(pose.to_camera(spec.outline(spec.margin_squares)), cam)
    return bool(
        np.all(np.isfinite(px))
        and np.all(px[:, 0] > margin_px)
        and np.all(px[:, 0] < width - 1 - margin_px)
        and np.all(px[:, 1] > margin_px)
        and np.all(px[:, 1] < height - 1 - margin_px)
    )


def _crosses_laser(pose: BoardPose, plane: LaserPlane, spec: BoardSpec) -> bool:
    pts = true_laser_points(pose, plane, spec)
    return len(pts) > 1 and np.linalg.norm(pts[-1] - pts[0]) > 0.5 * spec.square_m * (spec.squares_x - 2)


#: 3x3 image cells (row-major), frame corners first: they constrain the distortion most.
_CELL_ORDER = (0, 2, 6, 8, 1, 7, 3, 5, 4)


def generate_poses(
    cam: CameraModel,
    width: int,
    height: int,
    plane: LaserPlane,
    count: int,
    seed: int,
    spec: BoardSpec = BoardSpec(),
    depth_range: tuple[float, float] = (0.3, 1.2),
    laser_fraction: float = 0.6,
    max_tilt_rad: float = math.radians(35.0),
    margin_px: float = 8.0,
    max_view_angle_rad: float = math.radians(50.0),
    face_camera: bool = True,
) -> list[BoardPose]:
    """``count`` board poses fully in view, deterministic by ``seed``.

    Depths are stratified over ``depth_range``; image positions over a 3x3 grid of the frame
    (corners first); tilts
    uniform within +-``max_tilt_rad``, and the board is seen at most ``max_view_angle_rad`` off
    its normal (a wide-angle lens sees boards at the frame edge obliquely even untilted). A ``laser_fraction`` of the poses are placed so that the
    laser line crosses the checker area (the rest serve the intrinsics, e.g. the lower image).
    ``face_camera``: boards face the camera before tilting (else the optical axis: with no tilt,
    every board is then fronto-parallel, the all-at-one-depth failure set).
    """
    rng = np.random.default_rng(seed)
    depths = depth_range[0] + (rng.permutation(count) + rng.random(count)) / count * (depth_range[1] - depth_range[0])
    n_laser = int(round(laser_fraction * count))
    poses: list[BoardPose] = []
    k = cam.intrinsics
    for i in range(count):
        want_laser = i < n_laser
        for _ in range(2000):
            z = depths[i] if _ < 200 else rng.uniform(*depth_range)
            tilt = rng.uniform(-max_tilt_rad, max_tilt_rad, 2)
            roll = rng.uniform(-0.25, 0.25)
            if want_laser:
                # centre on the laser plane at depth z, then slide the board down so it is in view
                x = rng.uniform(-0.9, 0.9) * z
                nx, ny, nz = plane.normal
                y_plane = (plane.distance - nx * x - nz * z) / ny
                y = y_plane + rng.uniform(0.0, 0.45) * spec.square_m * (spec.squares_y - 2)
            else:
                cell = _CELL_ORDER[(i - n_laser) % 9]  # fixed per pose, so a hard cell (a frame corner) is not given up
                gx, gy = (cell % 3 - 1) * 0.7 + rng.uniform(-0.2, 0.2), (cell // 3 - 1) * 0.7 + rng.uniform(-0.2, 0.2)
                x = (gx * (width / 2) / k.fx) * z
                y = (gy * (height / 2) / k.fy) * z
            pose = pose_at(np.array([x, y, z]), tilt[0], tilt[1], roll, spec, face_camera)
            centre = pose.to_camera(spec.outline().mean(axis=0))
            if pose.rotation[:, 2] @ centre / np.linalg.norm(centre) < math.cos(max_view_angle_rad):
                continue  # seen too obliquely (or from behind)
            if not _in_view(cam, width, height, pose, spec, margin_px):
                continue
            if want_laser and not _crosses_laser(pose, plane, spec):
                continue
            poses.append(pose)
            break
        else:
            raise RuntimeError(f"could not place pose {i} in view (depth {depths[i]:.2f} m); widen the depth range")
    return poses


def render_wall(cam: CameraModel, width: int, height: int, plane: LaserPlane, distance_m: float, rng: np.random.Generator,
                scene: Scene = Scene(black=0.8, white=0.8)) -> Shot:
    """A flat white wall ``distance_m`` ahead, perpendicular to the scan's forward axis
    (device.model.scan_frame), lit and unlit: the frames of a post-calibration sweep (thesis 6.3)."""
    from ..model.scan_frame import scan_frame

    fr = scan_frame(plane)
    forward = fr.rotation[0]
    spec = BoardSpec(squares_x=12, squares_y=8, square_m=max(distance_m, 0.5), margin_squares=0.0)  # a wall wider than the view
    rot = _facing(forward)
    centre = fr.origin + distance_m * forward
    pose = BoardPose(rot, centre - rot @ (np.array([(spec.squares_x - 2) / 2, (spec.squares_y - 2) / 2, 0.0]) * spec.square_m))
    return render_shot(cam, width, height, plane, pose, rng, spec, scene)
