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
