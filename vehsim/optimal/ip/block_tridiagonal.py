r"""The block-tridiagonal KKT matrix of a stage-structured NLP, kept as its stage blocks.

Ordering the unknowns per knot as $(y_k, \lambda_k, \nu_k)$, $y_k = (x_k, u_k)$, the rows of
knot $k$ are

$$W_k \Delta y_k - A_k^T \Delta\lambda_k + J_{e,k}^T \Delta\nu_k + E^T \Delta\lambda_{k-1}
= r_{y,k},$$
$$-A_k \Delta y_k + d_{\lambda,k} \Delta\lambda_k + \Delta x_{k+1} = r_{\lambda,k},\qquad
J_{e,k} \Delta y_k + d_{\nu,k} \Delta\nu_k = r_{\nu,k},$$

with $E = (I\ 0)$ picking $x_k$ out of $y_k$: block $k$ couples with block $k+1$ only through
the identity between $\lambda_k$ and $x_{k+1}$ (the defect $x_{k+1} - F_k = 0$). The
diagonals $d_\lambda$, $d_\nu$ are $0$ on the defect rows (the dynamics are eliminated
exactly), $-\delta_c$ on the boundary equalities and $-1$ on padded rows.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float


class KKTMatrix(eqx.Module):
    """The stage blocks of the KKT matrix: ``W`` (primal, regularised), ``A`` (transition
    Jacobians $\\partial F_k / \\partial y_k$, zero at $k = M$), ``Je`` (equality Jacobians),
    and the diagonals ``dl`` of the defect rows and ``de`` of the equality rows (negative or
    zero)."""

    W: Float[Array, "M+1 ny ny"]
    A: Float[Array, "M+1 nx ny"]
    Je: Float[Array, "M+1 ne ny"]
    dl: Float[Array, "M+1 nx"]
    de: Float[Array, "M+1 ne"]

    @property
    def nx(self) -> int:
        return self.A.shape[1]

    def split(self, v: Float[Array, "M+1 nb"]):
        """A stacked vector split into its $(y, \\lambda, \\nu)$ parts."""
        ny, nx = self.W.shape[1], self.nx
        return v[:, :ny], v[:, ny : ny + nx], v[:, ny + nx :]

    def matvec(self, v: Float[Array, "M+1 nb"], absolute: bool = False) -> Float[Array, "M+1 nb"]:
        """$K v$, or $|K|\\,|v|$ with ``absolute`` (for componentwise backward errors)."""
        f = jnp.abs if absolute else (lambda a: a)
        sign = 1.0 if absolute else -1.0
        W, A, Je = f(self.W), f(self.A), f(self.Je)
        y, lam, nu = (f(p) for p in self.split(v))
        nx = self.nx
        ry = (jnp.einsum("kij,kj->ki", W, y) + sign * jnp.einsum("kji,kj->ki", A, lam)
              + jnp.einsum("kji,kj->ki", Je, nu))
        ry = ry.at[1:, :nx].add(lam[:-1])
        rl = sign * jnp.einsum("kij,kj->ki", A, y) + f(self.dl) * lam
        rl = rl.at[:-1].add(y[1:, :nx])
        rn = jnp.einsum("kij,kj->ki", Je, y) + f(self.de) * nu
        return jnp.concatenate([ry, rl, rn], axis=1)
