"""`laserpi design` contract (issue 2): JSON shape and values, readable report, plots, errors."""

import json
import subprocess
import sys

import pytest

from device import cli
from device.config import load_preset
from device.design import limits, report


def run_json(capsys, *argv):
    assert cli.main(["design", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_json_contract_matches_the_model(capsys):
    out = run_json(capsys, "--preset", "thesis-design", "--subpixel", "0.1,0.2", "--distances-mm", "2000,2500")
    assert set(out) == {"q_min_mm", "q_max_mm", "resolution_pct"}
    assert set(out["resolution_pct"]) == {"0.1", "0.2"}
    assert all(set(row) == {"2000", "2500"} for row in out["resolution_pct"].values())
    g = limits.geometry_from_config(load_preset("thesis-design"))
    table = limits.resolution_table(g, [0.1, 0.2], [2.0, 2.5]) * 100
    assert out["resolution_pct"]["0.2"]["2500"] == pytest.approx(table[1, 1], rel=1e-12)
    col = limits.column_limits(g, g.principal_column)
    assert out["q_min_mm"] == pytest.approx(col.q_min[0] * 1e3) and out["q_max_mm"] == pytest.approx(col.q_max[0] * 1e3)
    assert out["q_min_mm"] < out["q_max_mm"] < 10_000


def test_unbounded_range_is_null_and_unseen_distance_is_null(capsys, tmp_path):
    out = run_json(capsys, "--preset", "thesis-calibrated", "--subpixel", "0.5", "--distances-mm", "2000")
    assert out["q_max_mm"] is None and out["resolution_pct"]["0.5"]["2000"] > 0
    out = run_json(capsys, "--preset", "thesis-design", "--subpixel", "0.5", "--distances-mm", "9000")
    assert out["resolution_pct"]["0.5"]["9000"] is None      # beyond max(q) of the design


def test_config_file_works_like_the_preset(capsys, tmp_path):
    from device.config import PRESET_DIR
    path = tmp_path / "mine.toml"
    path.write_text((PRESET_DIR / "thesis-calibrated.toml").read_text())
    a = run_json(capsys, "--config", str(path), "--subpixel", "0.3", "--distances-mm", "2500")
    b = run_json(capsys, "--preset", "thesis-calibrated", "--subpixel", "0.3", "--distances-mm", "2500")
    assert a == b


def test_readable_report_and_plots(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(report, "SWEEP_COLUMN_STEP", 400)       # a few columns: the test is about the output
    monkeypatch.setattr(report, "SWEEP_ALPHAS_DEG", (50.0, 120.0, 5.0))
    assert cli.main(["design", "--preset", "thesis-calibrated", "--subpixel", "0.1,0.5",
                     "--distances-mm", "2000,3500", "--plots", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    for needle in ("min(q)", "unbounded", "3500 mm", "best alpha", "pulse_train", "Class 1", "mW/cm^2"):
        assert needle in text
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert pngs == ["alpha_sweep.png", "background.png", "column_limits.png", "resolution.png"]
    assert all((tmp_path / p).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)


@pytest.mark.parametrize("argv, option", [
    (["--preset", "nope"], "--preset"),
    (["--config", "/nonexistent/sensor.toml"], "--config"),
    (["--preset", "thesis-design", "--subpixel", "0.1,abc"], "--subpixel"),
    (["--preset", "thesis-design", "--subpixel", "-0.1"], "--subpixel"),
    (["--preset", "thesis-design", "--distances-mm", "0"], "--distances-mm"),
    (["--preset", "thesis-design", "--config", "x.toml"], "--config"),
])
def test_bad_arguments_exit_2(capsys, argv, option):
    with pytest.raises(SystemExit) as exc:
        cli.main(["design", *argv, "--json"])
    assert exc.value.code == 2 and f"argument {option}" in capsys.readouterr().err


def test_bad_config_value_names_the_field(tmp_path, capsys):
    from device.config import PRESET_DIR
    path = tmp_path / "bad.toml"
    path.write_text((PRESET_DIR / "thesis-calibrated.toml").read_text().replace("fx = 592.139", "fx = -1.0"))
    with pytest.raises(SystemExit) as exc:
        cli.main(["design", "--config", str(path), "--json"])
    assert exc.value.code == 2 and "fx" in capsys.readouterr().err


def test_subprocess_entry_point():
    res = subprocess.run([sys.executable, "-m", "device.cli", "design", "--preset", "thesis-design",
                          "--subpixel", "0.1", "--distances-mm", "2000", "--json"],
                         capture_output=True, text=True, check=True)
    assert json.loads(res.stdout)["resolution_pct"]["0.1"]["2000"] > 0
