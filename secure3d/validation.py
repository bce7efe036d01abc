"""Type checks of user input, in one place (issue 22: they were inline copies in every module).

Each check answers one question about a value from a user, a file or a caller (Python's ``bool``
is an ``int``, so every check refuses it explicitly); the caller raises its own error, naming its
field and the value, so that messages stay where the field is defined.

The ``numpy`` flag also accepts NumPy scalars (``np.integer``; for reals also ``np.floating``):
values read from arrays are NumPy scalars, values from YAML and keyword arguments are not.
"""

from __future__ import annotations

import numpy as np

__all__ = ["INTS", "NUMPY_INTS", "NUMPY_REALS", "REALS", "is_int", "is_int_in", "is_real"]

INTS: tuple[type, ...] = (int,)
NUMPY_INTS: tuple[type, ...] = (int, np.integer)
REALS: tuple[type, ...] = (int, float)
NUMPY_REALS: tuple[type, ...] = (int, float, np.integer, np.floating)


def is_int(value: object, *, numpy: bool = False) -> bool:
    """True for an integer that is not a ``bool``."""
    return not isinstance(value, bool) and isinstance(value, NUMPY_INTS if numpy else INTS)


def is_int_in(value: object, lo: int, hi: int | None = None, *, numpy: bool = False) -> bool:
    """True for an integer (not a ``bool``) with ``lo <= value`` (and ``value <= hi`` if given)."""
    return is_int(value, numpy=numpy) and value >= lo and (hi is None or value <= hi)  # type: ignore[operator]


def is_real(value: object, *, numpy: bool = False, types: tuple[type, ...] | None = None) -> bool:
    """True for a real number (not a ``bool``): ``int`` or ``float`` (NumPy's too with ``numpy``;
    ``types`` overrides both, e.g. ``(numbers.Real,)``). Finiteness is the caller's to check."""
    kinds = types if types is not None else NUMPY_REALS if numpy else REALS
    return not isinstance(value, bool) and isinstance(value, kinds)
