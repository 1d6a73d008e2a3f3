"""Every `laserpi` command and benchmark named in the tables exists, parses --help, and the
dispatcher imports only the module of the command being run."""

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from device.cli import COMMANDS, main
from device.commands.bench import BENCHMARKS

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_command_module_has_the_two_functions(name):
    module = importlib.import_module(COMMANDS[name][0])
    assert callable(module.add_arguments) and callable(module.run)


@pytest.mark.parametrize("name", sorted(BENCHMARKS))
def test_benchmark_module_has_the_two_functions(name):
    module = importlib.import_module(BENCHMARKS[name][0])
    assert callable(module.add_arguments) and callable(module.run)


def test_help_lists_every_command_without_importing_them(capsys):
    code = main([])
    out = capsys.readouterr().out
    assert code == 2 and all(name in out for name in COMMANDS)


def test_host_commands_do_not_import_opencv_or_the_simulator():
    probe = ("import sys, device.cli as c\n"
             "for n in ('scans', 'view', 'record', 'replay', 'export-bag'):\n"
             "    __import__(c.COMMANDS[n][0])\n"
             "heavy = [m for m in ('cv2', 'matplotlib', 'device.sim', 'device.vision') if m in sys.modules]\n"
             "print(heavy)")
    out = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_unknown_command_is_an_error_naming_the_choices(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["frobnicate"])
    assert exc.value.code == 2 and "unknown command 'frobnicate'" in capsys.readouterr().err


@pytest.mark.parametrize("argv, option, message", [
    (["soak", "--minutes", "-1"], "--minutes", "must be a finite positive number, got '-1'"),
    (["record", "--port", "sim://wall", "--out", "x.lpr", "--seconds", "-1"], "--seconds",
     "must be a finite positive number, got '-1'"),
    (["demo", "--seconds", "-1"], "--seconds", "must be a finite positive number, got '-1'"),
    (["serve", "--simulate", "--mock", "--link", "x", "--points", "0"], "--points", "must be a positive integer, got '0'"),
    (["scans", "--port", "sim://wall", "--baud", "0"], "--baud", "must be a positive integer, got '0'"),
    (["replay", "x.lpr", "--speed", "nan"], "--speed", "must be finite, got 'nan'"),
])
def test_a_number_out_of_range_is_refused_naming_the_option(argv, option, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"argument {option}: {message}" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []  # nothing started: no link, no recording
