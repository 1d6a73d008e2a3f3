import sys

import numpy as np
import pytest

from device.camera.base import Camera, CameraError, CaptureTimeout, EndOfRecording
from device.camera.frame import Frame
from device.camera.picamera2_camera import Picamera2Camera
from device.camera.replay import ReplayCamera, save_npz, save_recording
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
    frames = [Frame(rng.integers(0, 256, (30, 40), dtype=np.uint8), k, 10**9 + k * 5_000_000, 400.0, 5000.0, LINE_NS,
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


def _recording_arrays(n: int = 6) -> dict:
    """A valid recording's arrays: n frames of 30 x 40 at 5 ms, every other one lit."""
    k = np.arange(n)
    return {"images": np.zeros((n, 30, 40), np.uint8), "seq": k, "sensor_timestamp_ns": 10**9 + k * 5_000_000,
            "exposure_us": np.full(n, 400.0), "frame_duration_us": np.full(n, 5000.0), "line_time_ns": np.full(n, LINE_NS),
            "lit": (k % 2 == 0).astype(np.int8), "readout_offset_rows": np.full(n, 155)}


def _changed(**changes) -> dict:
    return {**_recording_arrays(), **changes}


@pytest.mark.parametrize("arrays, message", [
    (_changed(lit=np.array([1, 0, 1, 0], np.int8)), r"lit has shape \(4,\), one value per frame of the 6 images"),
    (_changed(images=np.zeros((4, 30, 40), np.uint8)), r"seq has shape \(6,\), one value per frame of the 4 images"),
    ({k: v[0] for k, v in _recording_arrays().items()}, r"images must be \(frames, height, width\) uint8"),
    (_changed(images=np.zeros((6, 30, 40, 3), np.uint8)), "colour frames: convert them to luminance first"),
    (_changed(images=np.zeros((6, 30, 40), np.uint16)), "uint8 luminance"),
    (_changed(lit=np.array(["1", "0"] * 3)), "lit must be numbers"),
    (_changed(exposure_us=np.full(6, True)), "exposure_us must be numbers, got bool"),
    (_changed(exposure_us=np.full(6, 400 + 1j)), "exposure_us must be numbers, got complex"),
    (_changed(lit=np.array([1, 0, 2, 0, 1, 0])), "frame 2 .seq 2.: lit is 2: 1 .lit., 0 .dark. or -1"),
    (_changed(seq=np.array([0, 1, np.nan, 3, 4, 5])), "frame 2 .*seq is nan: a count must be a whole number"),
    (_changed(seq=np.array([0, 1, 2, 3, 2, 3])), "frame 4 .seq 2.: seq does not increase from 3"),
    (_changed(line_time_ns=np.full(6, np.nan)), "frame 0 .*line_time_ns is nan: a duration must be finite and positive"),
    (_changed(line_time_ns=np.zeros(6)), "line_time_ns is 0.0"),
    (_changed(line_time_ns=np.full(6, 1e6)), "its 30 rows .read from row 155 of the sensor.* longer than the frame"),
    (_changed(exposure_us=np.full(6, 9000.0)), "exposure_us 9000 is not shorter than its frame"),
    (_changed(readout_offset_rows=np.full(6, -1)), "readout_offset_rows is -1"),
    # frames 4 and 5 swapped in time; timestamps in microseconds
    (_changed(sensor_timestamp_ns=10**9 + np.array([0, 1, 2, 3, 5, 4]) * 5_000_000),
     r"frame 4 .seq 4.: it starts 10.000 ms after the frame before .sensor_timestamp_ns., where seq and frame_duration_us "
     r"say 5.000 ms"),
    (_changed(sensor_timestamp_ns=10**6 + np.arange(6) * 5000), "it starts 0.005 ms after the frame before"),
])
def test_replay_refuses_a_recording_no_camera_made(tmp_path, arrays, message):
    """A recording from elsewhere (another renderer, another camera stack) is checked whole when
    opened: what no camera produces is refused, naming the frame and the field, before a frame is
    processed (device/camera/replay.py check_frames)."""
    path = tmp_path / "rec.npz"
    np.savez(path, **arrays)
    with pytest.raises(ValueError, match=message) as err:
        ReplayCamera(path)
    assert str(path) in str(err.value)


def test_replay_takes_a_dropped_frame_and_says_what_it_assumed(tmp_path, caplog):
    caplog.set_level("INFO")
    arrays = {k: np.delete(v, 3, axis=0) for k, v in _recording_arrays().items()}  # seq 3 dropped: a gap
    del arrays["readout_offset_rows"]
    np.savez(tmp_path / "rec.npz", **arrays)
    cam = ReplayCamera(tmp_path / "rec.npz")
    assert [cam.capture().seq for _ in range(5)] == [0, 1, 2, 4, 5]
    assert list(cam.assumed) == ["readout_offset_rows"] and cam.assumed["readout_offset_rows"][0] == 0
    assert "no readout_offset_rows recorded, taken as 0" in caplog.text


def test_replay_takes_a_frame_period_that_changes_at_once(tmp_path):
    """A frame starts the earlier frame's length after it (libcamera's FrameDuration): from 60 ms
    frames to 25 ms ones the step is 60 ms, whichever frame's period a recording labels it with."""
    k = np.arange(4)
    frame_us = np.array([60000.0, 60000.0, 25000.0, 25000.0])
    starts = 10**9 + np.concatenate([[0], np.cumsum(frame_us[:-1])]).astype(np.int64) * 1000
    for labels in (frame_us, np.roll(frame_us, 1)):  # its own length, or the time since the frame before (the simulator's)
        np.savez(tmp_path / "rec.npz", **_changed(images=np.zeros((4, 30, 40), np.uint8), seq=k, sensor_timestamp_ns=starts,
                                                  exposure_us=np.full(4, 400.0), frame_duration_us=labels,
                                                  line_time_ns=np.full(4, LINE_NS), lit=(k % 2 == 0).astype(np.int8),
                                                  readout_offset_rows=np.full(4, 155)))
        assert len(ReplayCamera(tmp_path / "rec.npz")) == 4


def test_replay_refuses_what_no_npz_reader_can_read(tmp_path):
    (tmp_path / "junk.npz").write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="junk.npz: not an .npz recording"):
        ReplayCamera(tmp_path / "junk.npz")
    np.savez(tmp_path / "objects.npz", **_changed(seq=np.array([0, 1, 2, 3, 4, None], dtype=object)))
    with pytest.raises(ValueError, match="objects.npz: an array holds Python objects, not numbers"):
        ReplayCamera(tmp_path / "objects.npz")
    import zipfile

    with zipfile.ZipFile(tmp_path / "objects.npz") as z:  # a truncated array: not a pickle's refusal
        parts = {n: z.read(n) for n in z.namelist()}
    with zipfile.ZipFile(tmp_path / "cut.npz", "w") as z:
        for n, data in parts.items():
            z.writestr(n, data[: len(data) // 2] if n == "images.npy" else data)
    with pytest.raises(ValueError, match="cut.npz: not a readable .npz recording"):
        ReplayCamera(tmp_path / "cut.npz")


def test_replay_folder_refuses_an_index_that_does_not_describe_its_frames(tmp_path):
    import json

    frames = [Frame(np.zeros((30, 40), np.uint8), k, 10**9 + k * 5_000_000, 400.0, 5000.0, LINE_NS, k % 2 == 0)
              for k in range(3)]
    save_recording(tmp_path / "rec", frames)
    index_path = tmp_path / "rec" / "frames.json"
    index = json.loads(index_path.read_text())

    def opened_with(change) -> str:
        broken = json.loads(json.dumps(index))
        change(broken["frames"])
        index_path.write_text(json.dumps(broken))
        with pytest.raises((ValueError, FileNotFoundError)) as err:
            ReplayCamera(tmp_path / "rec").capture()
        return str(err.value)

    assert "frame 1: lit is 'yes': true, false or null" in opened_with(lambda f: f[1].update(lit="yes"))
    assert "frame 1 (seq 1): lit is 2" in opened_with(lambda f: f[1].update(lit=2))
    assert "frame 2 has no seq" in opened_with(lambda f: f[2].pop("seq"))
    assert "a per-frame value is not a number" in opened_with(lambda f: f[0].update(exposure_us=[1, 2]))
    assert "exposure_us must be numbers" in opened_with(lambda f: f[0].update(exposure_us="400"))
    assert "no such frame image" in opened_with(lambda f: f[0].update(file="missing.png"))
    # readout_offset_rows on some frames only: the recorded values would be dropped for 0
    assert "frame 1 has no readout_offset_rows, other frames have one" in opened_with(
        lambda f: f[1].pop("readout_offset_rows"))
    index["frames"][0]["lit"], index["frames"][1]["lit"] = 1, -1  # the .npz's codes mean the same here
    index_path.write_text(json.dumps(index))
    cam = ReplayCamera(tmp_path / "rec")
    assert [cam.capture().lit for _ in range(3)] == [True, None, True]


def test_save_npz_leaves_nothing_behind_when_the_write_fails(tmp_path, mocker):
    path = tmp_path / "out.npz"

    def half_written(file, **arrays):
        open(file, "wb").write(b"PK\x03\x04 half")
        raise OSError(27, "File too large")

    mocker.patch("numpy.savez_compressed", side_effect=half_written)
    with pytest.raises(OSError, match="File too large"):
        save_npz(path, a=np.zeros(3))
    assert list(tmp_path.iterdir()) == []


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
