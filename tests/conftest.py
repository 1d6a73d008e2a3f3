"""Fixtures shared by several test modules."""

import pytest

from device.sim.comcu_emulator import build_emulator


@pytest.fixture(scope="session")
def emulator():
    """The production firmware ELF and the simavr harness, built once per run. A missing simavr
    fails loudly (make test installs it), never skips."""
    try:
        return build_emulator()
    except Exception as exc:
        pytest.fail(f"simavr harness unavailable: {exc}")
