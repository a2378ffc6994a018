r"""Longitudinal LuGre friction: parameters, Stribeck function, point and lumped models.

Conventions used by every longitudinal model in `vehsim.tire`:

- $v$ is the wheel-centre speed, $\omega$ the wheel angular speed, $r$ the rolling radius;
  $v_r = r\omega - v$ is the relative velocity (report, after eq. 10).
- Models return the *normalised* force $\mu = F/F_n$; $F>0$ accelerates the vehicle
  (driving, $v_r>0$), $F<0$ decelerates it (braking).
- The road condition $\theta$ (Canudas de Wit and Tsiotras 1999) scales the decay term:
  $\dot z = v_r - \theta\sigma_0|v_r|z/g(v_r)$; $\theta = 1$ is the report's model.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float

from .._checks import check_count, check_order, check_positive, check_range, check_type
from .._fields import array_field
from .._math import safe_abs, safe_pow_abs


class LuGreParams(eqx.Module):
    r"""Parameters of the longitudinal LuGre models (eqs. 8-14, 22-25).

    **Fields** (SI units):

    - `sigma0` [1/m]: rubber longitudinal lumped stiffness $\sigma_0 > 0$.
    - `sigma1` [s/m]: rubber longitudinal lumped damping $\sigma_1 \ge 0$.
    - `sigma2` [s/m]: viscous relative damping $\sigma_2 \ge 0$.
    - `mu_c`, `mu_s` [-]: Coulomb and static friction, $0 < \mu_c \le \mu_s$.
    - `v_s` [m/s]: Stribeck relative velocity $v_s > 0$.
    - `alpha` [-]: Stribeck exponent of eq. 10 (1/2 in the report, footnote 1).
    - `theta` [-]: road-condition factor (1 = the report's model; larger = more slippery).
    - `L` [m]: contact-patch length (distributed and lumped models only).

    All fields are arrays, so new values never trigger a recompile, and a batch of
    parameter sets is just a `LuGreParams` with leading batch axes (use `jax.vmap`).
    """

    sigma0: Float[Array, ...] = array_field()
    sigma1: Float[Array, ...] = array_field()
    sigma2: Float[Array, ...] = array_field()
    mu_c: Float[Array, ...] = array_field()
    mu_s: Float[Array, ...] = array_field()
    v_s: Float[Array, ...] = array_field()
    alpha: Float[Array, ...] = array_field(default=0.5)
    theta: Float[Array, ...] = array_field(default=1.0)
    L: Float[Array, ...] = array_field(default=0.2)

    def __check_init__(self):
        owner = "LuGreParams"
        check_positive(owner, "sigma0", self.sigma0)
        check_range(owner, "sigma1", self.sigma1, lower=0.0)
        check_range(owner, "sigma2", self.sigma2, lower=0.0)
        check_positive(owner, "mu_c", self.mu_c)
        check_positive(owner, "mu_s", self.mu_s)
        check_order(owner, "mu_c", self.mu_c, "mu_s", self.mu_s)
        check_positive(owner, "v_s", self.v_s)
        check_positive(owner, "alpha", self.alpha)
        check_positive(owner, "theta", self.theta)
        check_positive(owner, "L", self.L)


def stribeck(params: LuGreParams, v_r):
    r"""$g(v_r) = \mu_c + (\mu_s-\mu_c)\,e^{-|v_r/v_s|^\alpha}$ (eq. 10).

    Finite value and gradient (in $v_r$ and every parameter) at $v_r = 0$.
    """
    return params.mu_c + (params.mu_s - params.mu_c) * jnp.exp(
        -safe_pow_abs(v_r / params.v_s, params.alpha)
    )


def decay_rate(params: LuGreParams, v_r):
    r"""$\theta\sigma_0|v_r|/g(v_r)$, the bristle decay rate of eq. 8 [1/s]."""
    return params.theta * params.sigma0 * safe_abs(v_r) / stribeck(params, v_r)


def relative_velocity(v, omega, r):
    r"""$v_r = r\omega - v$."""
    return r * omega - v


def relaxed_deflection_rate(u, v, omega, r, relaxation_length):
    r"""$\dot u = v_r - |v|\,u/\sigma$: the carcass deflection $u$ [m] of a tire whose
    transient slip $u/\sigma$ relaxes over the length $\sigma$ towards $v_r/|v|$."""
    return relative_velocity(v, omega, r) - safe_abs(v) * u / relaxation_length


class AbstractLongitudinalTire(eqx.Module):
    r"""A longitudinal tire friction model with internal friction state.

    Subclasses provide `init_state`, `dynamics` (the state's time derivative, driven by
    $v$, $\omega$, $r$) and `mu` (the normalised force $F/F_n$).

    **Steady state.** `steady_state` is the state at rest under constant $v$, $\omega$,
    $r$ (``dynamics = 0``), `steady_state_mu` the force there and `braking_mu` the same at
    braking slip $s = r\omega/v - 1$: by default computed (`solve_steady_state`, Newton
    from the undeflected state), overridden by the closed forms of the models that have
    one (eq. 19 for `UniformLumpedLuGre`, eqs. 22-23 at rest for `LumpedLuGre`, the
    formula for `RelaxedMagicFormula`, one linear solve for `DistributedLuGre`).
    """

    params: eqx.AbstractVar[LuGreParams]

    @abc.abstractmethod
    def init_state(self):
        """Undeflected friction state."""

    @abc.abstractmethod
    def dynamics(self, state, v, omega, r):
        """Time derivative of the friction state."""

    @abc.abstractmethod
    def mu(self, state, v, omega, r):
        """Normalised friction force $F/F_n$."""

    def steady_state(self, v, omega, r):
        """The friction state at rest under constant `v`, `omega`, `r` (by default
        `solve_steady_state`)."""
        return solve_steady_state(self, v, omega, r)

    def steady_state_mu(self, v, omega, r):
        """Steady-state $F/F_n$ under constant `v`, `omega`, `r`: `mu` at `steady_state`."""
        return self.mu(self.steady_state(v, omega, r), v, omega, r)

    def braking_mu(self, s, v, r):
        r"""Steady-state $F/F_n$ at braking slip $s\in[-1, 0]$ and speed $v > 0$:
        `steady_state_mu` at $\omega = (1 + s)v/r$."""
        return self.steady_state_mu(v, (1.0 + s) * v / r, r)


NEWTON_STEPS = 3
"""Newton steps of `solve_steady_state` (one is exact for the dynamics linear in the state
of every model in `vehsim.tire`)."""


def solve_steady_state(tire: AbstractLongitudinalTire, v, omega, r, steps: int = NEWTON_STEPS):
    r"""The state $z$ with ``tire.dynamics(z, v, omega, r)`` $= 0$, by `steps` Newton steps
    from ``tire.init_state()`` (the Jacobian by forward-mode differentiation).

    The steps are unrolled and differentiated through, so derivatives of every order with
    respect to $v$, $\omega$, $r$ and the tire's fields are those of the converged state
    (exact after one step for dynamics linear in the state: $\dot z = b - Az$ gives
    $z = A^{-1}b$). A component with no restoring dynamics (a zero row of the Jacobian,
    e.g. a point contact at rest, $v_r = 0$) keeps its initial value. Jit-, vmap- and
    grad-safe; any state pytree (scalar or vector, e.g. `DistributedLuGre`'s nodes).
    """
    check_count("solve_steady_state", "steps", steps, sep=": ")
    z, unravel = ravel_pytree(tire.init_state())
    if z.size == 0:
        return unravel(z)

    def rates(x):
        return ravel_pytree(tire.dynamics(unravel(x), v, omega, r))[0]

    eye = jnp.eye(z.size, dtype=z.dtype)
    for _ in range(steps):
        f, J = rates(z), jax.jacfwd(rates)(z)
        held = jnp.all(J == 0, axis=1)
        J = jnp.where(held[:, None], eye, J)
        z = z - jnp.linalg.solve(J, jnp.where(held, 0.0, f))
    return unravel(z)


class PointLuGre(AbstractLongitudinalTire):
    r"""Point-contact LuGre (eqs. 8-10).

    $$\dot z = v_r - \frac{\theta\sigma_0|v_r|}{g(v_r)}z,\qquad
      F = (\sigma_0 z + \sigma_1\dot z + \sigma_2 v_r)F_n.$$
    """

    params: LuGreParams

    def init_state(self):
        return jnp.zeros(())

    def dynamics(self, state, v, omega, r):
        v_r = relative_velocity(v, omega, r)
        return v_r - decay_rate(self.params, v_r) * state

    def mu(self, state, v, omega, r):
        p = self.params
        zdot = self.dynamics(state, v, omega, r)
        return p.sigma0 * state + p.sigma1 * zdot + p.sigma2 * relative_velocity(v, omega, r)


class LumpedLuGre(AbstractLongitudinalTire):
    r"""Average lumped LuGre (eqs. 22-23) with $\kappa = \kappa_0/L$ (eq. 25).

    $$\dot{\bar z} = v_r - \frac{\theta\sigma_0|v_r|}{g(v_r)}\bar z - \kappa|\omega r|\bar z,\qquad
      F = (\sigma_0\bar z + \sigma_1\dot{\bar z} + \sigma_2 v_r)F_n.$$

    `dynamics` and `mu` accept an explicit `kappa` [1/m] (e.g. the exact eq. 24 value from
    `DistributedLuGre.kappa`); by default $\kappa = \kappa_0/L$.

    **Arguments:**

    - `params`: `LuGreParams`.
    - `kappa0`: dimensionless $\kappa_0$, in [1, 2] in the report (any positive value allowed).
    """

    params: LuGreParams
    kappa0: Float[Array, ...] = array_field(default=1.0)

    def __check_init__(self):
        check_type("LumpedLuGre", "params", self.params, LuGreParams)
        check_range("LumpedLuGre", "kappa0", self.kappa0, lower=0.0)

    def init_state(self):
        return jnp.zeros(())

    def dynamics(self, state, v, omega, r, kappa=None):
        p = self.params
        kappa = self.kappa0 / p.L if kappa is None else kappa
        v_r = relative_velocity(v, omega, r)
        return v_r - decay_rate(p, v_r) * state - kappa * safe_abs(omega * r) * state

    def mu(self, state, v, omega, r, kappa=None):
        p = self.params
        zdot = self.dynamics(state, v, omega, r, kappa)
        return p.sigma0 * state + p.sigma1 * zdot + p.sigma2 * relative_velocity(v, omega, r)

    def steady_state_mu(self, v, omega, r, kappa=None):
        r"""Steady state of eqs. 22-23: $\bar z_{ss} = v_r/(\theta\sigma_0|v_r|/g + \kappa|\omega r|)$."""
        p = self.params
        kappa = self.kappa0 / p.L if kappa is None else kappa
        v_r = relative_velocity(v, omega, r)
        g = stribeck(p, v_r)
        # z_ss = v_r g / (theta sigma0 |v_r| + kappa |w r| g): smooth through v_r = 0 when rolling.
        den = p.theta * p.sigma0 * safe_abs(v_r) + kappa * safe_abs(omega * r) * g
        is_zero = den == 0
        z = jnp.where(is_zero, 0.0, v_r * g / jnp.where(is_zero, 1.0, den))
        return p.sigma0 * z + p.sigma2 * v_r
