"""The code stays runnable on Raspberry Pi OS bookworm's numpy 1.24 (pyproject's floor, README "On
the Pi"): no numpy name that arrived after 1.24 (numpy 1.25: ``exceptions``, ``dtypes``; 2.0:
the array-API names and ``trapezoid``) is used by anything a Pi or a robot imports."""

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
AFTER_1_24 = {
    "exceptions", "dtypes",  # 1.25
    "trapezoid", "unstack", "concat", "permute_dims", "matrix_transpose", "vecdot", "vecmat", "matvec", "bitwise_count",
    "isdtype", "astype", "cumulative_sum", "cumulative_prod", "pow", "acos", "asin", "atan", "acosh", "asinh", "atanh",
    "atan2", "bitwise_left_shift", "bitwise_right_shift", "bitwise_invert", "long", "ulong",  # 2.0
}


def newer_numpy_names(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    aliases = {a.asname or a.name for node in ast.walk(tree) if isinstance(node, ast.Import)
               for a in node.names if a.name == "numpy"}
    found = [f"{path.relative_to(REPO)}:{node.lineno} numpy.{node.attr}" for node in ast.walk(tree)
             if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases
             and node.attr in AFTER_1_24]
    found += [f"{path.relative_to(REPO)}:{node.lineno} from numpy import {a.name}" for node in ast.walk(tree)
              if isinstance(node, ast.ImportFrom) and node.module == "numpy" for a in node.names if a.name in AFTER_1_24]
    return found


def test_the_scan_finds_a_newer_name(tmp_path):
    probe = REPO / "tests" / "data" / "_numpy_probe.py"
    probe.write_text("import numpy as np\nfrom numpy import concat\nx = np.trapezoid([1, 2])\n")
    try:
        assert newer_numpy_names(probe) == ["tests/data/_numpy_probe.py:3 numpy.trapezoid",
                                            "tests/data/_numpy_probe.py:2 from numpy import concat"]
    finally:
        probe.unlink()


@pytest.mark.parametrize("package", ["protocol", "host_sdk", "device"])
def test_no_numpy_name_newer_than_bookworms(package):
    found = [hit for path in sorted((REPO / package).rglob("*.py")) for hit in newer_numpy_names(path)]
    assert not found, "numpy names newer than 1.24 (bookworm's): " + ", ".join(found)
