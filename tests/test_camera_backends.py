import sys

import numpy as np
import pytest

from device.camera.base import Camera, CameraError, CaptureTimeout, EndOfRecording
from device.camera.frame import Frame
from device.camera.modes import MODE5
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
    assert [f.sensor_timestamp_ns for f, _ in out] == [round(10**9 + k * FRAME_NS) for k in range(4)]
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
        k = round((f.sensor_timestamp_ns - 10**9) / FRAME_NS)
        assert k == f.seq
        late = f.sensor_timestamp_ns - (10**9 + k * FRAME_NS)
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
                    [True, False, None][k % 3]) for k in range(5)]
    path = tmp_path / ("rec.npz" if kind == "npz" else "rec")
    save_recording(path, frames)
    cam = ReplayCamera(path)
    assert isinstance(cam, Camera) and len(cam) == 5 and (cam.width, cam.height) == (40, 30)
    cam.start()
    for f in frames:
        g = cam.capture()
        assert np.array_equal(f.image, g.image)
        assert (g.seq, g.sensor_timestamp_ns, g.exposure_us, g.frame_duration_us, g.line_time_ns, g.lit) == (
            f.seq, f.sensor_timestamp_ns, f.exposure_us, f.frame_duration_us, f.line_time_ns, f.lit)
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


class FakeRequest:
    def __init__(self, yuv, meta):
        self.yuv, self.meta, self.released = yuv, meta, False

    def make_array(self, name):
        assert name == "main"
        return self.yuv

    def get_metadata(self):
        return self.meta

    def release(self):
        self.released = True


@pytest.fixture
def fake_picamera2(mocker):
    module = mocker.MagicMock(name="picamera2")
    mocker.patch.dict(sys.modules, {"picamera2": module})
    return module


def test_picamera2_configures_mode5_fixed_exposure(fake_picamera2):
    cam = Picamera2Camera(exposure_us=30000, frame_duration_us=50000, analogue_gain=4.0)
    cam.start()
    pc = fake_picamera2.Picamera2.return_value
    fake_picamera2.Picamera2.assert_called_once_with(0)
    kwargs = pc.create_video_configuration.call_args.kwargs
    assert kwargs["main"] == {"size": (1640, 922), "format": "YUV420"}
    assert kwargs["sensor"] == {"output_size": (1640, 1232), "bit_depth": 10}
    pc.configure.assert_called_once_with(pc.create_video_configuration.return_value)
    controls = pc.set_controls.call_args.args[0]
    assert controls["AeEnable"] is False and controls["AwbEnable"] is False
    assert controls["ExposureTime"] == 30000 and controls["AnalogueGain"] == 4.0
    assert controls["FrameDurationLimits"] == (50000, 50000) and controls["ScalerCrop"] == MODE5.scaler_crop
    pc.start.assert_called_once()
    cam.set_frame_duration(40000)
    assert pc.set_controls.call_args.args[0] == {"FrameDurationLimits": (40000, 40000)}
    cam.set_exposure(20000)
    assert pc.set_controls.call_args.args[0] == {"ExposureTime": 20000}
    cam.stop()
    pc.stop.assert_called_once() and pc.close.assert_called_once()


def test_picamera2_capture_takes_the_luminance_plane_and_metadata(fake_picamera2):
    cam = Picamera2Camera()
    cam.start()
    pc = fake_picamera2.Picamera2.return_value
    stride = 1664
    yuv = np.full((922 * 3 // 2, stride), 7, dtype=np.uint8)
    yuv[:922, :1640] = np.arange(1640, dtype=np.uint64).astype(np.uint8)[None, :]
    req = FakeRequest(yuv, {"SensorTimestamp": 123456789, "ExposureTime": 39990, "FrameDuration": 50001})
    pc.wait.return_value = req
    f = cam.capture(timeout_s=0.5)
    pc.capture_request.assert_called_once_with(wait=False)
    assert pc.wait.call_args.kwargs == {"timeout": 0.5}
    assert req.released
    assert f.image.shape == (928, 1664)
    assert np.array_equal(f.image[:922, :1640], yuv[:922, :1640])
    assert not f.image[922:].any() and not f.image[:, 1640:].any()  # chroma and stride padding are not luminance
    assert (f.seq, f.sensor_timestamp_ns, f.exposure_us, f.frame_duration_us, f.lit) == (0, 123456789, 39990.0, 50001.0, None)
    assert cam.capture().seq == 1


def test_picamera2_errors(fake_picamera2, mocker):
    cam = Picamera2Camera()
    with pytest.raises(CameraError, match="not started"):
        cam.capture()
    cam.start()
    pc = fake_picamera2.Picamera2.return_value
    pc.wait.side_effect = TimeoutError()
    with pytest.raises(CaptureTimeout):
        cam.capture(0.01)
    timed_out_job = pc.capture_request.return_value
    pc.wait.side_effect = None
    pc.capture_request.reset_mock()
    req = FakeRequest(np.zeros((10, 10), np.uint8), {})
    pc.wait.return_value = req
    with pytest.raises(CameraError, match="unexpected YUV420 buffer"):
        cam.capture()
    pc.capture_request.assert_not_called()  # the timed-out job was waited on again, not leaked
    assert pc.wait.call_args.args[0] is timed_out_job
    assert req.released  # the buffer goes back to the camera even on error
    with pytest.raises(ValueError):
        Picamera2Camera(exposure_us=60000, frame_duration_us=50000)


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
    assert [f.sensor_timestamp_ns for f in frames] == [round(2 * 10**9 + k * FRAME_NS) for k in range(3)]  # no jitter
    assert [f.lit for f in frames] == [True, False, True]
    assert frames[0].exposure_us == pytest.approx(30000.0, abs=LINE_NS / 1e3)  # line-quantised
    with pytest.raises(ValueError, match="not both"):
        SimulatedCamera(CFG, wall_scene(1.5), train, timing=EXACT, exposure_us=30000.0)
    with pytest.raises(ValueError, match="exceeds the frame duration"):
        SimulatedCamera(CFG, wall_scene(1.5), train, exposure_us=60000.0, frame_duration_us=50000.0)
