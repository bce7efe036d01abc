"""A tiny numpy / CasADi dispatch layer, so one kernel body serves both.

Every geometry kernel used by the optimiser is written once in terms of these functions. With
numpy inputs they broadcast over leading batch dimensions (vectors are ``(..., n)``, matrices
``(..., r, c)``); with CasADi inputs (``SX``, ``MX`` or ``DM``) vectors are columns ``(n, 1)`` and
there is no batching. The convention that makes one body possible: a *vector* is ``(..., n)`` in
numpy and ``(n, 1)`` in CasADi, a *matrix* is ``(..., r, c)`` resp. ``(r, c)``, and a "list of
vectors" (normals, half-space rows) is always a matrix whose rows are the vectors.

casadi is imported lazily (only once a CasADi object has been seen), so numpy-only users such as
the safety certificate do not pay for it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

ArrayOrSym = Any
"""A numpy array (or scalar) or a CasADi ``SX``/``MX``/``DM`` expression."""


def _ca():
    import casadi

    return casadi


def _is_casadi(x: object) -> bool:
    return type(x).__module__.startswith("casadi") and type(x).__name__ in ("SX", "MX", "DM")


def is_symbolic(*xs: object) -> bool:
    """True if any argument is a CasADi ``SX``, ``MX`` or ``DM``.

    ``DM`` counts as CasADi so that a kernel called with CasADi numbers returns CasADi numbers, the
    same orientation (column vectors) as the symbolic call.
    """
    return any(_is_casadi(x) for x in xs)


def to_casadi(x: ArrayOrSym) -> ArrayOrSym:
    """Convert a numpy vector ``(n,)`` to a ``DM`` column ``(n, 1)`` and a matrix to ``DM``;
    CasADi objects pass through."""
    if _is_casadi(x):
        return x
    return _ca().DM(np.asarray(x, dtype=float))


def vector(x: ArrayOrSym, symbolic: bool) -> ArrayOrSym:
    """``x`` as a vector of the requested backend: float array, or CasADi column."""
    if symbolic:
        x = to_casadi(x)
        if x.shape[0] == 1 and x.shape[1] > 1:
            x = x.T
        return x
    return np.asarray(x, dtype=float)


def matrix(x: ArrayOrSym, symbolic: bool) -> ArrayOrSym:
    """``x`` as a matrix of the requested backend."""
    return to_casadi(x) if symbolic else np.asarray(x, dtype=float)


def transpose(a: ArrayOrSym) -> ArrayOrSym:
    """Swap the last two axes (numpy) / transpose (CasADi)."""
    if is_symbolic(a):
        return a.T
    return np.swapaxes(a, -1, -2)


def matmul(a: ArrayOrSym, b: ArrayOrSym) -> ArrayOrSym:
    """Matrix product, batched over leading axes in numpy."""
    if is_symbolic(a, b):
        return _ca().mtimes(to_casadi(a), to_casadi(b))
    return np.matmul(a, b)


def matvec(a: ArrayOrSym, x: ArrayOrSym) -> ArrayOrSym:
    """``a @ x`` for a matrix ``(..., r, c)`` and a vector ``(..., c)`` (CasADi: ``(c, 1)``)."""
    if is_symbolic(a, x):
        return _ca().mtimes(to_casadi(a), vector(x, True))
    return np.matmul(a, np.asarray(x)[..., None])[..., 0]


def dot(x: ArrayOrSym, y: ArrayOrSym) -> ArrayOrSym:
    """Inner product of two vectors over the last axis (CasADi: ``x.T @ y``)."""
    if is_symbolic(x, y):
        return _ca().dot(vector(x, True), vector(y, True))
    return np.sum(np.multiply(x, y), axis=-1)


def sqrt(x: ArrayOrSym) -> ArrayOrSym:
    return _ca().sqrt(x) if is_symbolic(x) else np.sqrt(x)


def sin(x: ArrayOrSym) -> ArrayOrSym:
    return _ca().sin(x) if is_symbolic(x) else np.sin(x)


def cos(x: ArrayOrSym) -> ArrayOrSym:
    return _ca().cos(x) if is_symbolic(x) else np.cos(x)


def norm(x: ArrayOrSym) -> ArrayOrSym:
    """Euclidean norm of a vector (numpy: over the last axis). Not differentiable at 0."""
    if is_symbolic(x):
        return _ca().norm_2(x)
    return np.linalg.norm(x, axis=-1)


def smooth_norm(x: ArrayOrSym, eps: float) -> ArrayOrSym:
    """``sqrt(|x|^2 + eps^2)``: an upper bound on ``|x|`` that is smooth at 0.

    Used where the optimiser could drive the argument to zero (DESIGN.md section 4, "Known
    obstacles"); ``|x| <= smooth_norm(x) <= |x| + eps``, so it only adds conservatism.
    """
    if is_symbolic(x):
        return _ca().sqrt(_ca().sumsqr(x) + eps * eps)
    return np.sqrt(np.sum(np.square(x), axis=-1) + eps * eps)


def row_norms(a: ArrayOrSym) -> ArrayOrSym:
    """Norm of every row of a matrix: numpy ``(..., k, n) -> (..., k)``, CasADi ``(k, 1)``."""
    if is_symbolic(a):
        ca = _ca()
        return ca.sqrt(ca.sum2(a * a))
    return np.linalg.norm(a, axis=-1)


def fmin(x: ArrayOrSym, y: ArrayOrSym) -> ArrayOrSym:
    """Element-wise minimum."""
    return _ca().fmin(x, y) if is_symbolic(x, y) else np.minimum(x, y)


def fmax(x: ArrayOrSym, y: ArrayOrSym) -> ArrayOrSym:
    """Element-wise maximum."""
    return _ca().fmax(x, y) if is_symbolic(x, y) else np.maximum(x, y)


def vmin(x: ArrayOrSym) -> ArrayOrSym:
    """Smallest entry of a vector (numpy: over the last axis). Non-smooth: for reporting, not for
    constraints (constrain every entry instead)."""
    return _ca().mmin(x) if is_symbolic(x) else np.min(x, axis=-1)


def stack(xs: Sequence[ArrayOrSym]) -> ArrayOrSym:
    """Stack scalars (or numpy arrays of equal batch shape) into a vector: numpy ``(..., n)``,
    CasADi column ``(n, 1)``."""
    if is_symbolic(*xs):
        return _ca().vertcat(*xs)
    return np.stack(np.broadcast_arrays(*[np.asarray(x, dtype=float) for x in xs]), axis=-1)


def block(rows: Sequence[Sequence[ArrayOrSym]]) -> ArrayOrSym:
    """Build a matrix from nested rows of scalar entries.

    numpy entries may be arrays of a common batch shape ``S``; the result is ``S + (r, c)``.
    """
    flat = [x for row in rows for x in row]
    if is_symbolic(*flat):
        ca = _ca()
        return ca.vertcat(*[ca.horzcat(*row) for row in rows])
    arrays = np.broadcast_arrays(*[np.asarray(x, dtype=float) for x in flat])
    n_rows, n_cols = len(rows), len(rows[0])
    out = np.stack(arrays, axis=-1)
    return out.reshape(out.shape[:-1] + (n_rows, n_cols))


def component(x: ArrayOrSym, i: int) -> ArrayOrSym:
    """Entry ``i`` of a vector (numpy: of every vector in the batch)."""
    if is_symbolic(x):
        return x[i]
    return np.asarray(x)[..., i]
