"""The compiled kernel of the fast pipeline and the table triangulation: the module
``device.vision._columns``, built from ``device/vision/columns/`` (a plain C kernel, columns.c,
whose header says why it is C, and its Python binding, binding.c), with a clear error where it
was not built."""

from __future__ import annotations

import functools


@functools.cache
def columns_kernel():
    """The module ``device.vision._columns``; ImportError naming the fix if it is not built."""
    try:
        from . import _columns
    except ImportError as exc:
        raise ImportError("device.vision._columns, the fast pipeline's compiled kernel, is not built: run "
                          "`pip install -e .` (or `make test`) with a C compiler and the Python headers") from exc
    return _columns
