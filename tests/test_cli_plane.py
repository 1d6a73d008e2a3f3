"""`laserpi plane` contract (issue 2): both directions, mm at the CLI, argparse errors."""

import json
import math

import pytest

from device import cli
from device.model.triangulation import TriangulationParams, params_from_plane, plane_from_params


def run_json(capsys, *argv):
    assert cli.main(["plane", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_plane_to_params_uses_mm_and_degrees(capsys):
    out = run_json(capsys, "--plane", "0.03099,-1.62720,94.05262", "--beta-deg", "90")
    assert set(out) == {"theta_deg", "alpha_deg", "psi_deg", "s_mm"}
    p = params_from_plane(0.03099, -1.62720, 0.09405262, math.pi / 2)
    assert out["s_mm"] == pytest.approx(p.s * 1e3, rel=1e-12)
    assert out["theta_deg"] == pytest.approx(math.degrees(math.atan(1 / 1.6272)), rel=1e-12)   # docs/thesis-notes.md N4
    assert out["alpha_deg"] + out["theta_deg"] == pytest.approx(90.0)                        # D.72, beta 90
    assert out["s_mm"] == pytest.approx(math.sin(math.radians(out["theta_deg"])) * 94.05262)  # D.71


def test_params_to_plane_and_back(capsys):
    out = run_json(capsys, "--alpha-deg", "58.9", "--beta-deg", "90", "--psi-deg", "90", "--s-mm", "55")
    assert set(out) == {"a", "b", "c"}
    a, b, c = plane_from_params(TriangulationParams(math.radians(58.9), math.pi / 2, math.pi / 2, 0.055))
    assert (out["a"], out["b"], out["c"]) == pytest.approx((a, b, c * 1e3), abs=1e-12)
    assert out["c"] == pytest.approx(55 / math.sin(math.radians(31.1)))        # s / sin(theta), mm
    back = run_json(capsys, f"--plane={out['a']},{out['b']},{out['c']}", "--beta-deg", "90")  # A may be negative
    assert back["alpha_deg"] == pytest.approx(58.9) and back["s_mm"] == pytest.approx(55.0)
    assert back["psi_deg"] == pytest.approx(90.0)


def test_conditioning_warning_goes_to_stderr(capsys):
    assert cli.main(["plane", "--plane", "0,-0.00001,100", "--json"]) == 0
    captured = capsys.readouterr()
    assert "perpendicular" in captured.err and json.loads(captured.out)["theta_deg"] > 89.9


@pytest.mark.parametrize("argv, needle", [
    (["--plane", "1,2"], "argument --plane"),
    (["--plane", "0,-1.6,abc"], "argument --plane"),
    (["--plane", "0,-1.6,-5"], "argument --plane"),
    (["--plane", "0,0,100"], "argument --plane"),
    (["--plane", "0,-1.6,100", "--alpha-deg", "50"], "argument --plane"),
    (["--alpha-deg", "58.9"], "--psi-deg, --s-mm"),
    (["--alpha-deg", "100", "--psi-deg", "90", "--s-mm", "55"], "theta"),
    (["--alpha-deg", "nan", "--psi-deg", "90", "--s-mm", "55"], "argument --alpha-deg"),
])
def test_bad_arguments_exit_2(capsys, argv, needle):
    with pytest.raises(SystemExit) as exc:
        cli.main(["plane", *argv, "--json"])
    assert exc.value.code == 2 and needle in capsys.readouterr().err
