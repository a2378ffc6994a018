r"""`MomentLuGre2D`: the moment system of eqs. 39-48 as a tire with the online closure.

State `(m, z_edge, s)`: moments `m` (in `basis`) of shape `(2, P, K)` (P pieces,
K = load degree + 2), edge deflections `z_edge` of shape `(2, P)` (the right edge of every
piece) and the travelled distance `s` (in patch lengths). The edge equations close the
arrival term with the inputs frozen over a transit (`vehsim.tire.moments`, "Online").
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..._checks import check_integer
from ..._math import floor_transport
from ..load import AbstractLoadDistribution, UniformLoad
from ..lugre2d import AbstractPatchLuGre2D, LuGre2DParams, decay_rates
from .basis import (
    BASES,
    basis_tables,
    coupling_matrix,
    coupling_powers,
    lever_arm,
    piecewise_coefficients,
    response_rows,
)


MAX_DEGREE = 12
r"""The highest polynomial degree per piece of `MomentLuGre2D`. Its tables hold monomial
coefficients in the global $\xi$ and the powers of the coupling matrix, whose entries grow
as $K!$: at degree 12 the forces of a quartic load padded to that degree equal the exact
degree's to 5e-11, at 14 to 4e-8, at 16 to 1e-3, and from 20 on they are garbage."""


class MomentLuGre2D(AbstractPatchLuGre2D):
    r"""Method-of-moments model of the distributed 2D LuGre tire (eqs. 39-48).

    See `vehsim.tire.moments` for the equations, the basis, and when the moment system is
    exact.

    **Arguments:**

    - `params`: `LuGre2DParams`.
    - `load`: normalised load shape (default uniform); polynomial and trapezoidal loads are
      represented exactly.
    - `degree`: polynomial degree per piece for other loads (see `piecewise_coefficients`),
      at most `MAX_DEGREE`.
    - `basis`: `"legendre"` (default; shifted Legendre moments per piece, well conditioned)
      or `"monomial"` (the report's $\int z\xi^p$ of eq. 39). The same moment system in two
      bases (`basis_tables`): both are exact; they differ in rounding and in how the
      solver's error control sees the state.

    Besides the tables of `basis_tables` the model keeps the powers $N^i$ of the coupling
    matrix and the load rows $w_cN^i$ (`response_rows`) that `moments_step_response` needs.
    """

    params: LuGre2DParams
    load: AbstractLoadDistribution
    edges: Float[Array, " P1"]
    coeffs: Float[Array, "P K"]
    lever: Float[Array, ""]
    src: Float[Array, "P K"]
    right: Float[Array, "P K"]
    left: Float[Array, "P K"]
    transport: Float[Array, "P K K"]
    w_force: Float[Array, "P K"]
    w_moment: Float[Array, "P K"]
    coupling_powers: Float[Array, "K1 D D"]
    response_source: Float[Array, "3 K1"]
    response_edges: Float[Array, "3 K1 P"]
    n_moments: int = eqx.field(static=True)
    basis: str = eqx.field(static=True)

    def __init__(self, params: LuGre2DParams, load: AbstractLoadDistribution | None = None,
                 degree: int | None = None, basis: str = "legendre"):
        if basis not in BASES:
            raise ValueError(f"MomentLuGre2D.basis must be one of {BASES}, got {basis!r}")
        self.params = params
        self.load = UniformLoad() if load is None else load
        self.basis = basis
        if degree is not None:
            check_integer("MomentLuGre2D", "degree", degree)
            if degree > MAX_DEGREE:
                raise ValueError(f"MomentLuGre2D.degree must be at most {MAX_DEGREE} (the "
                                 f"moment tables' conditioning), got {degree}")
        self.edges, self.coeffs = piecewise_coefficients(self.load, degree)
        if self.coeffs.shape[1] - 1 > MAX_DEGREE:
            raise ValueError(f"MomentLuGre2D: the load's polynomial degree "
                             f"{self.coeffs.shape[1] - 1} exceeds {MAX_DEGREE} (the moment "
                             "tables' conditioning)")
        self.n_moments = int(self.coeffs.shape[1]) + 1
        self.lever = lever_arm(self.edges, self.coeffs)
        (self.src, self.right, self.left, self.transport, self.w_force,
         self.w_moment) = basis_tables(self.edges, self.coeffs, self.n_moments, basis)
        N = coupling_matrix(self.transport, self.right, self.left)
        self.coupling_powers = coupling_powers(N, self.n_moments)
        self.response_source, self.response_edges = response_rows(
            self.w_force, self.w_moment, self.src, self.coupling_powers)

    @property
    def pieces(self) -> int:
        return int(self.coeffs.shape[0])

    def init_state(self, z0=None):
        r"""State of the uniform deflection `z0` (default 0), shape (2,) [m]."""
        z0 = jnp.zeros(2) if z0 is None else jnp.asarray(z0, dtype=float)
        z_edge = jnp.broadcast_to(z0[:, None], (2, self.pieces))
        return (z0[:, None, None] * self.src[None, :, :], z_edge, jnp.zeros(()))

    def edge_values(self, state):
        r"""$z_i(t, e_j)$ at every piece edge, shape `(2, P+1)` ($z = 0$ at the leading edge)."""
        z_edge = state[1]
        return jnp.concatenate([jnp.zeros_like(z_edge[:, :1]), z_edge], axis=1)

    def moment_rates(self, m, zedge, v_r, c):
        r"""Eqs. 41-42 (in `self.basis`, `basis_tables`) for moments `m` (2, P, K) given the
        deflections at every piece edge, `zedge` (2, P+1) (leading edge first)."""
        C0 = decay_rates(self.params, v_r)
        boundary = (zedge[:, 1:, None] * self.right[None, :, :]
                    - zedge[:, :-1, None] * self.left[None, :, :])
        lower = jnp.einsum("jkl,ijl->ijk", self.transport, m)
        return (
            v_r[:, None, None] * self.src[None, :, :]
            - C0[:, None, None] * m
            + (c / self.params.L) * (lower - boundary)
        )

    def derivative(self, state, v_r, c):
        r"""Time derivative of `(m, z_edge, s)` (eqs. 41-42 and the edge equations)."""
        m, z_edge, s = state
        C0 = decay_rates(self.params, v_r)
        b = self.edges[1:]
        m_dot = self.moment_rates(m, self.edge_values(state), v_r, c)
        # Edge equations: point model minus the (frozen) arrival of undeflected tread.
        rolling = c > 0
        c_safe = floor_transport(jnp.where(rolling, c, 1.0))
        decay = jnp.exp(-(C0 * self.params.L / c_safe)[:, None] * b[None, :])
        arrived = (s >= b)[None, :] & rolling
        arrival = jnp.where(arrived, decay * v_r[:, None], 0.0)
        z_edge_dot = v_r[:, None] - C0[:, None] * z_edge - arrival
        return (m_dot, z_edge_dot, c / self.params.L)

    def mu_from_moments(self, m, m_dot, v_r):
        r"""$(F_x/F_n, F_y/F_n, M_z/(F_nL))$ from the moments and their rates (eqs. 46, 48)."""
        p = self.params
        agg = p.sigma0[:, None, None] * m + p.sigma1[:, None, None] * m_dot  # (2, P, K)
        f = jnp.sum(self.w_force[None, :, :] * agg, axis=(1, 2)) + p.sigma2 * v_r
        mz = jnp.sum(self.w_moment * agg[1]) + p.sigma2[1] * v_r[1] * self.lever
        return jnp.stack([f[0], f[1], mz])

    def mu(self, state, v_r, c):
        r"""$(F_x/F_n, F_y/F_n, M_z/(F_nL))$ (eqs. 46 and 48, our sign)."""
        return self.mu_from_moments(state[0], self.derivative(state, v_r, c)[0], v_r)

    def mean_deflection(self, state):
        r"""$\bar z_i = \int_0^1 z_i q\,d\xi$ (eq. 20 per axis) [m]."""
        return jnp.sum(self.w_force[None, :, :] * state[0], axis=(1, 2))
