"""Optional heavy dependencies, imported in exactly one place.

open3d links ``libusb-1.0`` at import time. Machines without the system package still work because
the ``libusb-package`` wheel ships the library: we load it globally with ctypes before importing
open3d (no root needed). Rerun is imported lazily so that ``import secure3d`` stays fast.

Each import runs under :func:`_interrupt_after`: a Ctrl-C that arrives while an extension module
initialises would otherwise surface as that module's ``ImportError("initialization failed")``
(pybind11 turns the ``KeyboardInterrupt`` into one) instead of a clean stop.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import os
import threading
from types import ModuleType

from secure3d.sigint import held_sigint


def _interrupt_after() -> contextlib.AbstractContextManager[None]:
    """Hold a Ctrl-C during an import; raise it as ``KeyboardInterrupt`` at the end."""
    return held_sigint(threading.Event())


@functools.cache
def open3d() -> ModuleType:
    """Return the ``open3d`` module, preloading libusb from the ``libusb-package`` wheel."""
    with _interrupt_after():
        return _import_open3d()


def _import_open3d() -> ModuleType:
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
    with _interrupt_after():
        import rerun as rr

    return rr


@functools.cache
def fcl() -> ModuleType:
    """Return the python-fcl module."""
    with _interrupt_after():
        import fcl as _fcl

    return _fcl
