"""Sensor configuration file: presets, round trip, and clear errors for bad values."""

import math
import tomllib

import numpy as np
import pytest

from device.config import ConfigError, config_from_dict, dumps_config, load_config, load_preset, preset_names, save_config


def _doc(name="thesis-calibrated"):
    from device.config import PRESET_DIR
    return tomllib.loads((PRESET_DIR / f"{name}.toml").read_text())


def test_presets_load_and_hold_thesis_inputs():
    assert {"thesis-design", "thesis-calibrated"} <= set(preset_names())
    cal = load_preset("thesis-calibrated")
    assert (cal.width, cal.height) == (1664, 928)
    assert cal.plane.to_abc() == pytest.approx((0.03099, -1.62720, 0.09405262))
    design = load_preset("thesis-design")
    assert design.camera.intrinsics.cy == pytest.approx(576.404 - 155)  # docs/thesis-notes.md N12
    a, b, c = design.plane.to_abc()
    assert c == pytest.approx(0.055 / math.sin(math.radians(31.1)))


@pytest.mark.parametrize("name", ["thesis-design", "thesis-calibrated"])
def test_roundtrip_through_toml(tmp_path, name):
    cfg = load_preset(name)
    save_config(cfg, tmp_path / "s.toml")
    back = load_config(tmp_path / "s.toml")
    assert back.camera == cfg.camera and back.laser == cfg.laser and back.range == cfg.range
    np.testing.assert_allclose(back.plane.normal, cfg.plane.normal, rtol=1e-14)
    assert back.plane.distance == pytest.approx(cfg.plane.distance, rel=1e-14)


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d["camera"].__setitem__("fx", -5.0), "fx"),
    (lambda d: d["camera"].__setitem__("fy", "600"), "'fy' must be a float"),
    (lambda d: d["camera"].__setitem__("model", "pinhole"), "model must be"),
    (lambda d: d["camera"].__setitem__("distortion", [0.1] * 6), "up to 5"),
    (lambda d: d["laser_plane"].__setitem__("c_m", -0.09), "positive"),
    (lambda d: d["laser_plane"].__setitem__("colour", 3), "unknown key"),
    (lambda d: d.__setitem__("schema_version", 99), "schema_version 99"),
    (lambda d: d["laser"].__setitem__("wavelength_m", 5e-7), "600-1050 nm"),
    (lambda d: d["laser"].__setitem__("pulse_s", 0.2), "overlap"),
    (lambda d: d["range"].__setitem__("max_m", 0.0005), "max_m"),
    (lambda d: d.pop("image"), r"\[image\]"),
    (lambda d: d.__setitem__("triangulation", {"alpha_deg": 58.9, "s_m": 0.05}), "exactly one"),
    (lambda d: d["image"].__setitem__("active_width", 5000), "active_width"),
])
def test_bad_values_name_the_field(mutate, message):
    doc = _doc()
    mutate(doc)
    with pytest.raises(ConfigError, match=message):
        config_from_dict(doc, "sensor.toml")


def test_unreadable_files(tmp_path):
    with pytest.raises(ConfigError, match="no such"):
        load_config(tmp_path / "missing.toml")
    (tmp_path / "bad.toml").write_text("schema_version = = 1")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(tmp_path / "bad.toml")
    with pytest.raises(ConfigError, match="unknown preset"):
        load_preset("nope")


def test_save_leaves_no_half_file(tmp_path, monkeypatch):
    cfg = load_preset("thesis-calibrated")
    target = tmp_path / "s.toml"
    target.write_text("previous")
    import device.config as C
    monkeypatch.setattr(C, "dumps_config", lambda c: "garbage = [")
    with pytest.raises(Exception):
        save_config(cfg, target)
    assert target.read_text() == "previous"
    assert dumps_config(cfg).startswith("schema_version = 1")



def test_files_without_the_sensor_mode_load_as_mode5():
    # [image] sensor_mode/mode_left/mode_top came after the first files: without them a file
    # means what it meant (the thesis's mode 5)
    from device.camera.modes import MODE5

    doc = _doc()
    for key in ("sensor_mode", "mode_left", "mode_top"):
        doc["image"].pop(key)
    cfg = config_from_dict(doc, "old.toml")
    assert cfg.window == MODE5 == load_preset("thesis-calibrated").window


def test_sensor_mode_round_trips(tmp_path):
    doc = _doc()
    doc["image"].update(sensor_mode="1920x1080", mode_left=10, mode_top=20)
    cfg = config_from_dict(doc, "s.toml")
    assert (cfg.window.mode.name, cfg.window.left, cfg.window.top) == ("1920x1080", 10, 20)
    save_config(cfg, tmp_path / "s.toml")
    assert load_config(tmp_path / "s.toml").window == cfg.window


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d["image"].__setitem__("sensor_mode", "1640x922"), r"\[image\]: sensor mode must be one of"),
    (lambda d: d["image"].__setitem__("mode_top", 400), r"\[image\]: a 1640x922 image at \(0, 400\) does not fit"),
    (lambda d: d["image"].__setitem__("mode_left", -1), "does not fit"),
    (lambda d: d["image"].__setitem__("sensor_mode", "640x480"), "does not fit the 640x480"),
])
def test_crops_that_do_not_fit_their_mode_name_the_field(mutate, message):
    doc = _doc()
    mutate(doc)
    with pytest.raises(ConfigError, match=message):
        config_from_dict(doc, "sensor.toml")


def test_files_without_an_operating_point_get_the_defaults():
    """The constants device/sensor had, but a 10 ms exposure (9.2 ms before): a whole period of
    100 Hz mains flicker, so that it cancels at 15 and 20 scans/s too (device/model/flicker.py)."""
    from device.config import OperatingPoint

    doc = _doc()
    assert "operating_point" not in doc
    assert config_from_dict(doc, "old.toml").operating_point == OperatingPoint(
        scan_rate_hz=10.0, exposure_us=10000.0, analog_gain=4.0, min_m=0.4, max_m=3.2, flicker_hz=(100.0, 120.0))


def test_operating_point_round_trips(tmp_path):
    from device.config import OperatingPoint

    doc = _doc()
    doc["operating_point"] = {"scan_rate_hz": 5.0, "exposure_us": 20000, "analog_gain": 8.0, "min_m": 0.3, "max_m": 2.0,
                              "flicker_hz": [100]}
    cfg = config_from_dict(doc, "s.toml")
    assert cfg.operating_point == OperatingPoint(5.0, 20000.0, 8.0, 0.3, 2.0, (100.0,))
    save_config(cfg, tmp_path / "s.toml")
    assert load_config(tmp_path / "s.toml").operating_point == cfg.operating_point


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d.__setitem__("operating_point", {"scan_rate_hz": 20.0}), r"exceeds \[laser\] rate_hz"),
    (lambda d: (d["laser"].__setitem__("rate_hz", 25.0), d["laser"].__setitem__("pulse_s", 0.01),
                d.__setitem__("operating_point", {"scan_rate_hz": 25.0})), "1640x1232 sensor mode runs at .* to 41.85 frames/s"),
    (lambda d: d.__setitem__("operating_point", {"scan_rate_hz": 0.1}), "needs 0.2 frames/s"),
    (lambda d: d.__setitem__("operating_point", {"exposure_us": 60000.0}), "longer than a frame"),
    (lambda d: d.__setitem__("operating_point", {"exposure_us": 49950.0}), "less 4 lines"),
    (lambda d: d.__setitem__("operating_point", {"analog_gain": 12.0}), "outside the IMX219's 1..10.67"),
    (lambda d: d.__setitem__("operating_point", {"analog_gain": 0.5}), "analog_gain"),
    (lambda d: d.__setitem__("operating_point", {"min_m": 3.0, "max_m": 2.0}), r"\[operating_point\]: max_m"),
    (lambda d: d.__setitem__("operating_point", {"exposure_us": -5.0}), "positive"),
    (lambda d: d.__setitem__("operating_point", {"gain": 4.0}), "unknown key"),
    (lambda d: d.__setitem__("operating_point", {"scan_rate_hz": 7.0, "exposure_us": 9200.0}),
     r"exposure_us = 9200 at 7 scans/s .* leaves 100 Hz and 120 Hz flicker"),
    (lambda d: d.__setitem__("operating_point", {"flicker_hz": 100.0}), "'flicker_hz' must be a list"),
    (lambda d: d.__setitem__("operating_point", {"flicker_hz": [100.0, -120.0]}), "'flicker_hz' must be a list of finite positive"),
    (lambda d: d.__setitem__("operating_point", {"flicker_hz": [True]}), "'flicker_hz' must be a list of finite positive"),
])
def test_bad_operating_points_name_the_field(mutate, message):
    doc = _doc()
    mutate(doc)
    with pytest.raises(ConfigError, match=message):
        config_from_dict(doc, "sensor.toml")
