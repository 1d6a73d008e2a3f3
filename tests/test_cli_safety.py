"""`laserpi safety` contract (issue 2): JSON keys, values from the model, argparse errors."""

import json
import subprocess
import sys

import pytest

from device import cli
from device.model import safety as sf

BASE = ["safety", "--wavelength-nm", "808", "--pulse-ms", "17.4", "--rate-hz", "10", "--fan-deg", "120",
        "--line-height-mm", "4", "--source-mm", "1"]


def run_json(capsys, *extra):
    assert cli.main(BASE + list(extra) + ["--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_contract_with_nohd(capsys):
    out = run_json(capsys, "--nohd-mm", "10")
    assert set(out) == {"max_power_mw", "nohd_mm", "class1", "limiting_condition"}
    assert out["max_power_mw"] == pytest.approx(30.43, rel=1e-3)      # hand value, see test_safety
    assert out["nohd_mm"] == 10.0 and out["class1"] is None  # no laser given: a limit, not a verdict
    assert out["limiting_condition"] == sf.CONDITION_TRAIN


def test_contract_with_power(capsys):
    out = run_json(capsys, "--power-mw", "25")
    assert out["nohd_mm"] == pytest.approx(8.216, rel=1e-3) and out["class1"] is True
    out = run_json(capsys, "--power-mw", "40")
    assert out["nohd_mm"] > 10 and out["class1"] is False
    out = run_json(capsys, "--power-mw", "25", "--closest-eye-mm", "5")
    assert out["class1"] is False and out["max_power_mw"] < 25


def test_readable_output_as_subprocess():
    res = subprocess.run([sys.executable, "-m", "device.cli", *BASE, "--power-mw", "25"],
                         capture_output=True, text=True, check=True)
    assert "pulse_train" in res.stdout and "Class 1" in res.stdout and "8.22 mm" in res.stdout
    res = subprocess.run([sys.executable, "-m", "device.cli", *BASE, "--nohd-mm", "10"], capture_output=True, text=True,
                         check=True)
    assert res.stdout.splitlines()[-2:] == ["max power at 10 mm: 30.42 mW",
                                            "a laser of at most that peak power is Class 1 with no eye nearer than 10 mm"]


@pytest.mark.parametrize("change, option", [
    (("--wavelength-nm", "532"), "--wavelength-nm"),
    (("--pulse-ms", "0.001"), "--pulse-ms"),
    (("--pulse-ms", "150"), "--pulse-ms"),
    (("--fan-deg", "180"), "--fan-deg"),
    (("--rate-hz", "-3"), "--rate-hz"),
    (("--source-mm", "abc"), "--source-mm"),
])
def test_bad_arguments_exit_2_naming_the_argument(capsys, change, option):
    argv = list(BASE)
    i = argv.index(change[0])
    argv[i + 1] = change[1]
    with pytest.raises(SystemExit) as exc:
        cli.main(argv + ["--power-mw", "25"])
    assert exc.value.code == 2
    assert f"argument {option}" in capsys.readouterr().err


def test_nohd_and_power_are_exclusive(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(BASE + ["--power-mw", "25", "--nohd-mm", "10"])
    assert exc.value.code == 2 and "not allowed with" in capsys.readouterr().err
