import sys

import numpy as np
import pytest

from device.camera.base import Camera, CameraError, CaptureTimeout, EndOfRecording
from device.camera.frame import Frame
from device.camera.picamera2_camera import Picamera2Camera
from device.camera.replay import ReplayCamera, save_recording
from device.config import load_preset
from device.sim.camera import SimulatedCamera
from device.sim.pulses import NoPulses, PulseTrain, frame_aligned_train
from device.sim.render import RenderOptions
from device.sim.scene import wall_scene
from device.sim.timing import CameraTimingConfig, quantise_frame_duration

CFG = load_preset("thesis-calibrated")
LINE_NS = CFG.window.mode.line_time_ns
FAST = RenderOptions(ray_samples=4096, background_step=4)


EXACT = CameraTimingConfig(frame_duration_s=0.05, exposure_s=0.04, timestamp_jitter_s=0.0, drop_probability=0.0)
FRAME_NS = quantise_frame_duration(0.05, 0.04, EXACT) * LINE_NS  # whole lines
#: SensorTimestamp is the frame start of the whole mode's readout: image row 0 is read the ISP
#: crop's rows (155 in mode 5) later
CROP_NS = CFG.window.top * LINE_NS


def sim_camera(pulses=None, timing=EXACT, **kw):
    train = pulses or frame_aligned_train(10**9, FRAME_NS / 1e3, 40000.0, LINE_NS, CFG.height, 17400.0, every=2)
    return SimulatedCamera(CFG, wall_scene(1.5), train, timing=timing, options=FAST, **kw)


def test_simulated_camera_lights_frames_from_the_pulse_timing():
    cam = sim_camera()
    assert isinstance(cam, Camera)
    with pytest.raises(CameraError, match="start"):
        cam.capture()
    cam.start()
    out = [cam.capture_with_truth() for _ in range(4)]
    lit = [f.lit for f, _ in out]
    assert lit == [True, False, True, False]
    assert [f.seq for f, _ in out] == [0, 1, 2, 3]
    assert CFG.window.top == 155 and all(f.readout_offset_rows == 155 for f, _ in out)
    assert [f.sensor_timestamp_ns + CROP_NS for f, _ in out] == [round(10**9 + k * FRAME_NS) for k in range(4)]
    assert [f.row_exposure_ns(0)[1] for f, _ in out] == [round(10**9 + k * FRAME_NS) for k in range(4)]
    (f0, t0), (f1, t1) = out[0], out[1]
    assert t0.lit_rows.all() and not t1.lit_rows.any()  # 17.4 ms pulse inside the all-rows window
    cols = np.nonzero(np.isfinite(t0.row))[0]
    rows = np.round(t0.row[cols]).astype(int)
    diff = f0.image.astype(int) - f1.image.astype(int)
    assert np.median(diff[rows, cols]) > 10  # the laser line is where the truth says
    # a new frame duration applies two frames after the last one seen (IMX219 control delay)
    cam.set_frame_duration(60000.0)  # seen: frame 3; frame 4 keeps 50 ms, frame 5 has 60 ms
    ts = [out[-1][0].sensor_timestamp_ns] + [cam.capture().sensor_timestamp_ns for _ in range(3)]
    assert np.diff(ts).tolist() == pytest.approx([FRAME_NS, 60e6, 60e6], abs=LINE_NS)
    with pytest.raises(ValueError):
        cam.set_frame_duration(-1.0)


def test_simulated_camera_skips_dropped_frames_and_reports_jittered_timestamps():
    timing = CameraTimingConfig(frame_duration_s=0.05, exposure_s=0.04, timestamp_jitter_s=20e-6, drop_probability=0.5)
    cam = sim_camera(timing=timing, seed=1)
    cam.start()
    frames = [cam.capture_with_truth() for _ in range(10)]
    seqs = [f.seq for f, _ in frames]
    assert seqs == sorted(seqs) and seqs[-1] > 9  # some sequence numbers were dropped
    for f, t in frames:
        k = round((f.sensor_timestamp_ns + CROP_NS - 10**9) / FRAME_NS)
        assert k == f.seq
        late = f.sensor_timestamp_ns + CROP_NS - (10**9 + k * FRAME_NS)
        assert 0 <= late < 1e6  # interrupt latency: never early
        assert f.lit == (k % 2 == 0)  # the pulse train lights even frames, dropped or not


def test_simulated_camera_is_dark_without_pulses_and_partial_when_the_pulse_is_short():
    cam = sim_camera(NoPulses())
    cam.start()
    f, t = cam.capture_with_truth()
    assert f.lit is False and not t.lit_rows.any()
    # a late 2 ms pulse (10 ms after T) lights only the rows still exposing then
    short = sim_camera(PulseTrain(10**9 + 10_000_000, 10**9, 2_000_000))
    exposure_ns = round(0.04 / (LINE_NS / 1e9)) * LINE_NS  # line-quantised
    short.start()
    f, t = short.capture_with_truth()
    lit = np.nonzero(t.lit_rows)[0]
    assert f.lit and 0 < lit.size < CFG.height
    # rows r with T - E + r t_line < on + width and T + r t_line > on
    r = np.arange(CFG.height)
    start = 10**9 - exposure_ns + r * LINE_NS
    end = 10**9 + r * LINE_NS
    expected = np.nonzero((start < 10**9 + 12_000_000) & (end > 10**9 + 10_000_000))[0]
    assert expected[0] > 500
    assert np.array_equal(lit, expected)


@pytest.mark.parametrize("kind", ["npz", "folder"])
def test_replay_round_trip(tmp_path, kind):
    rng = np.random.default_rng(0)
    frames = [Frame(rng.integers(0, 256, (30, 40), dtype=np.uint8), k, 10**9 + k * 5000, 400.0, 5000.0, LINE_NS,
                    [True, False, None][k % 3], readout_offset_rows=k) for k in range(5)]
    path = tmp_path / ("rec.npz" if kind == "npz" else "rec")
    save_recording(path, frames)
    cam = ReplayCamera(path)
    assert isinstance(cam, Camera) and len(cam) == 5 and (cam.width, cam.height) == (40, 30)
    cam.start()
    for f in frames:
        g = cam.capture()
        assert np.array_equal(f.image, g.image)
        assert (g.seq, g.sensor_timestamp_ns, g.exposure_us, g.frame_duration_us, g.line_time_ns, g.lit,
                g.readout_offset_rows) == (f.seq, f.sensor_timestamp_ns, f.exposure_us, f.frame_duration_us,
                                           f.line_time_ns, f.lit, f.readout_offset_rows)
    with pytest.raises(EndOfRecording):
        cam.capture()
    looped = ReplayCamera(path, loop=True)
    assert [looped.capture().seq for _ in range(7)] == [0, 1, 2, 3, 4, 0, 1]


def test_replay_bad_input(tmp_path):
    with pytest.raises(FileNotFoundError):
        ReplayCamera(tmp_path / "none.npz")
    with pytest.raises(FileNotFoundError, match="frames.json"):
        ReplayCamera(tmp_path)
    np.savez(tmp_path / "x.npz", images=np.zeros((1, 2, 2), np.uint8))
    with pytest.raises(ValueError, match="missing array"):
        ReplayCamera(tmp_path / "x.npz")
    with pytest.raises(ValueError, match="one size"):
        save_recording(tmp_path / "y.npz", [Frame(np.zeros((2, 2), np.uint8), 0, 0, 1, 1, 1), Frame(np.zeros((3, 2), np.uint8), 1, 0, 1, 1, 1)])
    assert not (tmp_path / "y.npz").exists()


def test_picamera2_missing_module_is_a_clear_error(mocker):
    mocker.patch.dict(sys.modules, {"picamera2": None})
    with pytest.raises(CameraError, match="picamera2 is not installed"):
        Picamera2Camera().start()


def test_simulated_camera_from_plain_timing_values():
    train = frame_aligned_train(2 * 10**9, FRAME_NS / 1e3, 30000.0, LINE_NS, CFG.height, 17400.0, every=2)
    cam = SimulatedCamera(CFG, wall_scene(1.5), train, exposure_us=30000.0, frame_duration_us=50000.0,
                          start_ns=2 * 10**9, line_time_ns=LINE_NS, options=FAST)
    cam.start()
    frames = [cam.capture() for _ in range(3)]
    assert [f.sensor_timestamp_ns + CROP_NS for f in frames] == [round(2 * 10**9 + k * FRAME_NS) for k in range(3)]  # no jitter
    assert [f.lit for f in frames] == [True, False, True]
    assert frames[0].exposure_us == pytest.approx(30000.0, abs=LINE_NS / 1e3)  # line-quantised
    with pytest.raises(ValueError, match="not both"):
        SimulatedCamera(CFG, wall_scene(1.5), train, timing=EXACT, exposure_us=30000.0)
    with pytest.raises(ValueError, match="exceeds the frame duration"):
        SimulatedCamera(CFG, wall_scene(1.5), train, exposure_us=60000.0, frame_duration_us=50000.0)
