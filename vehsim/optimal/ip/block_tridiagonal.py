r"""The block-tridiagonal KKT matrix of a stage-structured NLP: product, factorisation, solve.

Ordering the unknowns per knot as $(x_k, u_k, \lambda_k, \nu_k)$, block $k$ couples with block
$k+1$ only through the identity between $\lambda_k$ and $x_{k+1}$ (the defect
$x_{k+1} - F_k = 0$). With diagonal blocks $K_k$ the block $LDL^T$ recursion (a Riccati-like
sweep) is

$$D_0 = K_0,\qquad D_{k+1} = K_{k+1} - E^T D_k^{-1} E,$$

where $E^T D_k^{-1} E$ is the $(\lambda_k, \lambda_k)$ block of $D_k^{-1}$, subtracted from the
$(x_{k+1}, x_{k+1})$ block. By Sylvester's law the inertia of the matrix is the sum of those of
the pivots $D_k$: the count of negative pivot eigenvalues drives the inertia correction.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int


RUIZ_SWEEPS = 3
"""Sweeps of symmetric Ruiz equilibration of each pivot before its eigen-decomposition."""


def _lambda_slice(nx: int, nu: int) -> slice:
    return slice(nx + nu, 2 * nx + nu)


def block_factor(
    Kd: Float[Array, "M+1 nb nb"], nx: int, nu: int
) -> tuple[Float[Array, "M+1 nb"], Float[Array, "M+1 nb nb"], Int[Array, ""], Int[Array, ""]]:
    """Block $LDL^T$ of the block-tridiagonal KKT matrix with diagonal blocks ``Kd`` and
    sub-diagonal blocks all equal to the identity from $\\lambda_k$ (columns) to $x_{k+1}$
    (rows).

    **Returns:** the pivots' eigen-decompositions ``(W, V)`` (eigenvalues, and eigenvectors
    with the equilibration folded in: $D_k^{-1} = V_k \\operatorname{diag}(1/W_k) V_k^T$),
    the number of negative and the number of zero or non-finite pivot eigenvalues.

    Each pivot is equilibrated (symmetric Ruiz, a congruence: the inertia is kept) before its
    eigen-decomposition, so that graded pivots (barrier terms of 1e10 beside regularisations
    of 1e-9) keep their small eigenvalues."""
    lam_sl = _lambda_slice(nx, nu)

    def step(carry, Kk):
        D = Kk.at[:nx, :nx].add(-carry)
        D = 0.5 * (D + D.T)
        d = jnp.ones(D.shape[0])
        for _ in range(RUIZ_SWEEPS):
            r = jnp.max(jnp.abs(D * d[:, None] * d[None, :]), axis=1)
            d = d / jnp.sqrt(jnp.where(r > 0, r, 1.0))
        w, V = jnp.linalg.eigh(D * d[:, None] * d[None, :])
        V = V * d[:, None]  # D^{-1} = (dV) diag(1/w) (dV)^T
        Vl = V[lam_sl, :]
        winv = jnp.where(jnp.abs(w) > 0, 1.0 / jnp.where(w == 0, 1.0, w), 0.0)
        S = (Vl * winv[None, :]) @ Vl.T
        neg = jnp.sum(w < 0)
        tiny = jnp.sum(~jnp.isfinite(w)) + jnp.sum(w == 0)
        return S, (w, V, neg, tiny)

    _, (W, V, neg, tiny) = jax.lax.scan(step, jnp.zeros((nx, nx)), Kd)
    return W, V, jnp.sum(neg), jnp.sum(tiny)


def block_matvec(Kd: Float[Array, "M+1 nb nb"], v: Float[Array, "M+1 nb"], nx: int,
                 nu: int) -> Float[Array, "M+1 nb"]:
    """$K v$ for the block-tridiagonal KKT matrix (diagonal blocks and the
    $\\lambda_k$/$x_{k+1}$ identities)."""
    lam_sl = _lambda_slice(nx, nu)
    out = jnp.einsum("kij,kj->ki", Kd, v)
    out = out.at[1:, :nx].add(v[:-1, lam_sl])
    out = out.at[:-1, lam_sl].add(v[1:, :nx])
    return out


def block_solve(W: Float[Array, "M+1 nb"], V: Float[Array, "M+1 nb nb"],
                rhs: Float[Array, "M+1 nb"], nx: int, nu: int) -> Float[Array, "M+1 nb"]:
    """Solve $K x = $ ``rhs`` with the factor from `block_factor` (a forward and a backward
    block sweep)."""
    lam_sl = _lambda_slice(nx, nu)

    def dinv(w, v, r):
        winv = jnp.where(w == 0, 0.0, 1.0 / jnp.where(w == 0, 1.0, w))
        return v @ (winv * (v.T @ r))

    def fwd(carry, inp):
        w, v, r = inp
        y = r.at[:nx].add(-carry)
        return dinv(w, v, y)[lam_sl], y

    _, ys = jax.lax.scan(fwd, jnp.zeros((nx,)), (W, V, rhs))

    def bwd(carry, inp):
        w, v, y = inp
        y = y.at[lam_sl].add(-carry)
        sol = dinv(w, v, y)
        return sol[:nx], sol

    _, sols = jax.lax.scan(bwd, jnp.zeros((nx,)), (W, V, ys), reverse=True)
    return sols
