"""The compiled kernels (``reachset_ros/_tick.c``), loaded with ctypes.

Two functions, both exact copies of numpy code paths of this package (same floating-point
operations in the same order, compiled with ``-ffp-contract=off``), so results are bitwise
equal whether or not the kernel is used:

* ``reachset_monitor_tick``: one tick of :class:`reachset_ros.conformance.monitor.Monitor`;
* ``reachset_sweep_block``: one block of :func:`reachset_ros.conformance.sweep`.

``LIB`` is None when the shared library was not built (e.g. no C compiler at install time)
or the environment variable ``REACHSET_NO_KERNEL`` is set; callers then use numpy.
"""
from __future__ import annotations

import ctypes
import importlib.machinery
import os
from pathlib import Path

_P = ctypes.c_void_p
_I = ctypes.c_int64


def _load():
    if os.environ.get("REACHSET_NO_KERNEL"):
        return None, None
    here = Path(__file__).resolve().parent
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = here / f"_tick{suffix}"
        if path.exists():
            lib = ctypes.CDLL(str(path))
            lib.reachset_monitor_tick.argtypes = [_P, _I, _P, _P]
            lib.reachset_monitor_tick.restype = _I
            lib.reachset_sweep_block.argtypes = [_P, _P, _P, _P, _I, _I, _I, _I, _P, _P, _P, _P, _I, _I, _P, _P]
            lib.reachset_sweep_block.restype = _I
            return lib, str(path)
    return None, None


LIB, PATH = _load()


def ptr(a):
    """ctypes pointer to the data of a C-contiguous numpy array."""
    return a.ctypes.data_as(_P)
