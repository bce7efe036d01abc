"""Where numba keeps secure3d's compiled kernels: the user's cache directory, keyed by content.

Compiling the kernels costs 15-40 s; numba caches the result, by default in the ``__pycache__``
beside each source file, so every new clone, virtual environment or wheel install paid it again on
its first plan. Importing this module (every kernel module does, before its decorators run)
registers a cache locator that keeps the compiled code in

    $SECURE3D_NUMBA_CACHE_DIR, else $SECURE3D_CACHE_DIR/numba, else $XDG_CACHE_HOME/secure3d/numba,
    else ~/.cache/secure3d/numba

under a folder named by a digest of *all* of secure3d's kernel sources (the ``.py`` files that
define ``njit`` kernels) and the Python and numba versions. So a checkout anywhere of the same kernel sources reuses
them, and a change to any kernel file (a kernel may inline another file's kernel, which numba's
per-file freshness check would not see) compiles afresh into a new folder. numba's own
``NUMBA_CACHE_DIR``, when set, still wins; if the directory cannot be written, numba's default
locations apply.

:func:`warm` compiles the kernels a plan and a closed-loop flight use (``make venv`` runs it).
"""

from __future__ import annotations

import functools
import hashlib
import os
import re
import sys
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent
#: A numba decorator at the start of a line: the file defines kernels.
_KERNEL_MARK = re.compile(rb"^@(numba\.)?n" rb"jit\b", re.MULTILINE)


def cache_root() -> Path:
    """The folder of secure3d's compiled kernels (see the module)."""
    explicit = os.environ.get("SECURE3D_NUMBA_CACHE_DIR")
    if explicit:
        return Path(explicit)
    shared = os.environ.get("SECURE3D_CACHE_DIR")  # the reactive-set families' cache root too
    if shared:
        return Path(shared) / "numba"
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "secure3d" / "numba"


@functools.cache
def kernel_digest() -> str:
    """Digest of every secure3d source file that defines numba kernels, with the Python and numba
    versions."""
    import numba

    h = hashlib.sha256(f"{sys.version_info[:2]}{numba.__version__}".encode())
    for path in sorted(_PACKAGE.rglob("*.py")):
        text = path.read_bytes()
        if _KERNEL_MARK.search(text):
            h.update(str(path.relative_to(_PACKAGE)).encode())
            h.update(text)
    return h.hexdigest()[:16]


def _locator_class() -> type | None:
    """A numba cache locator class for secure3d's files, or None if numba's internals differ."""
    try:
        from numba.core import caching
    except ImportError:  # pragma: no cover - numba is a dependency
        return None
    base = getattr(caching, "_CacheLocator", None)
    mixin = getattr(caching, "_SourceFileBackedLocatorMixin", None)
    if base is None or mixin is None:  # pragma: no cover - a numba without these internals
        return None

    class Secure3dCacheLocator(mixin, base):
        """secure3d's kernels, in :func:`cache_root` / :func:`kernel_digest` / package subfolder."""

        def __init__(self, py_func: object, py_file: str) -> None:
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            rel = Path(py_file).resolve().parent.relative_to(_PACKAGE)
            self._cache_path = str(cache_root() / kernel_digest() / "secure3d" / rel)

        def get_cache_path(self) -> str:
            return self._cache_path

        def get_source_stamp(self) -> str:
            return kernel_digest()

        @classmethod
        def from_function(cls, py_func: object, py_file: str) -> object:
            try:
                Path(py_file).resolve().relative_to(_PACKAGE)
            except ValueError:
                return None  # not secure3d's: numba's own locators decide
            return super().from_function(py_func, py_file)

    return Secure3dCacheLocator


def install() -> bool:
    """Register the locator (once; after numba's ``NUMBA_CACHE_DIR`` one). True if registered."""
    from numba.core import caching

    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    classes = getattr(impl, "_locator_classes", None)
    if not isinstance(classes, list):  # pragma: no cover - a numba without these internals
        return False
    if any(getattr(c, "__name__", "") == "Secure3dCacheLocator" for c in classes):
        return True
    cls = _locator_class()
    if cls is None:  # pragma: no cover
        return False
    classes.insert(1, cls)  # after UserProvidedCacheLocator (NUMBA_CACHE_DIR), before in-tree
    return True


install()

__all__ = ["cache_root", "install", "kernel_digest"]
