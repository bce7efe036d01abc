"""The numpy / CasADi dispatch layer: each primitive gives the same numbers on both backends."""

from __future__ import annotations

import casadi as ca
import numpy as np

from secure3d.geometry import backend as B


def test_is_symbolic():
    assert B.is_symbolic(1.0, ca.SX.sym("x"))
    assert B.is_symbolic(ca.MX.sym("x"))
    assert B.is_symbolic(ca.DM(1.0))
    assert not B.is_symbolic(np.ones(3), 2.0, [1, 2])


def test_primitives_agree(rng):
    A, x, y = ca.SX.sym("A", 4, 3), ca.SX.sym("x", 3), ca.SX.sym("y", 3)
    exprs = [
        B.matvec(A, x),
        B.dot(x, y),
        B.norm(x),
        B.smooth_norm(x, 0.1),
        B.row_norms(A),
        B.fmin(x, y),
        B.fmax(x, y),
        B.vmin(x),
        B.matmul(A, B.transpose(A)),
        B.stack([B.sqrt(B.dot(x, x)), B.sin(x[0]), B.cos(x[1])]),
        B.block([[x[0], 1.0], [2.0, x[1]]]),
        B.component(x, 2),
    ]
    f = ca.Function("f", [A, x, y], exprs)
    for _ in range(10):
        An, xn, yn = rng.standard_normal((4, 3)), rng.standard_normal(3), rng.standard_normal(3)
        expected = [
            An @ xn,
            xn @ yn,
            np.linalg.norm(xn),
            np.sqrt(xn @ xn + 0.01),
            np.linalg.norm(An, axis=1),
            np.minimum(xn, yn),
            np.maximum(xn, yn),
            xn.min(),
            An @ An.T,
            np.array([np.linalg.norm(xn), np.sin(xn[0]), np.cos(xn[1])]),
            np.array([[xn[0], 1.0], [2.0, xn[1]]]),
            xn[2],
        ]
        numpy_side = [
            B.matvec(An, xn),
            B.dot(xn, yn),
            B.norm(xn),
            B.smooth_norm(xn, 0.1),
            B.row_norms(An),
            B.fmin(xn, yn),
            B.fmax(xn, yn),
            B.vmin(xn),
            B.matmul(An, B.transpose(An)),
            B.stack([B.sqrt(B.dot(xn, xn)), B.sin(xn[0]), B.cos(xn[1])]),
            B.block([[xn[0], 1.0], [2.0, xn[1]]]),
            B.component(xn, 2),
        ]
        for got, num, want in zip(f(An, xn, yn), numpy_side, expected, strict=True):
            want = np.asarray(want, dtype=float)
            np.testing.assert_allclose(np.array(got).reshape(want.shape), want, atol=1e-12)
            np.testing.assert_allclose(num, want, atol=1e-12)


def test_numpy_batching():
    A = np.arange(2 * 4 * 3, dtype=float).reshape(2, 4, 3)
    x = np.ones((2, 3))
    np.testing.assert_allclose(B.matvec(A, x), np.einsum("nij,nj->ni", A, x))
    assert B.block([[np.zeros(5), 1.0], [2.0, np.ones(5)]]).shape == (5, 2, 2)
    v = np.array([[3.0, 4.0, 0.0]])
    assert B.smooth_norm(v, 0.0)[0] == 5.0 and 5.0 < B.smooth_norm(v, 1e-3)[0] <= 5.0 + 1e-3
