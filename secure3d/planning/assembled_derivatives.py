"""Constraint Jacobian and Lagrangian Hessian of the transcribed NLP, assembled from its node kernels.

CasADi derives ``jac_g`` and ``hess_lag`` of an NLP by colouring and sweeping the whole inlined
expression graph. For the closed loop's NLP (blind corner, K = 40, 12 obstacle slots, look-back as
a parameter: 3481 variables, 2463 rows) that took 1.2 of the 1.5 s spent in ``nlpsol``. Every
constraint family of :func:`secure3d.planning.collocation.build_nlp`, though, is one kernel mapped
over the nodes, and its arguments are affine in the decision vector w (slices of it, the interval
lengths ``T r_k / (K-1)``, duals times a 0/1 side parameter). For such a family with stacked
arguments z = A(p) w + b and multipliers mu,

    d g / d w = blockdiag_k(dG/dz_k) A,    d^2 (mu' g) / d w^2 = A' blockdiag_k(d^2 (mu_k' G)/dz_k^2) A,

so only the small per-node kernel needs symbolic derivatives. :func:`assembled_derivatives` builds
both Functions this way (the rows that are not a kernel call, and the objective, are differentiated
directly) and declines, returning None, when an argument is not affine in w. They are the exact
derivatives of the same g, only differently computed; a test compares them with CasADi's own.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca


@dataclass
class KernelCall:
    """Rows ``vec(fn.map(n)(*args))`` of g: a node kernel applied column by column to ``args``."""

    fn: ca.Function
    args: list
    n: int

    def rows(self) -> ca.SX:
        return ca.vec(self.fn.map(self.n)(*self.args))

    @property
    def size(self) -> int:
        return self.fn.numel_out(0) * self.n


def _kernel_derivatives(fn: ca.Function, dec: tuple[int, ...], cache: dict) -> tuple:
    """(Jacobian, Hessian-of-mu'G) Functions of kernel ``fn`` with respect to its inputs ``dec``."""
    key = (id(fn), dec)
    if key not in cache:
        ins = [ca.SX.sym(f"in{i}", fn.sparsity_in(i)) for i in range(fn.n_in())]
        out = ca.vec(fn(*ins))
        z = ca.vertcat(*[ca.vec(ins[i]) for i in dec])
        mu = ca.SX.sym("mu", out.numel())
        jac = ca.Function(f"{fn.name()}_jac", ins, [ca.jacobian(out, z)])
        hess = ca.Function(f"{fn.name()}_hess", [*ins, mu], [ca.hessian(ca.dot(mu, out), z)[0]])
        cache[key] = (fn, jac, hess)  # fn kept alive so its id stays unique
    return cache[key][1], cache[key][2]


def _block_diagonal(blocks: ca.SX, width: int) -> ca.SX:
    """The column blocks of ``blocks`` (rows x width*n) on a block diagonal."""
    return ca.diagcat(*ca.horzsplit(blocks, width))


def assembled_derivatives(
    w: ca.SX, p: ca.SX, f: ca.SX, g: ca.SX, parts: list, cache: dict
) -> tuple[ca.Function, ca.Function] | None:
    """``(jac_g, hess_lag)`` for nlpsol's options of the same names. The rows ``g`` are the
    vertical concatenation of ``parts``, each a :class:`KernelCall` or a column of SX rows. None if
    a kernel argument is not affine in ``w``. ``cache`` keeps the kernels' derivative Functions."""
    lam_f = ca.SX.sym("lam_f")
    sizes = [part.size if isinstance(part, KernelCall) else part.numel() for part in parts]
    if sum(sizes) != g.numel():
        raise ValueError(f"parts hold {sum(sizes)} rows, g has {g.numel()}")
    lam_g = ca.SX.sym("lam_g", g.numel())
    hess = ca.hessian(lam_f * f, w)[0]
    jac_rows = []
    offset = 0
    for part, size in zip(parts, sizes, strict=True):
        mu = lam_g[offset : offset + size]
        offset += size
        if not isinstance(part, KernelCall):
            jac_rows.append(ca.jacobian(part, w))
            if not ca.is_linear(part, w):
                hess += ca.hessian(ca.dot(mu, part), w)[0]
            continue
        dec = tuple(i for i, a in enumerate(part.args) if ca.depends_on(a, w))
        z = ca.vec(ca.vertcat(*[part.args[i] for i in dec]))  # node-major: z_0, z_1, ...
        A = ca.jacobian(z, w)
        if ca.depends_on(A, w):
            return None
        width = z.numel() // part.n
        jac_fn, hess_fn = _kernel_derivatives(part.fn, dec, cache)
        J_local = _block_diagonal(jac_fn.map(part.n)(*part.args), width)
        jac_rows.append(ca.mtimes(J_local, A))
        mus = ca.reshape(mu, part.fn.numel_out(0), part.n)
        H_local = _block_diagonal(hess_fn.map(part.n)(*part.args, mus), width)
        hess += ca.mtimes(A.T, ca.mtimes(H_local, A))
    jac_g = ca.Function(
        "nlp_jac_g", [w, p], [g, ca.vertcat(*jac_rows)], ["x", "p"], ["g", "jac_g_x"]
    )
    hess_lag = ca.Function(
        "nlp_hess_l",
        [w, p, lam_f, lam_g],
        [ca.triu(hess)],
        ["x", "p", "lam_f", "lam_g"],
        ["triu_hess_gamma_x_x"],
    )
    return jac_g, hess_lag
