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
is if and only if their Cholesky factors exist. Each stage costs a few small matrix products
and a Cholesky factor of size $n_u$ (an eigen-decomposition of every $(2n_x + n_u + n_e)$
pivot is not needed).

The blocks are a few rows wide, so a stage's cost is the number of operations it dispatches,
not their arithmetic: the products are written as broadcast products and sums, and the
Cholesky factor of $Q_{uu}$ and its triangular solves are unrolled into scalar arithmetic
(LAPACK's algorithm: a pivot that is not positive gives NaN there too). A stage then compiles to
fused loops only, which on blocks this small cost less than a LAPACK or BLAS call each.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .block_tridiagonal import KKTMatrix


class RiccatiFactor(eqx.Module):
    """The factor of a `KKTMatrix`: Cholesky factors ``L`` of $Q_{uu,k}$, feedback gains
    ``G`` $= Q_{uu}^{-1} Q_{ux}$, cost-to-go matrices ``P`` ($P_{k+1}$ for knot $k$), the
    Cholesky factor ``L0`` of $P_0$, and ``ok``: every factor exists (right inertia)."""

    L: Float[Array, "M+1 nu nu"]
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


UNROLLED_MAX = 4
"""The largest control block whose Cholesky factor and triangular solves are unrolled into
elementwise arithmetic (LAPACK beyond)."""


def _cholesky(Q: Float[Array, "n n"]) -> Float[Array, "n n"]:
    r"""The lower Cholesky factor of a small symmetric ``Q`` (Cholesky-Banachiewicz, unrolled
    for $n \le$ `UNROLLED_MAX`); NaN on a pivot that is not positive, as LAPACK's."""
    n = Q.shape[0]
    if n == 0:  # no controls: an empty factor
        return Q
    if n > UNROLLED_MAX:
        return jnp.linalg.cholesky(Q)
    L = [[None] * n for _ in range(n)]
    for i in range(n):
        for j in range(i + 1):
            s = Q[i, j] - sum((L[i][k] * L[j][k] for k in range(j)), jnp.zeros((), Q.dtype))
            L[i][j] = jnp.sqrt(s) if i == j else s / L[j][j]
    zero = jnp.zeros((), Q.dtype)
    return jnp.stack([jnp.stack([L[i][j] if j <= i else zero for j in range(n)])
                      for i in range(n)])


def _solve_lower(L, b, transposed=False):
    r"""$L^{-1} b$, or $L^{-T} b$ where ``transposed``, for a lower triangular ``L``
    (substitution, unrolled for $n \le$ `UNROLLED_MAX`); ``b`` a vector or a matrix."""
    n = L.shape[0]
    if n == 0:
        return b
    if n > UNROLLED_MAX:
        return jax.scipy.linalg.solve_triangular(L, b, lower=True, trans=int(transposed))
    x = [None] * n
    for i in (reversed(range(n)) if transposed else range(n)):
        ks = range(i + 1, n) if transposed else range(i)
        s = b[i] - sum(((L[k, i] if transposed else L[i, k]) * x[k] for k in ks),
                       jnp.zeros_like(b[i]))
        x[i] = s / L[i, i]
    return jnp.stack(x)


def riccati_factor(K: KKTMatrix) -> RiccatiFactor:
    """Factor ``K`` by the backward Riccati recursion (one `lax.scan` over the knots)."""
    nx = K.nx

    def step(P_next, blk):
        W, A, Je, de = blk
        Q = W + _tmm(A, _mm(P_next, A)) - _tmm(Je / de[:, None], Je)
        Q = 0.5 * (Q + Q.T)
        Qxx, Qux, Quu = Q[:nx, :nx], Q[nx:, :nx], Q[nx:, nx:]
        L = _cholesky(Quu)
        V = _solve_lower(L, Qux)  # L^{-1} Q_ux
        G = _solve_lower(L, V, transposed=True)
        P = Qxx - _tmm(V, V)
        return 0.5 * (P + P.T), (L, G, P_next)

    P0, (L, G, P) = jax.lax.scan(step, jnp.zeros((nx, nx)), (K.W, K.A, K.Je, K.de),
                                 reverse=True)
    L0 = jnp.linalg.cholesky(P0)
    return RiccatiFactor(L=L, G=G, P=P, L0=L0, ok=_chol_ok(L) & _chol_ok(L0))


def riccati_solve(F: RiccatiFactor, K: KKTMatrix,
                  rhs: Float[Array, "M+1 nb"]) -> Float[Array, "M+1 nb"]:
    """Solve $K v = $ ``rhs`` with the factor ``F`` of ``K`` (a backward and a forward sweep)."""
    nx = K.nx
    ry, rl, rn = K.split(rhs)

    def backward(p_next, blk):
        r, s, t, A, Je, de, P_next, L, G = blk
        q = r - _tmv(Je, t / de) + _tmv(A, p_next - _mv(P_next, s))
        lu = _solve_lower(L, _solve_lower(L, q[nx:]), transposed=True)
        p = q[:nx] - _tmv(G, q[nx:])
        return p, (lu, p)

    p0, (lu, p) = jax.lax.scan(backward, jnp.zeros((nx,)),
                               (ry, rl, rn, K.A, K.Je, K.de, F.P, F.L, F.G), reverse=True)
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
