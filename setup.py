"""The one compiled part of laserpi: the fast pipeline's per-column kernel (device/vision/_columns.c,
see its header for why it is C). Everything else about the package is in pyproject.toml.

``optional``: a robot that installs laserpi only for the host SDK needs no compiler; the device
reports a missing kernel when a fast pipeline is built (device.vision.kernel.columns_kernel).
``-ffp-contract=off``: no fused multiply-adds, so the kernel rounds alike on x86 and ARM."""

from setuptools import Extension, setup

setup(ext_modules=[Extension("device.vision._columns", ["device/vision/_columns.c"],
                             extra_compile_args=["-O3", "-ffp-contract=off"], optional=True)])
