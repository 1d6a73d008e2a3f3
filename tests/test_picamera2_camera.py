"""The Pi camera backend (device/camera/picamera2_camera.py) against a fake picamera2 that behaves
as the real one (tests/fake_picamera2.py: drops when the consumer lags, SensorTimestamp at the
start of the whole readout, YUV420 with stride padding), and the device process with its
synchronisation running on it."""

import sys
import time

import numpy as np
import pytest

from device.camera.base import CameraError, CaptureTimeout
from device.camera.modes import MODE5, SENSOR_MODES, readout_geometry
from device.camera.picamera2_camera import Picamera2Camera, camera_stack_problem
from device.sim.timing import CameraTimingConfig
from tests.fake_picamera2 import ManualClock, install_fake

TIMING = CameraTimingConfig(frame_duration_s=0.05, exposure_s=0.04)
LINE_NS = 1e9 * 3448 / 182.4e6  # imx219.c: IMX219_PPL_MIN / IMX219_PIXEL_RATE


def gradient(seq, frame_start_ns, row0_ns, exposure_us, line_ns):
    return np.broadcast_to((np.arange(1640) % 200 + 20).astype(np.uint8), (922, 1640)).copy()


def install(monkeypatch, **kw):
    kw.setdefault("clock", ManualClock())
    kw.setdefault("render", gradient)
    kw.setdefault("timing", TIMING)
    return install_fake(monkeypatch, **kw)


def test_readout_geometry_is_the_crop_and_the_shortest_frame_over_its_lines():
    # what libcamera reports for the binned mode (41.85 fps: 23894 us shortest frame) and mode 5's crop
    g = readout_geometry((1640, 1232), (0, 0, 3280, 2464), 23894, MODE5.scaler_crop)
    assert g.first_row == 155 == MODE5.top
    assert g.line_time_ns == pytest.approx(LINE_NS, abs=0.5)  # 1264 lines; the table rounds to 18904
    wide = SENSOR_MODES["1920x1080"]
    assert readout_geometry((1920, 1080), (680, 692, 1920, 1080), 21022, (680, 792, 1920, 880)).first_row == 100
    assert wide.binning == 1
    with pytest.raises(ValueError, match="not inside"):
        readout_geometry((1640, 1232), (0, 0, 3280, 2464), 23894, (0, 2000, 3280, 1844))
    with pytest.raises(ValueError, match="bin evenly"):
        readout_geometry((1640, 1231), (0, 0, 3280, 2464), 23894, MODE5.scaler_crop)


def test_configures_mode5_fixed_exposure(monkeypatch):
    made = install(monkeypatch)
    cam = Picamera2Camera(exposure_us=30000, frame_duration_us=50000, analogue_gain=4.0)
    cam.start()
    (pc,) = made
    assert pc.camera_num == 0
    assert pc._config["main"] == {"size": (1640, 922), "format": "YUV420"}
    assert pc._config["sensor"] == {"output_size": (1640, 1232), "bit_depth": 10}
    controls = pc.controls
    assert controls["AeEnable"] is False and controls["AwbEnable"] is False
    assert controls["ExposureTime"] == 30000 and controls["AnalogueGain"] == 4.0
    assert controls["FrameDurationLimits"] == (50000, 50000) and controls["ScalerCrop"] == MODE5.scaler_crop
    assert pc.started
    cam.set_frame_duration(40000)
    assert pc.controls["FrameDurationLimits"] == (40000, 40000)
    cam.set_exposure(20000)
    assert pc.controls["ExposureTime"] == 20000
    cam.stop()
    assert not pc.started and pc.closed
    with pytest.raises(ValueError):
        Picamera2Camera(exposure_us=60000, frame_duration_us=50000)


def test_capture_takes_the_luminance_plane_and_the_timing_libcamera_reports(monkeypatch):
    made = install(monkeypatch)
    cam = Picamera2Camera()
    cam.start()
    f = cam.capture(timeout_s=0.5)
    pc = made[0]
    assert pc.stride == 1664 and pc.stride > 1640  # Y stride padded to 64 bytes (picamera2 align_stream, VC4)
    assert f.image.shape == (928, 1664)
    assert np.array_equal(f.image[:922, :1640], gradient(0, 0, 0, 0, 0))
    assert not f.image[922:].any() and not f.image[:, 1640:].any()  # chroma and stride padding are not luminance
    # line time and crop from libcamera's report, not the table
    assert f.line_time_ns == pytest.approx(LINE_NS, abs=0.5) and cam.line_time_ns == f.line_time_ns
    assert f.readout_offset_rows == 155
    assert f.sensor_timestamp_ns % 1000 == 0  # a V4L2 timeval: microseconds
    assert (f.exposure_us, f.frame_duration_us, f.lit) == (pytest.approx(40000, abs=19), pytest.approx(50000, abs=19), None)
    # image row 0 is read 155 line times after the frame start the timestamp marks
    _, end0 = f.row_exposure_ns(0)
    # (to the whole microsecond libcamera gives the shortest frame in, spread over its 1264 lines)
    assert end0 - f.sensor_timestamp_ns == pytest.approx(155 * LINE_NS, abs=155 * 500 / 1264)
    g = cam.capture()
    assert g.seq == f.seq + 1


def test_the_luminance_is_copied_out_of_the_buffer_mapped_for_reading_before_its_release(monkeypatch):
    # once released the buffer is the camera's again and a later frame is written into it (the
    # fake overwrites it at once): the frame must hold its own copy, taken from the buffer mapped
    # for reading only (a read sync of the dma-buf), the chroma and padding left behind
    made = install(monkeypatch)
    cam = Picamera2Camera()
    cam.start()
    f = cam.capture(timeout_s=0.5)
    (request,) = made[0].requests
    assert request.released and not (request._yuv != 0x55).any()
    assert np.array_equal(f.image[:922, :1640], gradient(0, 0, 0, 0, 0))
    assert [m.write for m in request.mappings] == [False]
    with pytest.raises(AttributeError):  # the mapping ended with the block
        request.mappings[0].array  # noqa: B018


def test_a_lagging_consumer_sees_a_sequence_gap_not_a_restart(monkeypatch):
    clock = ManualClock()
    made = install(monkeypatch, clock=clock)
    cam = Picamera2Camera()
    cam.start()
    a = cam.capture()
    clock.advance(int(3.5 * 50e6))  # the consumer is away for 3.5 frames: three complete, one is kept
    b = cam.capture()
    c = cam.capture()
    assert (b.seq - a.seq, c.seq - b.seq) == (3, 1)
    assert made[0].stats.dropped == 2
    # the kept frame is handed out at once, older than the clock: its timestamp says when it was taken
    assert b.sensor_timestamp_ns - a.sensor_timestamp_ns == pytest.approx(3 * 50e6, abs=2 * LINE_NS)


def test_a_timeout_keeps_the_job_and_other_modes_are_refused(monkeypatch):
    clock = ManualClock(auto=False)
    made = install(monkeypatch, clock=clock)
    cam = Picamera2Camera()
    with pytest.raises(CameraError, match="not started"):
        cam.capture()
    cam.start()
    with pytest.raises(CaptureTimeout):
        cam.capture(0.01)
    clock.advance(10**9)
    assert cam.capture().seq >= 0
    assert made[0].jobs == 1  # the timed-out job was waited on again, not leaked
    cam.stop()
    only_full = {"3280x2464": SENSOR_MODES["3280x2464"]}
    install(monkeypatch, modes=only_full)
    with pytest.raises(CameraError, match="runs sensor mode 3280x2464, not the configured 1640x1232"):
        Picamera2Camera().start()


def test_a_broken_camera_stack_names_the_fix(monkeypatch):
    monkeypatch.setitem(sys.modules, "picamera2", None)
    problem = camera_stack_problem()
    assert problem is not None and "python3-picamera2" in problem and "--system-site-packages" in problem


def test_a_picamera2_without_read_only_mapping_names_the_fix(monkeypatch):
    # picamera2 before 0.3.13: MappedArray(request, stream, reshape=True), no ``write`` (capture
    # would raise a TypeError at every frame)
    install(monkeypatch)
    assert camera_stack_problem() is None

    class OldMappedArray:
        def __init__(self, request, stream, reshape=True):
            pass

    monkeypatch.setattr(sys.modules["picamera2"], "MappedArray", OldMappedArray)
    problem = camera_stack_problem()
    assert problem is not None and "0.3.13" in problem and "apt update" in problem


@pytest.mark.slow
def test_the_device_process_and_sync_run_on_it_through_dropped_frames(monkeypatch):
    """SensorSource + SyncedLaser (the co-MCU's firmware in the emulator) + the fast pipeline, with
    the fake picamera2 as the camera: the laser locks; when the consumer lags, frames are dropped
    (sequence gaps), counted, and every frame the controller labels is labelled as the rendered
    truth says (lit/unlit parity survives the gaps); scans range the wall."""
    from device.service.assembly import AssemblyConfig, build_sensor
    from device.sim.render import FrameTiming, RenderOptions, SceneRenderer
    from device.sim.scene import wall_scene

    built = build_sensor(AssemblyConfig(simulate=True, distance_m=1.5))
    hw = built.hardware
    cfg = built.source.camera.renderer.cfg
    op = cfg.operating_point
    # the scene once lit in every row and once dark; each frame's row r is the dark row plus the
    # line times the fraction of row r's exposure the laser was on (the rolling shutter), so a
    # frame costs next to nothing and the emulated co-MCU keeps its pace on a loaded machine
    renderer = SceneRenderer(cfg, wall_scene(1.5), options=RenderOptions(ray_samples=4096, background_step=4))
    line_ns, t = cfg.window.mode.line_time_ns, 10**9
    lit_img, _ = renderer.render(FrameTiming(t, op.exposure_us, line_ns, ((0, 2 * 10**9),)), np.random.default_rng(1))
    dark_img, _ = renderer.render(FrameTiming(t, op.exposure_us, line_ns, ()), np.random.default_rng(2))
    lit_img, dark_img = lit_img[:922, :1640].astype(np.float32), dark_img[:922, :1640].astype(np.float32)
    geometry = built.source.pipeline.pipeline.geometry
    row_lo, row_hi = int(geometry.roi_lo.min()), int(geometry.roi_hi.max())
    truth: dict[int, bool] = {}

    def render(seq, frame_start_ns, row0_ns, exposure_us, line_ns):
        ends = row0_ns + np.arange(922) * line_ns
        starts = ends - exposure_us * 1e3
        on = np.zeros(922)
        for a, b in hw.windows(int(starts[0]), int(ends[-1])):
            on += np.clip(np.minimum(ends, b) - np.maximum(starts, a), 0, None)
        frac = (on / (exposure_us * 1e3))[:, None]
        truth[seq] = bool(frac[row_lo:row_hi].any())
        return np.clip(dark_img + frac * (lit_img - dark_img), 0, 255).astype(np.uint8)

    made = install(monkeypatch, clock=hw, render=render)
    camera = Picamera2Camera(exposure_us=op.exposure_us, frame_duration_us=0.5e6 / op.scan_rate_hz, window=MODE5,
                             analogue_gain=op.analog_gain)
    labels: dict[int, bool] = {}
    laser = built.source.laser
    frame_lit = laser.frame_lit

    def labelled(frame):
        lit = frame_lit(frame)
        if lit is not None:
            labels[frame.seq] = lit
        if frame.seq % 17 == 16:
            time.sleep(0.16)  # the consumer lags: ~3 frames complete meanwhile
        return lit

    monkeypatch.setattr(laser, "frame_lit", labelled)
    source = built.source
    source.camera = camera
    source.apply(built.settings)
    source.start()
    scans = []
    try:
        deadline = time.monotonic() + 60
        while len(scans) < 25 and time.monotonic() < deadline:
            s = source.next_scan(0.5)
            if s is not None:
                scans.append(s)
    finally:
        source.stop()
        for close in built.closers:
            close()
    fake = made[0]
    assert len(scans) == 25 and laser.locked is not None
    assert fake.stats.dropped >= 2 and source.counters.frames_dropped >= 2
    assert source.counters.camera_restarts <= 1  # the first start only: a drop is no restart
    assert len(labels) >= 40
    wrong = {s: lit for s, lit in labels.items() if truth.get(s) != lit}
    assert not wrong, f"frames labelled against the truth: {wrong}"
    angles = source.geometry().angles
    depth = np.concatenate([s.ranges_m * np.cos(angles) for s in scans[-5:]])  # the wall's distance ahead
    assert np.isfinite(depth).mean() > 0.5 and np.nanmedian(depth) == pytest.approx(1.5, rel=0.02)


def test_the_linear_isp_the_pipeline_expects(monkeypatch):
    made = install(monkeypatch)
    Picamera2Camera().start()
    pc = made[0]
    contrast = next(a for a in pc.tuning["algorithms"] if "rpi.contrast" in a)["rpi.contrast"]
    sharpen = next(a for a in pc.tuning["algorithms"] if "rpi.sharpen" in a)["rpi.sharpen"]
    assert contrast == {"ce_enable": 0, "gamma_curve": [0, 0, 65535, 65535]} and sharpen["strength"] == 0.0
    assert pc._config["colour_space"] == "Sycc"  # full range
    assert pc.controls["NoiseReductionMode"] == 0 and pc.controls["Sharpness"] == 0.0
    # the ISP as picamera2 sets it up, on request
    made = install(monkeypatch)
    Picamera2Camera(isp="default").start()
    assert made[0].tuning is None and made[0]._config["colour_space"] == "Rec709"
    assert "NoiseReductionMode" not in made[0].controls
    # no tuning file to make linear: a clear error
    install(monkeypatch, tuning_files={})
    with pytest.raises(CameraError, match="no tuning file imx219_noir.json or imx219.json"):
        Picamera2Camera().start()
    with pytest.raises(ValueError, match="isp must be"):
        Picamera2Camera(isp="raw")


def test_linear_tuning_leaves_the_sensors_tuning_alone():
    from device.camera.picamera2_camera import linear_tuning
    from tests.fake_picamera2 import TUNING_FILES

    def find(t, name):
        return next(a for a in t["algorithms"] if name in a)[name]

    original = TUNING_FILES["imx219_noir.json"]
    out = linear_tuning(original, find)
    assert find(original, "rpi.contrast")["ce_enable"] == 1 and find(original, "rpi.sharpen")["strength"] == 1.0
    assert find(out, "rpi.contrast")["gamma_curve"] == [0, 0, 65535, 65535]
    assert find(out, "rpi.black_level") == {"black_level": 4096}  # the rest as it was
    no_sharpen = {"algorithms": [a for a in original["algorithms"] if "rpi.sharpen" not in a]}
    assert find(linear_tuning(no_sharpen, find), "rpi.contrast")["ce_enable"] == 0
