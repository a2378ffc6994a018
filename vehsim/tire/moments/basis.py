r"""The moment system of eqs. 41-48 as arrays: load pieces, basis tables and couplings.

A load polynomial on pieces $[e_j, e_{j+1}]$ (eq. 43) and a basis of the polynomials of
degree $< K$ on each piece give eqs. 41-42 and 46/48 as small linear maps per piece
(`basis_tables`); the transport and boundary couplings of all pieces together are the
nilpotent matrix $N$ of `coupling_matrix`. `MomentLuGre2D` builds these once.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..._checks import is_concrete
from ..load import AbstractLoadDistribution, AbstractPolynomialLoad, TrapezoidalLoad


BASES = ("legendre", "monomial")


def piecewise_coefficients(load: AbstractLoadDistribution, degree: int | None = None):
    r"""Edges $0 = e_0 < \dots < e_P = 1$ and monomial coefficients $c^{(j)}_k$ (in global
    $\xi$) with $q(\xi) = \sum_kc^{(j)}_k\xi^k$ on $[e_j, e_{j+1}]$ (eq. 43).

    Exact for an `AbstractPolynomialLoad` (uniform, quartic, user polynomials) and a
    `TrapezoidalLoad` (differentiable in the ramp). Any other load needs `degree`: each piece
    between its kinks is interpolated at `degree + 1` Chebyshev points (the Taylor-type
    approximation of eq. 43), and the moment model is then exact for that interpolant.

    **Returns:** `(edges (P+1,), coeffs (P, K))`.
    """
    if isinstance(load, AbstractPolynomialLoad):
        return _polynomial_pieces(load.coefficients, degree)
    if isinstance(load, TrapezoidalLoad):
        return _trapezoid_pieces(load.ramp)
    return _interpolated_pieces(load, degree)


def _polynomial_pieces(c, degree):
    """One piece, the coefficients padded with zeros up to `degree`."""
    if degree is not None and degree + 1 > c.shape[0]:
        c = jnp.concatenate([c, jnp.zeros(degree + 1 - c.shape[0])])
    return jnp.array([0.0, 1.0]), c[None, :]


def _trapezoid_pieces(eps):
    r"""Ramp up on $[0, \epsilon]$, flat, ramp down on $[1-\epsilon, 1]$, height $1/(1-\epsilon)$;
    the triangle ($\epsilon = 1/2$, given as a number) as its two ramps (a flat piece of zero
    width would divide the Legendre tables by its width)."""
    h = 1.0 / (1.0 - eps)
    zero = jnp.zeros(())
    if is_concrete(eps) and float(eps) == 0.5:
        coeffs = jnp.stack([jnp.stack([zero, h / eps]), jnp.stack([h / eps, -h / eps])])
        return jnp.stack([zero, jnp.asarray(eps, float), jnp.ones(())]), coeffs
    coeffs = jnp.stack([
        jnp.stack([zero, h / eps]),
        jnp.stack([h, zero]),
        jnp.stack([h / eps, -h / eps]),
    ])
    edges = jnp.stack([zero, eps, 1.0 - eps, jnp.ones(())])
    return edges, coeffs


def _interpolated_pieces(load, degree):
    """Chebyshev interpolation of degree `degree` between the load's kinks."""
    if degree is None:
        raise ValueError(
            f"MomentLuGre2D.degree is required for a {type(load).__name__} (a load that is not "
            "piecewise polynomial): give the polynomial degree per piece, >= 0"
        )
    if int(degree) < 0:
        raise ValueError(f"MomentLuGre2D.degree must be >= 0, got {degree}")
    edges = np.unique(np.concatenate([[0.0, 1.0], np.asarray(load.kinks(), dtype=float)]))
    coeffs = []
    for a, b in zip(edges[:-1], edges[1:]):
        t = np.cos(np.pi * (np.arange(degree + 1) + 0.5) / (degree + 1))
        x = 0.5 * (a + b) + 0.5 * (b - a) * t
        V = np.vander(x, degree + 1, increasing=True)
        coeffs.append(np.linalg.solve(V, np.asarray(load.q(jnp.asarray(x)))))
    return jnp.asarray(edges), jnp.asarray(np.stack(coeffs))


def powers(x, K):
    """x**k for k = 0..K-1 along a new last axis (integer powers: finite gradients at 0)."""
    return jnp.stack([jnp.ones_like(x)] + [x**k for k in range(1, K)], axis=-1)


def lever_arm(edges, coeffs):
    r"""$\int_0^1 q\,(\tfrac12 - \xi)\,d\xi$ from the piece coefficients (exact, differentiable)."""
    K = coeffs.shape[1]
    a, b = edges[:-1], edges[1:]
    ints = (powers(b, K + 2)[:, 1:] - powers(a, K + 2)[:, 1:]) / jnp.arange(1, K + 2)[None, :]
    return jnp.sum(coeffs * (0.5 * ints[:, :K] - ints[:, 1:]))


def legendre_tables(K):
    r"""Shifted Legendre polynomials $\tilde P_k(x) = P_k(2x-1)$ on $[0, 1]$, $k < K$: Gauss
    nodes and weights on $[0, 1]$ exact to degree $2K+1$, the values $\tilde P_k(x_g)$
    (K, G), and the derivative map $\tilde P_k' = \sum_{l<k,\ k-l\ \text{odd}}
    2(2l+1)\tilde P_l$ as a strictly lower-triangular matrix (K, K)."""
    x, w = np.polynomial.legendre.leggauss(K + 1)
    x, w = 0.5 * (x + 1.0), 0.5 * w
    vals = np.stack([np.polynomial.legendre.legval(2 * x - 1, np.eye(K)[k]) for k in range(K)])
    k, j = np.meshgrid(np.arange(K), np.arange(K), indexing="ij")
    deriv = np.where((j < k) & ((k - j) % 2 == 1), 2.0 * (2 * j + 1), 0.0)
    return x, w, vals, deriv


def basis_tables(edges, coeffs, K: int, basis: str):
    r"""The moment system of eqs. 41-42 and 46/48 in `basis`, as arrays per piece.

    For moments $\mu_k$ of $z$ against basis functions $\phi^{(j)}_k$ on piece $j$, eq. 31a
    integrated by parts gives, in both bases,
    $$\dot\mu = v_r\,s - C_0\mu - \frac cL\bigl(z(t,b)\,\rho - z(t,a)\,\lambda\bigr)
      + \frac cL\,T\mu,\qquad \frac{F}{F_n} = w_F\cdot(\sigma_0\mu + \sigma_1\dot\mu)
      + \sigma_2v_r,$$
    with $s_k = \int\phi_k$, $\rho_k = \phi_k(b)$, $\lambda_k = \phi_k(a)$, $T$ the map of
    $\phi_k'$ onto the basis, $w_F$ the coefficients of $q$ and $w_M$ those of
    $q(\tfrac12-\xi)$ (for $M_z$). **Monomial** (eqs. 41-42 verbatim): $\phi_k = \xi^k$,
    $s_k = (b^{k+1}-a^{k+1})/(k+1)$, $\rho_k = b^k$, $\lambda_k = a^k$, $T_{k,k-1} = k$.
    **Legendre**: $\phi_k = \tilde P_k((\xi-a)/h)/h$, $h = b - a$, so
    $\mu_k = \int_0^1 z(a+hx)\tilde P_k(x)\,dx$, $s_k = \delta_{k0}$, $\rho_k = 1/h$,
    $\lambda_k = (-1)^k/h$, $T = $ (derivative map)$/h$; $w_{F,k} = h(2k+1)\int_0^1
    q(a+hx)\tilde P_k\,dx$ (exact Gauss projection of the polynomial load).

    **Returns:** `(src, right, left, transport, w_force, w_moment)`, shapes
    `(P,K), (P,K), (P,K), (P,K,K), (P,K), (P,K)`.
    """
    if basis == "monomial":
        return _monomial_tables(edges, coeffs, K)
    return _legendre_basis_tables(edges, coeffs, K)


def _monomial_tables(edges, coeffs, K):
    a, b = edges[:-1], edges[1:]
    P, m1 = coeffs.shape
    pa, pb = powers(a, K + 1), powers(b, K + 1)
    src = (pb[:, 1:] - pa[:, 1:]) / jnp.arange(1, K + 1)[None, :]
    shift = np.diag(np.arange(1.0, K), -1)
    transport = jnp.broadcast_to(jnp.asarray(shift), (P, K, K))
    zero = jnp.zeros((P, K - m1))
    w_force = jnp.concatenate([coeffs, zero], axis=1)
    prev = jnp.concatenate([jnp.zeros((P, 1)), coeffs, zero[:, 1:]], axis=1)
    w_moment = 0.5 * w_force - prev
    return src, pb[:, :K], pa[:, :K], transport, w_force, w_moment


def _legendre_basis_tables(edges, coeffs, K):
    a, b = edges[:-1], edges[1:]
    P, m1 = coeffs.shape
    x, w, vals, deriv = legendre_tables(K)
    h = b - a
    xi = a[:, None] + h[:, None] * jnp.asarray(x)[None, :]  # (P, G)
    q = jnp.sum(coeffs[:, None, :] * powers(xi, m1), axis=-1)
    proj = jnp.asarray((2 * np.arange(K) + 1)[:, None] * vals * w[None, :])  # (K, G)
    w_force = h[:, None] * (q @ proj.T)
    w_moment = h[:, None] * ((q * (0.5 - xi)) @ proj.T)
    ones = jnp.ones((P, K))
    src = ones * jnp.asarray(np.eye(K)[0])[None, :]
    right = ones / h[:, None]
    left = jnp.asarray((-1.0) ** np.arange(K))[None, :] / h[:, None]
    transport = jnp.asarray(deriv)[None, :, :] / h[:, None, None]
    return src, right, left, transport, w_force, w_moment


def coupling_matrix(transport, right, left):
    r"""$N$ of `moments_step_response`: eqs. 41-42 less the decay and the sources, per axis, on
    $Y = (\mu^{(0)}, \dots, \mu^{(P-1)}, z_{e_1}, \dots, z_{e_P})$ (moments of each piece, then the
    deflection at each piece's right edge): $\dot\mu^{(j)} \ni \lambda\bigl(T_j\mu^{(j)}
    - \rho_j z_{e_{j+1}} + \lambda_j z_{e_j}\bigr)$, $z_{e_0} = 0$ (`basis_tables`).
    Strictly block lower triangular, so $N^{K+1} = 0$. **Returns:** `(D, D)`, $D = PK + P$."""
    P, K = right.shape
    eye = jnp.eye(P)
    Nmm = jnp.einsum("jkl,jJ->jkJl", transport, eye).reshape(P * K, P * K)
    Nme = (-right[:, :, None] * eye[:, None, :]
           + left[:, :, None] * jnp.eye(P, k=-1)[:, None, :]).reshape(P * K, P)
    top = jnp.concatenate([Nmm, Nme], axis=1)
    return jnp.concatenate([top, jnp.zeros((P, P * K + P))], axis=0)


def coupling_powers(N, K: int):
    r"""$N^0, \dots, N^K$ stacked, shape `(K+1, D, D)` (all the nonzero powers of $N$)."""
    out = [jnp.eye(N.shape[0])]
    for _ in range(K):
        out.append(N @ out[-1])
    return jnp.stack(out)


def response_rows(w_force, w_moment, src, npow):
    r"""The load rows $w_cN^i$ of eqs. 46/48 ($c$ = $F_x$, $F_y$ from `w_force`, $M_z$ from
    `w_moment`; no weight on the edge deflections), for $N^i$ = `npow` (K+1, D, D), applied
    to the source pattern (the moments' `src`, 1 at every edge) and to each edge deflection.

    **Returns:** `(source (3, K+1), edges (3, K+1, P))`."""
    P, K = w_force.shape
    w = jnp.concatenate([jnp.stack([w_force.ravel()] * 2 + [w_moment.ravel()]),
                         jnp.zeros((3, P))], axis=1)  # (3, D)
    rows = jnp.einsum("cd,ide->cie", w, npow)  # (3, K + 1, D)
    source = rows @ jnp.concatenate([src.ravel(), jnp.ones(P)])
    return source, rows[..., P * K:]
