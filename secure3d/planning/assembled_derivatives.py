"""The transcribed NLP as a small MX graph over its node kernels, with its constraint Jacobian and
Lagrangian Hessian assembled from the kernels' own derivatives.

Every constraint family of :func:`secure3d.planning.collocation.build_nlp` is one node kernel mapped
over the nodes, and its arguments are affine in the decision vector w (slices of it, the interval
lengths ``T r_k / (K-1)``, duals times a 0/1 side parameter). For such a family with stacked
arguments z = A(p) w + b and multipliers mu,

    d g / d w = blockdiag_k(dG/dz_k) A,    d^2 (mu' g) / d w^2 = A' blockdiag_k(d^2 (mu_k' G)/dz_k^2) A,

so only the small per-node kernel needs symbolic derivatives. :func:`assembled_nlp` builds the NLP
(``f``, ``g``) and both derivative Functions this way, as an MX graph of a few hundred nodes: the
kernels are mapped SX Functions called once per family, the block diagonals are the mapped outputs
reinterpreted (``sparsity_cast``: a (r, w n) map output and the (r n, w n) block diagonal of its n
blocks store their nonzeros in the same order), and A is a constant (or p-dependent) sparse matrix.
The rows that are not a kernel call, and the objective, are small SX Functions differentiated
directly. It declines, returning None, when an argument is not affine in w.

Why MX at the top: a new look-back assignment is a new NLP structure, and expanding the same
assembly into one SX graph (CasADi's own derivatives, or this assembly in SX) spends 0.7-0.9 s per
build inlining every node's derivatives (forest and blind_corner_quadrotor, K = 40, 12 slots); the
MX graph builds in ~0.05 s, and IPOPT's set-up adds ~0.05 s. The price is ~1 ms more per
evaluation of the Hessian (the products with A, and no sharing of work between g and its Jacobian),
against 10-20 ms of a whole IPOPT iteration. The values are the SX assembly's, bit for bit; a test
compares them with CasADi's whole-graph derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from secure3d.planning import compiled_kernels
from secure3d.planning.compiled_kernels import KernelTag


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


@dataclass
class AssembledNLP:
    """The NLP for ``nlpsol`` (``nlp``: MX ``x``, ``p``, ``f``, ``g``) and its derivative Functions,
    given to nlpsol as the options ``jac_g`` and ``hess_lag``."""

    nlp: dict
    jac_g: ca.Function
    hess_lag: ca.Function


def _kernel_derivatives(fn: ca.Function, dec: tuple[int, ...], cache: dict) -> tuple:
    """(rows-and-Jacobian, Hessian-of-mu'G) Functions of kernel ``fn`` with respect to its inputs
    ``dec``. The first returns the kernel's rows too, so g and its Jacobian share one call. Each is
    its compiled library when there is one (:mod:`secure3d.planning.compiled_kernels`)."""
    key = (id(fn), dec)
    if key not in cache:
        ins = [ca.SX.sym(f"in{i}", fn.sparsity_in(i)) for i in range(fn.n_in())]
        out = ca.vec(fn(*ins))
        z = ca.vertcat(*[ca.vec(ins[i]) for i in dec])
        mu = ca.SX.sym("mu", out.numel())
        jac = ca.Function(f"{fn.name()}_jac", ins, [out, ca.jacobian(out, z)])
        hess = ca.Function(f"{fn.name()}_hess", [*ins, mu], [ca.hessian(ca.dot(mu, out), z)[0]])
        jac_tag = KernelTag.of(fn, dec, "jac")  # one serialisation of the kernel for both
        tags = (jac_tag, jac_tag.with_role("hess"))
        cache[key] = (fn, jac, hess, tags)  # fn kept alive so its id stays unique
    _, jac, hess, tags = cache[key]
    # compiled to C when a library is there (the same values bit for bit), else CasADi's VM
    return compiled_kernels.best(jac, tags[0]), compiled_kernels.best(hess, tags[1])


def _block_diagonal(mapped: ca.MX, block: ca.Sparsity, n: int) -> ca.MX:
    """The n column blocks of a map's output (each of sparsity ``block``) on a block diagonal: the
    same nonzeros in the same order, so no copy."""
    return ca.sparsity_cast(mapped, ca.diagcat(*([block] * n)))


@dataclass
class _Family:
    """One kernel call's place in g and what its derivatives need: the kernel's inputs that depend
    on w (``dec``), d z / d w (``A``, SX in p only) and the index of its first argument."""

    part: KernelCall
    offset: int
    dec: tuple[int, ...]
    A: ca.SX
    first_arg: int


def _families(w: ca.SX, parts: list) -> tuple[list[_Family], list, list[int]] | None:
    """The kernel calls among ``parts`` (None if an argument is not affine in w), every kernel
    argument in order, and the row offset of every part."""
    families, args, offsets, offset = [], [], [], 0
    for part in parts:
        offsets.append(offset)
        if isinstance(part, KernelCall):
            dec = tuple(i for i, a in enumerate(part.args) if ca.depends_on(a, w))
            z = ca.vec(ca.vertcat(*[part.args[i] for i in dec]))  # node-major: z_0, z_1, ...
            A = ca.jacobian(z, w)
            if ca.depends_on(A, w):
                return None
            families.append(_Family(part, offset, dec, A, len(args)))
            args.extend(part.args)
            offset += part.size
        else:
            offset += part.numel()
    return families, args, offsets


def assembled_nlp(w: ca.SX, p: ca.SX, f: ca.SX, parts: list, cache: dict) -> AssembledNLP | None:
    """The NLP with rows ``vertcat(parts)`` (each a :class:`KernelCall` or a column of SX rows in
    ``w`` and ``p``) and objective ``f``, as an MX graph with assembled derivatives (see the module
    docstring). None if a kernel argument is not affine in ``w``. ``cache`` keeps the kernels'
    derivative Functions (one set per kernel, shared by every NLP built from it)."""
    found = _families(w, parts)
    if found is None:
        return None
    families, arg_exprs, offsets = found
    n_g = sum(part.size if isinstance(part, KernelCall) else part.numel() for part in parts)
    W, P = ca.MX.sym("w", w.sparsity()), ca.MX.sym("p", p.sparsity())
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", n_g)
    args = ca.Function("nlp_args", [w, p], arg_exprs).call([W, P]) if arg_exprs else []
    g_blocks, jac_blocks, hess_blocks, hess_f = _plain_parts(
        w, p, f, parts, offsets, W, P, lam_f, lam_g
    )
    for fam in families:
        part = fam.part
        a = args[fam.first_arg : fam.first_arg + len(part.args)]
        jac_fn, hess_fn = _kernel_derivatives(part.fn, fam.dec, cache)
        A = ca.Function("nlp_A", [p], [fam.A])(P) if ca.depends_on(fam.A, p) else ca.evalf(fam.A)
        rows, J = jac_fn.map(part.n)(*a)
        g_blocks[fam.offset] = ca.vec(rows)
        jac_blocks[fam.offset] = ca.mtimes(_block_diagonal(J, jac_fn.sparsity_out(1), part.n), A)
        mus = ca.reshape(lam_g[fam.offset : fam.offset + part.size], part.fn.numel_out(0), part.n)
        H = _block_diagonal(hess_fn.map(part.n)(*a, mus), hess_fn.sparsity_out(0), part.n)
        hess_blocks[fam.offset] = ca.mtimes(A.T, ca.mtimes(H, A))
    hess = hess_f
    for o in offsets:  # in the order of the rows: the same sums as the SX assembly
        if o in hess_blocks:
            hess = hess + hess_blocks[o]
    g = ca.vertcat(*[g_blocks[o] for o in offsets])
    jac_g = ca.Function(
        "nlp_jac_g",
        [W, P],
        [g, ca.vertcat(*[jac_blocks[o] for o in offsets])],
        ["x", "p"],
        ["g", "jac_g_x"],
    )
    hess_lag = ca.Function(
        "nlp_hess_l",
        [W, P, lam_f, lam_g],
        [ca.triu(hess)],
        ["x", "p", "lam_f", "lam_g"],
        ["triu_hess_gamma_x_x"],
    )
    F = ca.Function("nlp_f", [w, p], [f])(W, P)
    return AssembledNLP({"x": W, "p": P, "f": F, "g": g}, jac_g, hess_lag)


def _plain_parts(
    w: ca.SX,
    p: ca.SX,
    f: ca.SX,
    parts: list,
    offsets: list[int],
    W: ca.MX,
    P: ca.MX,
    lam_f: ca.MX,
    lam_g: ca.MX,
) -> tuple[dict, dict, dict, ca.MX]:
    """The rows that are not kernel calls, their Jacobians and Hessians (each by row offset; none
    for linear rows), and the objective's Hessian, from one small SX Function. Each block is
    differentiated on its own, as the SX assembly did, so that the sums come out bit for bit."""
    plain = [
        (o, part)
        for o, part in zip(offsets, parts, strict=True)
        if not isinstance(part, KernelCall)
    ]
    mu = ca.SX.sym("lam_g", lam_g.numel())
    mu_f = ca.SX.sym("lam_f")
    nonlinear = [(o, part) for o, part in plain if not ca.is_linear(part, w)]
    rows = [part for _, part in plain] + [ca.jacobian(part, w) for _, part in plain]
    rows = ca.Function("nlp_plain", [w, p], rows).call([W, P]) if plain else []
    hess = [ca.hessian(mu_f * f, w)[0]]
    hess += [ca.hessian(ca.dot(mu[o : o + part.numel()], part), w)[0] for o, part in nonlinear]
    hess = ca.Function("nlp_plain_hess", [w, p, mu_f, mu], hess).call([W, P, lam_f, lam_g])
    n = len(plain)
    g_blocks = {o: rows[i] for i, (o, _) in enumerate(plain)}
    jac_blocks = {o: rows[n + i] for i, (o, _) in enumerate(plain)}
    hess_blocks = {o: hess[1 + i] for i, (o, _) in enumerate(nonlinear)}
    return g_blocks, jac_blocks, hess_blocks, hess[0]
