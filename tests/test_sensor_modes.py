"""The IMX219 sensor-mode table (device/camera/modes.py) against the driver's formulas and what
libcamera reports for the same driver, and the configured image as a crop of a mode."""

import pytest

from device.camera.modes import (
    IMX219_ARRAY_HEIGHT, IMX219_ARRAY_WIDTH, IMX219_LINE_LENGTH_PIXELS, IMX219_PIXEL_RATE_HZ, IMX219_VBLANK_MIN_LINES,
    MODE5, SENSOR_MODES, ImageWindow, SensorMode, sensor_mode_named,
)
from device.config import load_preset

#: ``libcamera-hello --list-cameras`` on this driver (raspberrypi/linux issue #5438): per mode the
#: maximum frame rate and the crop (left, top)/width x height in active-array pixels.
LIBCAMERA = {
    "640x480": (206.65, (1000, 752, 1280, 960)),
    "1640x1232": (41.85, (0, 0, 3280, 2464)),
    "1920x1080": (47.57, (680, 692, 1920, 1080)),
    "3280x2464": (21.19, (0, 0, 3280, 2464)),
}


def test_the_table_has_the_drivers_four_modes():
    assert set(SENSOR_MODES) == set(LIBCAMERA)
    for name, mode in SENSOR_MODES.items():
        assert mode.name == name and sensor_mode_named(name) is mode


@pytest.mark.parametrize("name", sorted(SENSOR_MODES))
def test_line_time_is_line_length_over_pixel_rate(name):
    m = SENSOR_MODES[name]
    assert m.pixel_rate_hz == IMX219_PIXEL_RATE_HZ * m.rate_factor
    exact_ns = 1e9 * IMX219_LINE_LENGTH_PIXELS / m.pixel_rate_hz
    assert m.line_time_ns == round(exact_ns) and abs(m.line_time_ns - exact_ns) <= 0.5
    assert m.line_time_s == m.line_time_ns / 1e9


@pytest.mark.parametrize("name", sorted(SENSOR_MODES))
def test_frame_time_is_at_least_height_plus_vblank_min_lines(name):
    m = SENSOR_MODES[name]
    line_s = IMX219_LINE_LENGTH_PIXELS / m.pixel_rate_hz
    assert m.min_frame_lines == m.height + IMX219_VBLANK_MIN_LINES
    assert m.min_frame_duration_s == pytest.approx((m.height + IMX219_VBLANK_MIN_LINES) * line_s, rel=1e-15)
    assert m.min_frame_duration_s >= (m.height + IMX219_VBLANK_MIN_LINES) * line_s * (1 - 1e-15)
    assert m.max_frame_rate_hz == pytest.approx(1 / m.min_frame_duration_s, rel=1e-15)
    assert m.max_frame_duration_s == pytest.approx(0xFFFF * line_s)
    # libcamera lists 1 / (the shortest frame in whole microseconds)
    assert m.max_frame_rate_hz == pytest.approx(LIBCAMERA[name][0], abs=0.01)


@pytest.mark.parametrize("name", sorted(SENSOR_MODES))
def test_crop_is_where_libcamera_reports_it(name):
    m = SENSOR_MODES[name]
    crop = (m.crop_left, m.crop_top, m.width * m.binning, m.height * m.binning)
    assert crop == LIBCAMERA[name][1]
    assert crop[0] + crop[2] <= IMX219_ARRAY_WIDTH and crop[1] + crop[3] <= IMX219_ARRAY_HEIGHT


def test_the_binned_mode_is_the_whole_array_and_the_defaults_are_30_and_15_fps():
    binned = SENSOR_MODES["1640x1232"]
    assert (binned.binning, binned.crop_left, binned.crop_top) == (2, 0, 0)
    assert (binned.width * 2, binned.height * 2) == (IMX219_ARRAY_WIDTH, IMX219_ARRAY_HEIGHT)
    for name, fps in (("3280x2464", 15.0), ("1920x1080", 30.0), ("1640x1232", 30.0)):
        m = SENSOR_MODES[name]
        assert 1 / (m.vts_default * IMX219_LINE_LENGTH_PIXELS / m.pixel_rate_hz) == pytest.approx(fps, rel=2e-3)


def test_mode5_is_the_binned_modes_centre_and_table_b3s_line_time():
    assert MODE5.mode is SENSOR_MODES["1640x1232"]
    assert (MODE5.width, MODE5.height) == (1640, 922) and MODE5.top == (1232 - 922) // 2 == 155
    assert MODE5.scaler_crop == (0, 310, 3280, 1844)  # picamera2's ScalerCrop, full-resolution pixels
    assert MODE5.mode.line_time_ns == 18904.0 and MODE5.mode.line_time_s == 18904e-9  # thesis Table B.3
    assert MODE5.mode.max_frame_rate_hz > 40.0  # 20 scans/s (40 frames/s) fit; 21 would not
    assert MODE5.mode.max_frame_rate_hz < 42.0


@pytest.mark.parametrize("preset", ["thesis-calibrated", "thesis-design"])
def test_the_presets_image_is_mode5(preset):
    cfg = load_preset(preset)
    assert cfg.window == MODE5
    assert (cfg.width, cfg.height) == (1664, 928)  # the frame buffer around it (docs/thesis-notes.md N6)


def test_the_simulated_camera_and_the_pi_camera_use_the_table():
    from device.camera.picamera2_camera import Picamera2Camera
    from device.sim.timing import CameraTimingConfig

    timing = CameraTimingConfig()
    assert timing.line_time_s == MODE5.mode.line_time_s and timing.active_rows == MODE5.height
    assert timing.vblank_min_lines == IMX219_VBLANK_MIN_LINES
    cam = Picamera2Camera()
    assert cam.line_time_ns == MODE5.mode.line_time_ns
    wide = ImageWindow(SENSOR_MODES["1920x1080"], 0, 0, 1600, 900)
    assert Picamera2Camera(window=wide).line_time_ns == SENSOR_MODES["1920x1080"].line_time_ns


def test_crops_that_do_not_fit_and_unknown_modes_are_refused():
    with pytest.raises(ValueError, match="does not fit the 1640x1232"):
        ImageWindow(SENSOR_MODES["1640x1232"], 0, 311, 1640, 922)
    with pytest.raises(ValueError, match="does not fit"):
        ImageWindow(SENSOR_MODES["1640x1232"], 1, 0, 1640, 922)
    with pytest.raises(ValueError, match="leaves the 3280x2464 array"):
        SensorMode(1920, 1080, 1, 1400, 0, vts_default=1763)
    with pytest.raises(ValueError, match="sensor mode must be one of"):
        sensor_mode_named("1640x922")
