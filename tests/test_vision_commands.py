"""`laserpi evaluate` and `laserpi bench pipeline` end to end on small simulated runs."""

import json
import subprocess
import sys

import pytest

from device.cli import main


def test_evaluate_json_reports_against_truth(capsys):
    rc = main(["evaluate", "--scene", "wall:distance=2,reflectivity=0.9", "--pipeline", "reference,fast-com",
               "--frames", "1", "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert [r["variant"] for r in out] == ["reference", "fast-com"]
    fast = out[1]
    assert 0 < fast["subpixel_rms_px"] < out[0]["subpixel_rms_px"]
    assert fast["valid_fraction"] > 0.8 and fast["false_return_fraction"] == 0.0
    bins = {tuple(b["bin_m"]): b for b in fast["range_error_by_distance"]}
    ref_bins = {tuple(b["bin_m"]): b for b in out[0]["range_error_by_distance"]}
    assert bins[(1.5, 2.5)]["std_pct"] < ref_bins[(1.5, 2.5)]["std_pct"] and bins[(1.5, 2.5)]["n"] > 700


def test_evaluate_text_and_bad_input(capsys):
    assert main(["evaluate", "--scene", "empty", "--frames", "1"]) == 0
    text = capsys.readouterr().out
    assert "false returns 0.0000 of 1640 empty columns" in text  # the image's, not the buffer's padding
    assert main(["evaluate", "--scene", "no-such-scene", "--frames", "1"]) == 2
    assert "unknown scene" in capsys.readouterr().out
    assert main(["evaluate", "--scene", "empty", "--pipeline", "fast-median"]) == 2
    assert "unknown pipeline" in capsys.readouterr().out


def test_bench_pipeline_json_and_png(tmp_path):
    png = tmp_path / "speed.png"
    out = subprocess.run(
        [sys.executable, "-m", "device.cli", "bench", "pipeline", "--frames", "1", "--repeats", "2",
         "--variants", "reference,fast-com", "--json", "--png", str(png)],
        capture_output=True, text=True, check=True,
    ).stdout
    rows = json.loads(out)
    assert [r["variant"] for r in rows] == ["reference", "fast-com"]
    keys = {"variant", "ms_per_pair", "ms_per_pair_after_idle", "speedup_vs_reference", "subpixel_rms_px",
            "range_err_pct_2m", "range_err_pct_3m", "valid_fraction"}
    assert keys <= set(rows[0])
    assert all(r["ms_per_pair_after_idle"] > 0 for r in rows)
    assert rows[0]["speedup_vs_reference"] == pytest.approx(1.0)
    assert rows[1]["speedup_vs_reference"] == pytest.approx(rows[0]["ms_per_pair"] / rows[1]["ms_per_pair"])
    assert rows[1]["range_err_pct_2m"] < rows[0]["range_err_pct_2m"]
    assert png.stat().st_size > 1000 and png.read_bytes()[:4] == b"\x89PNG"
