"""Who may import whom (README "Layout", docs/architecture.md): ``protocol/`` imports nothing of
ours, ``host_sdk/`` only ``protocol/``, so a robot never needs the Pi's code; and no module of
protocol/, host_sdk/ or device/ imports itself through others (no import cycles).

Read statically from the sources: every import statement, those inside functions included.
Then the robot's case run for real: ``import host_sdk`` and scans from the mock device
``sim://wall`` load no module of ``device`` and no OpenCV, in this checkout and (slow) in a fresh
virtualenv with only ``pip install .``, no extras.
"""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("protocol", "host_sdk", "device")


def module_files(root: Path, packages: tuple[str, ...]) -> dict[str, Path]:
    """{dotted module name: source file} of every module in ``packages`` under ``root``."""
    out = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def imported_modules(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The modules of ``known`` that module ``name`` imports anywhere in its source (an imported
    name counts as its module)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the package, one level up per extra dot
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([node.module] if node.module else []))
            targets = [f"{base}.{alias.name}" for alias in node.names]  # a submodule, or a name in base
        else:
            continue
        for target in targets:
            while target and target not in known:
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


def import_graph(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> dict[str, set[str]]:
    known = module_files(root, packages)
    return {name: imported_modules(name, path, known) for name, path in known.items()}


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The shortest cycle through each module that is on one, each cycle once, as
    [a, b, ..., a]."""
    cycles = set()
    for start in sorted(graph):
        paths, seen, frontier = {start: [start]}, {start}, [start]
        while frontier and start not in [n for f in frontier for n in graph[f]]:
            nxt = []
            for node in frontier:
                for succ in sorted(graph[node]):
                    if succ not in seen and succ in graph:
                        seen.add(succ)
                        paths[succ] = paths[node] + [succ]
                        nxt.append(succ)
            frontier = nxt
        closing = [f for f in frontier if start in graph[f]]
        if closing:
            cycle = paths[min(closing, key=lambda f: (len(paths[f]), f))]
            i = cycle.index(min(cycle))  # one rotation per cycle
            cycles.add(tuple(cycle[i:] + cycle[:i]))
    return [list(c) + [c[0]] for c in sorted(cycles)]


def test_protocol_imports_nothing_of_ours():
    graph = import_graph()
    wrong = {m: sorted(t for t in ts if t.split(".")[0] != "protocol") for m, ts in graph.items()
             if m.split(".")[0] == "protocol"}
    assert not {m: ts for m, ts in wrong.items() if ts}


def test_host_sdk_imports_only_protocol():
    graph = import_graph()
    wrong = {m: sorted(t for t in ts if t.split(".")[0] not in ("host_sdk", "protocol")) for m, ts in graph.items()
             if m.split(".")[0] == "host_sdk"}
    assert not {m: ts for m, ts in wrong.items() if ts}


def test_no_import_cycles():
    cycles = import_cycles(import_graph())
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_a_cycle_through_an_import_inside_a_function_is_found(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from pkg.sub import b\n")
    (pkg / "sub" / "b.py").write_text("def f():\n    from ..a import g\n")
    (pkg / "c.py").write_text("import pkg.a\n")
    graph = import_graph(tmp_path, ("pkg",))
    assert graph["pkg.sub.b"] == {"pkg.a"} and graph["pkg.c"] == {"pkg.a"}
    assert import_cycles(graph) == [["pkg.a", "pkg.sub.b", "pkg.a"]]


#: Run by a robot's Python: the SDK reads three scans from the mock device, then the script prints
#: where host_sdk came from and the loaded modules of device and OpenCV (there should be none).
ROBOT_SCRIPT = """
import sys
import host_sdk
with host_sdk.LaserPi("sim://wall?points=50&noise=0") as sensor:
    scans = [scan for _, scan in zip(range(3), sensor.scans())]
assert [s.ranges.size for s in scans] == [50, 50, 50]
print(host_sdk.__file__)
print(sorted(m for m in sys.modules if m.split(".")[0] in ("device", "cv2")))
"""


def robot_run(python: str | Path, cwd: Path) -> tuple[str, str]:
    """(host_sdk's file, the device/cv2 modules loaded) of ROBOT_SCRIPT run by ``python``."""
    out = subprocess.run([str(python), "-c", ROBOT_SCRIPT], cwd=cwd, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    sdk_file, loaded = out.stdout.strip().splitlines()
    return sdk_file, loaded


def test_the_host_sdk_and_its_mock_device_load_no_device_module_and_no_opencv():
    sdk_file, loaded = robot_run(sys.executable, ROOT)
    assert Path(sdk_file).resolve() == ROOT / "host_sdk" / "__init__.py"
    assert loaded == "[]"


@pytest.mark.slow
def test_a_fresh_pip_install_without_extras_reads_the_mock_device_without_device_code(tmp_path):
    """`pip install .` (numpy, pyserial, cobs; no OpenCV) of a copy of this checkout into a new
    virtualenv; the robot's script runs outside the source tree, on the installed package."""
    src = tmp_path / "laserpi"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".venv", ".git", "build", "out", "__pycache__", "*.so",
                                                             "*.egg-info", ".pytest_cache"))
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    python = env_dir / "bin" / "python"
    install = subprocess.run([str(python), "-m", "pip", "install", "-q", "--disable-pip-version-check", str(src)],
                             capture_output=True, text=True, timeout=300)
    assert install.returncode == 0, install.stdout + install.stderr
    sdk_file, loaded = robot_run(python, tmp_path)
    assert Path(sdk_file).is_relative_to(env_dir)  # the installed package, not the copy's sources
    assert loaded == "[]"
