"""The one compiled part of laserpi: the fast pipeline's per-column kernel, the Python module
``device.vision._columns`` built from the plain C kernel (device/vision/columns/columns.c, its API
in columns.h, its header says why it is C) and its binding (device/vision/columns/binding.c).
Everything else about the package is in pyproject.toml.

``optional``: a robot that installs laserpi only for the host SDK needs no compiler; the device
reports a missing kernel when a fast pipeline is built (device.vision.kernel.columns_kernel).
``-ffp-contract=off``: no fused multiply-adds, so the kernel rounds alike on x86 and ARM (the
Makefile's C unit tests build it the same way)."""

from setuptools import Extension, setup

KERNEL = "device/vision/columns"

setup(ext_modules=[Extension("device.vision._columns", [f"{KERNEL}/binding.c", f"{KERNEL}/columns.c"],
                             depends=[f"{KERNEL}/columns.h"], extra_compile_args=["-O3", "-ffp-contract=off"],
                             optional=True)])
