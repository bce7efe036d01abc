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
import importlib
import os
import threading
from types import ModuleType

from secure3d.sigint import held_sigint


def _interrupt_after() -> contextlib.AbstractContextManager[None]:
    """Hold a Ctrl-C during an import; raise it as ``KeyboardInterrupt`` at the end."""
    return held_sigint(threading.Event())


#: Pure-Python modules every ``import open3d`` imports (its plotly viewer: plotly, and dash, which
#: pulls in IPython). They are imported first, outside the held Ctrl-C, where a Ctrl-C stops them
#: at once: on the 2-core VM they were 0.55-0.8 s of open3d's 1.0-1.4 s import, and a Ctrl-C held
#: through all of it was answered after 1.49 s (the CLI's bar is 1 s).
OPEN3D_PYTHON_DEPENDENCIES = ("plotly.graph_objects", "dash")


@functools.cache
def open3d() -> ModuleType:
    """Return the ``open3d`` module, preloading libusb from the ``libusb-package`` wheel."""
    for name in OPEN3D_PYTHON_DEPENDENCIES:
        try:
            importlib.import_module(name)
        except ImportError:
            pass  # open3d's own import says what is missing
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
