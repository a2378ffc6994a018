r"""Normal-load densities $f_n(\zeta)$ over the contact patch $\zeta\in[0, L]$ (report Fig. 16a).

Every density here is *normalised*: with $\xi = \zeta/L$ it is $f_n(\zeta) = F_n\,q(\xi)/L$ with
$\int_0^1 q(\xi)\,d\xi = 1$, so the total load of eq. 44 is $F_n$ whatever the shape, and the
shape can be combined with a time-varying $F_n$. $\zeta = 0$ is the leading edge (where
bristles enter the patch, report footnote 2).

The shapes are functions of $\xi$ only; `q`, `dq` (its $\xi$-derivative) and, for the
polynomial ones, `coefficients` (the $c_k$ of eq. 43 in $\xi$) are what models use.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import check_range, is_concrete
from .._fields import array_field


class AbstractLoadDistribution(eqx.Module):
    r"""Normalised normal-load shape $q(\xi)$, $\xi=\zeta/L\in[0,1]$, $\int_0^1 q = 1$."""

    @abc.abstractmethod
    def q(self, xi: Float[Array, "*n"]) -> Float[Array, "*n"]:
        """Normalised density $q(\\xi)$."""

    @abc.abstractmethod
    def dq(self, xi: Float[Array, "*n"]) -> Float[Array, "*n"]:
        """Derivative $dq/d\\xi$."""

    def kinks(self) -> tuple:
        """Interior points of [0, 1] where the shape is not smooth (for piecewise quadrature)."""
        return ()

    def gauss_points(self, order: int) -> tuple[np.ndarray, np.ndarray]:
        """Gauss-Legendre points and weights on [0, 1], ``order`` per smooth piece (split at
        `kinks`): exact for polynomials of degree ``2 order - 1`` times the shape."""
        edges = np.unique(np.concatenate([[0.0, 1.0], np.asarray(self.kinks(), dtype=float)]))
        gx, gw = np.polynomial.legendre.leggauss(order)
        xs = [0.5 * (b - a) * gx + 0.5 * (a + b) for a, b in zip(edges[:-1], edges[1:])]
        ws = [0.5 * (b - a) * gw for a, b in zip(edges[:-1], edges[1:])]
        return np.concatenate(xs), np.concatenate(ws)

    def density(self, zeta, L, Fn=1.0):
        r"""$f_n(\zeta) = F_n\,q(\zeta/L)/L$ [N/m]."""
        return Fn * self.q(zeta / L) / L


def _normalised(owner: str, coefficients) -> Float[Array, " m"]:
    r"""$c_k / \sum_k c_k/(k+1)$, so that $\int_0^1 q = 1$; checked when concrete."""
    c = jnp.asarray(coefficients, dtype=float)
    if c.ndim != 1 or c.shape[0] == 0:
        raise ValueError(f"{owner}.coefficients must be a non-empty 1-D sequence")
    if is_concrete(c):
        cn = np.asarray(c)
        if not np.all(np.isfinite(cn)):
            raise ValueError(f"{owner}.coefficients must be finite, got {cn}")
        total = float(np.sum(cn / np.arange(1, cn.size + 1)))
        shape = np.polyval(cn[::-1], np.linspace(0.0, 1.0, 201))
        if total <= 0 or np.any(shape * np.sign(total) < -1e-12):
            raise ValueError(
                f"{owner}.coefficients must give a non-negative shape with positive "
                f"total load on [0, 1], got {cn}"
            )
    return c / jnp.sum(c / jnp.arange(1, c.shape[0] + 1))


class AbstractPolynomialLoad(AbstractLoadDistribution):
    r"""$q(\xi) = \sum_k c_k \xi^k$ (eq. 43 in the normalised coordinate), $\int_0^1 q = 1$.

    Subclasses store the normalised `coefficients` $c_0, \dots, c_m$; `q` and `dq` follow.
    """

    coefficients: eqx.AbstractVar[Float[Array, " m"]]

    def q(self, xi):
        return jnp.polyval(self.coefficients[::-1], xi)

    def dq(self, xi):
        c = self.coefficients
        k = jnp.arange(1, c.shape[0])
        return jnp.polyval((c[1:] * k)[::-1], xi) if c.shape[0] > 1 else jnp.zeros_like(xi)


class PolynomialLoad(AbstractPolynomialLoad):
    r"""A user polynomial $q(\xi) = \sum_k c_k \xi^k$, normalised on build.

    **Arguments:**

    - `coefficients`: $c_0, c_1, \dots, c_m$, any overall scale (they are divided by
      $\sum_k c_k/(k+1)$ so that $\int_0^1 q = 1$). The shape must be non-negative on [0, 1].
    """

    coefficients: Float[Array, " m"]

    def __init__(self, coefficients):
        self.coefficients = _normalised("PolynomialLoad", coefficients)


class UniformLoad(AbstractPolynomialLoad):
    r"""Uniform load $q(\xi) = 1$ (the case of eqs. 18-19)."""

    coefficients: Float[Array, " 1"]

    def __init__(self):
        self.coefficients = _normalised("UniformLoad", jnp.array([1.0]))


class QuarticLoad(AbstractPolynomialLoad):
    r"""Quartic load $q(\xi) = \tfrac54\,(1 - (2\xi-1)^4)$: flat in the middle, zero at both edges.

    Our reading of the report's "quartic" shape (Fig. 16a); it resembles the measured
    distributions of Fig. 16b (Zomotor 1987).
    """

    coefficients: Float[Array, " 5"]

    def __init__(self):
        # 1 - (2x-1)^4 expanded: 8x - 24x^2 + 32x^3 - 16x^4
        self.coefficients = _normalised("QuarticLoad", jnp.array([0.0, 8.0, -24.0, 32.0, -16.0]))


class TrapezoidalLoad(AbstractLoadDistribution):
    r"""Trapezoid: linear ramps over $\xi\in[0,\epsilon]$ and $[1-\epsilon,1]$, flat between.

    $q = h\,\min(1, \xi/\epsilon, (1-\xi)/\epsilon)$ with $h = 1/(1-\epsilon)$.
    `ramp` $=\epsilon\in(0, 1/2]$; $\epsilon = 1/2$ is the triangle.
    """

    ramp: Float[Array, ""] = array_field(default=0.25)

    def __check_init__(self):
        check_range("TrapezoidalLoad", "ramp", self.ramp, lower=0.0, upper=0.5, lower_open=True)

    def q(self, xi):
        h = 1.0 / (1.0 - self.ramp)
        return h * jnp.clip(jnp.minimum(xi, 1.0 - xi) / self.ramp, 0.0, 1.0)

    def dq(self, xi):
        h = 1.0 / (1.0 - self.ramp)
        up = jnp.where(xi < self.ramp, h / self.ramp, 0.0)
        down = jnp.where(xi > 1.0 - self.ramp, -h / self.ramp, 0.0)
        return up + down

    def kinks(self) -> tuple:
        return (self.ramp, 1.0 - self.ramp)


class TabulatedLoad(AbstractLoadDistribution):
    r"""A user-given (e.g. measured) shape, piecewise linear through samples $(\xi_j, q_j)$.

    The samples are rescaled so that $\int_0^1 q = 1$ (trapezoid rule, exact for this shape).
    """

    xi: Float[Array, " n"]
    values: Float[Array, " n"]

    def __init__(self, xi, values):
        xi = np.asarray(xi, dtype=float)
        values = np.asarray(values, dtype=float)
        if xi.ndim != 1 or xi.shape != values.shape or xi.size < 2:
            raise ValueError("TabulatedLoad.xi and .values must be 1-D of equal length >= 2")
        if not (np.all(np.isfinite(xi)) and np.all(np.isfinite(values))):
            raise ValueError("TabulatedLoad.xi and .values must be finite")
        if abs(xi[0]) > 1e-12 or abs(xi[-1] - 1.0) > 1e-12 or np.any(np.diff(xi) <= 0):
            raise ValueError("TabulatedLoad.xi must increase strictly from 0 to 1")
        if np.any(values < 0):
            raise ValueError("TabulatedLoad.values must be non-negative")
        total = np.trapezoid(values, xi) if hasattr(np, "trapezoid") else np.trapz(values, xi)
        if total <= 0:
            raise ValueError("TabulatedLoad.values must have a positive integral")
        self.xi = jnp.asarray(xi)
        self.values = jnp.asarray(values / total)

    def q(self, xi):
        return jnp.interp(xi, self.xi, self.values)

    def kinks(self) -> tuple:
        return tuple(self.xi[1:-1])

    def dq(self, xi):
        slopes = jnp.diff(self.values) / jnp.diff(self.xi)
        idx = jnp.clip(jnp.searchsorted(self.xi, xi, side="right") - 1, 0, slopes.shape[0] - 1)
        return slopes[idx]
