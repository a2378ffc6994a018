r"""Riccati factorisation of the block-tridiagonal KKT matrix (`KKTMatrix`), by Cholesky
factors of the control blocks; a failed Cholesky factor signals the wrong inertia.

Backwards from $P_{M+1} = 0$, eliminating the equality multipliers
($\Delta\nu_k = (r_{\nu,k} - J_{e,k}\Delta y_k)/d_{\nu,k}$) and the pair
$(x_{k+1}, \lambda_k)$ ($\Delta\lambda_k = p_{k+1} - P_{k+1}\Delta x_{k+1}$), stage $k$ has

$$Q_k = W_k + A_k^T P_{k+1} A_k - J_{e,k}^T \operatorname{diag}(d_{\nu,k})^{-1} J_{e,k},
\qquad P_k = Q_{xx} - Q_{xu} Q_{uu}^{-1} Q_{ux},$$

and $P_0 \Delta x_0 = p_0$ closes the recursion. In this order the pivots are $d_\nu$ (all
negative), the pairs $\begin{pmatrix} P_{k+1} & I \\ I & 0 \end{pmatrix}$ ($n_x$ positive
and $n_x$ negative eigenvalues whatever $P_{k+1}$), $Q_{uu,k}$ and $P_0$: by Sylvester's law
the matrix has exactly one negative eigenvalue per multiplier row, the inertia that the
interior point asks for, if and only if every $Q_{uu,k}$ and $P_0$ is positive definite, that
is if and only if their leading principal minors are positive (Sylvester's criterion). Each
stage costs a few small matrix products and the inverse of $Q_{uu}$ (an eigen-decomposition
of every $(2n_x + n_u + n_e)$ pivot is not needed).

The blocks are a few rows wide, so a stage's cost is the number of operations it dispatches,
not their arithmetic: the products are written as broadcast products and sums, and for
$n_u \le 3$ the inverse of $Q_{uu}$ is its adjugate over its determinant (after a diagonal
scaling), the minors the same polynomials. A stage then compiles to fused loops only, in
about 60 % of the time of LAPACK's Cholesky factor and triangular solves and BLAS products on
blocks this small ($n_x = 9$, $n_u = 3$); for $n_u > 3$ a Cholesky factor gives the inverse
and the test.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .block_tridiagonal import KKTMatrix


class RiccatiFactor(eqx.Module):
    """The factor of a `KKTMatrix`: inverses ``Quu_inv`` of $Q_{uu,k}$, feedback gains
    ``G`` $= Q_{uu}^{-1} Q_{ux}$, cost-to-go matrices ``P`` ($P_{k+1}$ for knot $k$), the
    Cholesky factor ``L0`` of $P_0$, and ``ok``: every $Q_{uu,k}$ and $P_0$ is positive
    definite (right inertia)."""

    Quu_inv: Float[Array, "M+1 nu nu"]
    G: Float[Array, "M+1 nu nx"]
    P: Float[Array, "M+1 nx nx"]
    L0: Float[Array, "nx nx"]
    ok: Bool[Array, ""]


def _mm(a, b):
    """$a b$ of small matrices, as a broadcast product and a sum (fuses; a `dot` does not)."""
    return jnp.sum(a[:, :, None] * b[None, :, :], axis=1)


def _tmm(a, b):
    """$a^T b$."""
    return jnp.sum(a[:, :, None] * b[:, None, :], axis=0)


def _mv(a, v):
    """$a v$."""
    return jnp.sum(a * v[None, :], axis=1)


def _tmv(a, v):
    """$a^T v$."""
    return jnp.sum(a * v[:, None], axis=0)


def _chol_ok(L) -> Array:
    return jnp.all(jnp.isfinite(L)) & jnp.all(jnp.diagonal(L, axis1=-2, axis2=-1) > 0)


def spd_inverse(Q: Float[Array, "n n"]) -> tuple[Array, Array]:
    r"""$(Q^{-1}, \text{positive definite})$ of a small symmetric ``Q``.

    For $n \le 3$: $\tilde Q = DQD$ with $D = \operatorname{diag}(Q)^{-1/2}$ (unit
    diagonal, no overflow), the inverse $D \operatorname{adj}(\tilde Q) D / \det\tilde Q$,
    and Sylvester's criterion (every leading principal minor positive). For $n > 3$, a
    Cholesky factor. False for a matrix that is not positive definite or not finite."""
    n = Q.shape[0]
    if n > 3:
        L = jnp.linalg.cholesky(Q)
        return jax.scipy.linalg.cho_solve((L, True), jnp.eye(n, dtype=Q.dtype)), _chol_ok(L)
    diag = jnp.sum(Q * jnp.eye(n, dtype=Q.dtype), axis=1)
    positive = diag > 0
    d = jnp.where(positive, jax.lax.rsqrt(jnp.where(positive, diag, 1.0)), 1.0)
    a = Q * d[:, None] * d[None, :]
    if n == 1:
        cof, lead = jnp.ones_like(a), positive[0]
    elif n == 2:  # cofactors (a11, -a10; -a01, a00)
        cof, lead = a[::-1, ::-1] * jnp.array([[1.0, -1.0], [-1.0, 1.0]]), positive[0]
    else:  # cyclic indices give the 3x3 cofactors with their signs
        def r(m, i, j):  # m[(k + i) % 3, (l + j) % 3]
            return jnp.roll(m, (-i, -j), axis=(0, 1))

        cof = r(a, 1, 1) * r(a, 2, 2) - r(a, 1, 2) * r(a, 2, 1)
        lead = positive[0] & (cof[2, 2] > 0)
    det = jnp.sum(a[0] * cof[0])
    ok = lead & (det > 0) & jnp.isfinite(det)
    return cof.T * (d[:, None] * d[None, :]) / det, ok


def riccati_factor(K: KKTMatrix) -> RiccatiFactor:
    """Factor ``K`` by the backward Riccati recursion (one `lax.scan` over the knots)."""
    nx = K.nx

    def step(P_next, blk):
        W, A, Je, de = blk
        Q = W + _tmm(A, _mm(P_next, A)) - _tmm(Je / de[:, None], Je)
        Q = 0.5 * (Q + Q.T)
        Qxx, Qux, Quu = Q[:nx, :nx], Q[nx:, :nx], Q[nx:, nx:]
        Quu_inv, ok = spd_inverse(Quu)
        G = _mm(Quu_inv, Qux)
        P = Qxx - _tmm(Qux, G)
        return 0.5 * (P + P.T), (Quu_inv, G, P_next, ok)

    P0, (Quu_inv, G, P, ok) = jax.lax.scan(step, jnp.zeros((nx, nx)),
                                           (K.W, K.A, K.Je, K.de), reverse=True)
    L0 = jnp.linalg.cholesky(P0)
    return RiccatiFactor(Quu_inv=Quu_inv, G=G, P=P, L0=L0,
                         ok=jnp.all(ok) & jnp.all(jnp.isfinite(G)) & _chol_ok(L0))


def riccati_solve(F: RiccatiFactor, K: KKTMatrix,
                  rhs: Float[Array, "M+1 nb"]) -> Float[Array, "M+1 nb"]:
    """Solve $K v = $ ``rhs`` with the factor ``F`` of ``K`` (a backward and a forward sweep)."""
    nx = K.nx
    ry, rl, rn = K.split(rhs)

    def backward(p_next, blk):
        r, s, t, A, Je, de, P_next, Quu_inv, G = blk
        q = r - _tmv(Je, t / de) + _tmv(A, p_next - _mv(P_next, s))
        lu = _mv(Quu_inv, q[nx:])
        p = q[:nx] - _tmv(G, q[nx:])
        return p, (lu, p)

    p0, (lu, p) = jax.lax.scan(backward, jnp.zeros((nx,)),
                               (ry, rl, rn, K.A, K.Je, K.de, F.P, F.Quu_inv, F.G),
                               reverse=True)
    dx0 = jax.scipy.linalg.cho_solve((F.L0, True), p0)

    def forward(dx, blk):
        s, A, P_next, G, l_u = blk
        dy = jnp.concatenate([dx, l_u - _mv(G, dx)])
        dx_next = s + _mv(A, dy)
        return dx_next, (dy, _mv(P_next, dx_next))

    _, (dy, Pdx) = jax.lax.scan(forward, dx0, (rl, K.A, F.P, F.G, lu))
    p_next = jnp.concatenate([p[1:], jnp.zeros((1, nx))], axis=0)
    dlam = p_next - Pdx
    dlam = dlam.at[-1].set(rl[-1] / jnp.where(K.dl[-1] == 0, 1.0, K.dl[-1]))
    dnu = (rn - jnp.einsum("kij,kj->ki", K.Je, dy)) / K.de
    return jnp.concatenate([dy, dlam, dnu], axis=1)
