"""Optional heavy dependencies, imported in exactly one place.

open3d links ``libusb-1.0`` at import time. Machines without the system package still work because
the ``libusb-package`` wheel ships the library: we load it globally with ctypes before importing
open3d (no root needed). Rerun is imported lazily so that ``import secure3d`` stays fast.
"""

from __future__ import annotations

import ctypes
import functools
import os
from types import ModuleType


@functools.cache
def open3d() -> ModuleType:
    """Return the ``open3d`` module, preloading libusb from the ``libusb-package`` wheel."""
    try:
        import libusb_package

        path = libusb_package.get_library_path()
        if path is not None:
            ctypes.CDLL(os.fspath(path), mode=ctypes.RTLD_GLOBAL)
    except (ImportError, OSError):
        pass  # fall back to the system libusb, if any
    import open3d as o3d

    return o3d


@functools.cache
def rerun() -> ModuleType:
    """Return the ``rerun`` module (rerun-sdk 0.41)."""
    import rerun as rr

    return rr


@functools.cache
def fcl() -> ModuleType:
    """Return the python-fcl module."""
    import fcl as _fcl

    return _fcl
