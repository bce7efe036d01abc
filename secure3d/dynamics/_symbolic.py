"""One function body for numpy and CasADi.

Every kernel of the dynamics and reactive-set modules is written over *components*: a state is split
into its scalar entries, the kernel combines them with the functions of a math namespace (``numpy``
or ``casadi``), and the result is stacked back. With numpy the components may be arrays of any
common shape, so the same body evaluates one state ``(nx,)`` or a batch ``(N, nx)``; with CasADi the
components are scalar ``SX``/``MX`` expressions and the result is a column vector or matrix. This is
the STYLE.md rule "one function body that serves both numbers and symbols".
"""

from __future__ import annotations

from collections.abc import Sequence
from types import ModuleType
from typing import Any

import casadi as ca
import numpy as np

_CASADI_TYPES = (ca.SX, ca.MX, ca.DM)


def is_casadi(*values: Any) -> bool:
    """True if any of ``values`` is a CasADi ``SX``, ``MX`` or ``DM``."""
    return any(isinstance(v, _CASADI_TYPES) for v in values)


def math_of(*values: Any) -> ModuleType:
    """The namespace (``casadi`` or ``numpy``) whose ``sin``, ``sqrt``, ... apply to ``values``."""
    return ca if is_casadi(*values) else np


def split(x: Any, n: int, what: str = "x") -> list[Any]:
    """The ``n`` scalar components of ``x``.

    Parameters
    ----------
    x : (n,) or (N, n) float array, or CasADi column vector of length n
    n : expected length of the last axis.
    what : name used in the error message.
    """
    if is_casadi(x):
        if x.numel() != n:
            raise ValueError(
                f"{what}: expected {n} entries, got a CasADi object of shape {x.shape}"
            )
        return [x[i] for i in range(n)]
    return split_numbers(np.asarray(x, dtype=float), n, what)


def split_numbers(x: np.ndarray, n: int, what: str = "x") -> list[np.ndarray]:
    """:func:`split` of a numpy array (no CasADi check): its ``n`` components along the last axis."""
    if x.ndim == 0 or x.shape[-1] != n:
        raise ValueError(f"{what}: expected shape (..., {n}), got {x.shape}")
    return [x[..., i] for i in range(n)]


def stack(items: Sequence[Any], like_casadi: bool) -> Any:
    """Stack scalar components into a vector: ``(..., k)`` numpy array or CasADi column."""
    if like_casadi:
        return ca.vertcat(*items) if items else ca.DM.zeros(0, 1)
    if not items:
        return np.zeros(0)
    if all(getattr(i, "ndim", 0) == 0 for i in items):  # one state: the same values, unbroadcast
        return np.array(items, dtype=float)
    return np.stack(np.broadcast_arrays(*[np.asarray(i, dtype=float) for i in items]), axis=-1)


def matrix(rows: Sequence[Sequence[Any]], like_casadi: bool) -> Any:
    """Assemble a matrix from nested component lists: ``(..., r, c)`` numpy or CasADi ``r x c``."""
    if like_casadi:
        return ca.vertcat(*[ca.horzcat(*row) for row in rows])
    if all(np.ndim(e) == 0 for row in rows for e in row):  # one state: no broadcasting
        return np.array(rows, dtype=float)
    flat = np.broadcast_arrays(*[np.asarray(e, dtype=float) for row in rows for e in row])
    r, c = len(rows), len(rows[0])
    return np.stack(flat, axis=-1).reshape(*flat[0].shape, r, c)


def matvec(mat: Sequence[Sequence[Any]], vec: Sequence[Any]) -> list[Any]:
    """Component-wise product of a nested-list matrix and a component vector."""
    return [sum(row[j] * vec[j] for j in range(len(vec))) for row in mat]


def matmul(a: Sequence[Sequence[Any]], b: Sequence[Sequence[Any]]) -> list[list[Any]]:
    """Component-wise product of two nested-list matrices."""
    n, k, m = len(a), len(b), len(b[0])
    return [[sum(a[i][l] * b[l][j] for l in range(k)) for j in range(m)] for i in range(n)]


def transpose(a: Sequence[Sequence[Any]]) -> list[list[Any]]:
    """Transpose of a nested-list matrix."""
    return [list(col) for col in zip(*a, strict=True)]


def smooth_norm(components: Sequence[Any], eps: float, m: ModuleType) -> Any:
    """``sqrt(|v|^2 + eps^2)``: a smooth, strictly positive upper bound of ``|v|`` (within eps)."""
    return m.sqrt(sum(c * c for c in components) + eps * eps)
