"""Pin the BLAS under IPOPT's MUMPS to a fixed number of threads.

CasADi's wheel bundles its own OpenBLAS (``libcasadi-tp-openblas``), which MUMPS calls for the
dense fronts of the KKT factorisation. By default OpenBLAS starts one thread per core (or
``OPENBLAS_NUM_THREADS``), and a multithreaded reduction sums in another order: the same NLP then
takes other iterates on a machine with another core count, and a diff-drive solve can end in
another local minimum (measured on planar_blind_corner: T 4.53 s with one thread, 5.35 s with two).
The planner therefore pins that library to :data:`DEFAULT_THREADS` threads before every solve
(``SECURE3D_BLAS_THREADS`` overrides it), so a plan does not depend on the machine's core count or
on the user's OpenBLAS environment. One thread is also the right count for these small KKT systems
(threads spun in ``sched_yield`` for 19 % of a profile) and for campaigns, which run one process
per core.
"""

from __future__ import annotations

import ctypes
import functools
import os
from pathlib import Path

from secure3d.errors import ConfigError
from secure3d.validation import is_int_in

__all__ = ["DEFAULT_THREADS", "ENV", "blas_threads", "pin_blas_threads"]

#: Environment variable overriding :data:`DEFAULT_THREADS` (a positive integer).
ENV = "SECURE3D_BLAS_THREADS"
#: Threads of CasADi's OpenBLAS during solves.
DEFAULT_THREADS = 1


@functools.cache
def _openblas() -> ctypes.CDLL | None:
    """CasADi's bundled OpenBLAS (None if this CasADi build has none)."""
    import casadi

    for path in sorted(Path(casadi.__file__).parent.glob("libcasadi-tp-openblas.so*")):
        try:
            lib = ctypes.CDLL(str(path))
        except OSError:
            continue
        if hasattr(lib, "openblas_set_num_threads") and hasattr(lib, "openblas_get_num_threads"):
            return lib
    return None


def blas_threads() -> int:
    """Threads CasADi's OpenBLAS uses now (0 if it is not found)."""
    lib = _openblas()
    return 0 if lib is None else int(lib.openblas_get_num_threads())


def _wanted() -> int:
    raw = os.environ.get(ENV)
    if raw is None or raw.strip() == "":
        return DEFAULT_THREADS
    try:
        n = int(raw)
    except ValueError:
        n = 0
    if n < 1:
        raise ConfigError(f"{ENV}: must be a positive integer, got {raw[:40]!r}")
    return n


def pin_blas_threads(threads: int | None = None) -> int:
    """Set CasADi's OpenBLAS to ``threads`` (default: ``SECURE3D_BLAS_THREADS`` or 1).

    Returns the thread count in force afterwards (0 when this CasADi has no bundled OpenBLAS,
    in which case nothing is changed).
    """
    n = _wanted() if threads is None else threads
    if not is_int_in(n, 1):
        raise ConfigError(f"pin_blas_threads: threads must be a positive integer, got {n!r}")
    lib = _openblas()
    if lib is None:
        return 0
    if int(lib.openblas_get_num_threads()) != n:
        lib.openblas_set_num_threads(ctypes.c_int(n))
    return int(lib.openblas_get_num_threads())
