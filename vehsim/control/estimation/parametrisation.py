r"""What an estimator assumes: a tire model and the parameters of it that it estimates.

An estimator of the road (`FrictionObserver`, `MovingHorizonEstimator`) works on the
logarithms $u$ of a few parameters of an assumed tire; a parametrisation maps $u$ to the
tire it then believes in (`belief`), which the controllers read their targets off
(`vehsim.control.controllers.braking`). Two families:

- `RoadCondition`: a LuGre tire (any tire whose `params` are `LuGreParams`:
  `UniformLumpedLuGre`, `LumpedLuGre` with constant $\kappa_0$, `DistributedLuGre`) with
  its road condition $\theta$ estimated (Canudas de Wit and Tsiotras 1999: the friction
  level scales as $g/\theta$), optionally with $\mu_s$ or $\mu_c$.
- `FrictionScale`: any tire (a Magic Formula, a LuGre tire on a fixed road) with its force
  scaled by $\lambda$ (`ScaledFriction`, the Magic Formula's $\lambda_{\mu x}$), optionally
  with its slip axis stretched by $\rho$ (the peak slip moves to $\rho s^*$).

An estimator is only as right as its assumed shape: on data from another tire it returns the
parameter of the assumed tire that fits best, not the true peak (a uniform-load LuGre
assumed for a constant-$\kappa_0$ tire reads $\theta$ 10 % high on Table 3's dry road
with $\kappa_0$ = 2, `vehsim.control.experiments.estimators`).
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float

from ..._fields import array_field
from ...tire.lugre import AbstractLongitudinalTire, LuGreParams
from ...tire.scaled import ScaledFriction
from ...tire.uniform_lumped import UniformLumpedLuGre


ROAD_CONDITION_NAMES = ("theta", "mu_s", "mu_c")
FRICTION_SCALE_NAMES = ("scale", "slip_scale")


class AbstractRoadParametrisation(eqx.Module):
    r"""The assumed tire as a function of the log-parameters $u$ an estimator estimates."""

    @property
    @abc.abstractmethod
    def names(self) -> tuple[str, ...]:
        """The estimated parameters, in the order of $u$ (the first is the road's)."""

    @abc.abstractmethod
    def prior(self) -> Float[Array, " p"]:
        """$u$ at the prior: the logs of the assumed tire's own values."""

    @abc.abstractmethod
    def belief(self, log_values: Float[Array, " p"]) -> AbstractLongitudinalTire:
        """The tire at $u$ = `log_values`."""

    @abc.abstractmethod
    def prior_with(self, value) -> AbstractLongitudinalTire:
        """The tire at the prior with the first parameter set to `value` (not its log)."""

    @abc.abstractmethod
    def state_scale(self):
        """A typical magnitude of the tire's friction state (scales an estimator's unknown
        initial state)."""


def _check_free(owner, free, names):
    if not free or free[0] != names[0] or not set(free) <= set(names) or len(set(free)) != len(
            free):
        raise ValueError(f"{owner}.free must start with {names[0]!r} and name each of "
                         f"{names} at most once, got {free}")


class RoadCondition(AbstractRoadParametrisation):
    r"""The road condition $\theta$ of a LuGre `tire` (its `params` are `LuGreParams`; its
    $\theta$ is the prior), and with it the names in `free` (static; a tuple starting with
    ``"theta"``, of ``("theta", "mu_s", "mu_c")``). Freeing $\mu_s$ and $\mu_c$ together with
    $\theta$ is degenerate (only $\mu_s/\theta$ and $\mu_c/\theta$ act on the force)."""

    tire: AbstractLongitudinalTire
    free: tuple[str, ...] = eqx.field(static=True, default=("theta",))

    def __check_init__(self):
        if not isinstance(self.tire.params, LuGreParams):
            raise TypeError(f"RoadCondition.tire must be a LuGre tire (params LuGreParams), "
                            f"got {type(self.tire).__name__}; use FrictionScale")
        _check_free("RoadCondition", self.free, ROAD_CONDITION_NAMES)

    @property
    def names(self):
        return self.free

    def prior(self):
        return jnp.stack([jnp.log(getattr(self.tire.params, n)) for n in self.free])

    def belief(self, log_values):
        return eqx.tree_at(lambda t: [getattr(t.params, n) for n in self.free], self.tire,
                           [jnp.exp(log_values[i]) for i in range(len(self.free))])

    def prior_with(self, value):
        return eqx.tree_at(lambda t: t.params.theta, self.tire, value)

    def state_scale(self):
        r"""$\mu_s/(\theta\sigma_0)$: the bristles' sliding deflection."""
        p = self.tire.params
        return p.mu_s / (p.theta * p.sigma0)


class FrictionScale(AbstractRoadParametrisation):
    r"""The friction scale $\lambda$ of any `tire` (`ScaledFriction`; prior `scale`, 1),
    and with it the slip scale $\rho$ if `free` (static) is ``("scale", "slip_scale")``
    (prior `slip_scale`, 1). $\rho$ is identifiable only from data past the knee of the
    curve (below it all roads share the initial slope $\lambda/\rho$ times the tire's)."""

    tire: AbstractLongitudinalTire
    scale: Float[Array, ""] = array_field(default=1.0)
    slip_scale: Float[Array, ""] = array_field(default=1.0)
    free: tuple[str, ...] = eqx.field(static=True, default=("scale",))

    def __check_init__(self):
        _check_free("FrictionScale", self.free, FRICTION_SCALE_NAMES)

    @property
    def names(self):
        return self.free

    def prior(self):
        return jnp.stack([jnp.log(getattr(self, n)) for n in self.free])

    def belief(self, log_values):
        values = {"scale": self.scale, "slip_scale": self.slip_scale}
        values.update({n: jnp.exp(log_values[i]) for i, n in enumerate(self.free)})
        return ScaledFriction(self.tire, values["scale"], values["slip_scale"])

    def prior_with(self, value):
        return ScaledFriction(self.tire, value, self.slip_scale)

    def state_scale(self):
        """The tire's steady friction state at braking slip -0.05 from 20 m/s (r = 0.3 m):
        one Newton step from the undeflected state (exact for states linear in it)."""
        v, r = 20.0, 0.3
        z = steady_state(self.tire, v, 0.95 * v / r, r)
        return jnp.maximum(jnp.max(jnp.abs(ravel_pytree(z)[0])), 1e-12)


def steady_state(tire: AbstractLongitudinalTire, v, omega, r):
    """The friction state at which `tire.dynamics` vanishes under constant `v`, `omega`,
    `r`: one Newton step from the undeflected state (exact for dynamics affine in the state,
    every LuGre tire and the relaxed Magic Formula). Where the rates do not depend on the
    state (a point LuGre tire at zero relative velocity, where every state is steady) the
    undeflected state."""
    z0, unravel = ravel_pytree(tire.init_state())

    def rates(z):
        return ravel_pytree(tire.dynamics(unravel(z), v, omega, r))[0]

    if z0.size == 1:
        f, slope = jax.jvp(rates, (z0,), (jnp.ones_like(z0),))
        flat = slope == 0
        return unravel(z0 - jnp.where(flat, 0.0, f / jnp.where(flat, 1.0, slope)))
    return unravel(z0 - jnp.linalg.solve(jax.jacfwd(rates)(z0), rates(z0)))


def as_parametrisation(model) -> AbstractRoadParametrisation:
    """An estimator's assumed model: a parametrisation as it is; `LuGreParams` as the
    `RoadCondition` of a `UniformLumpedLuGre` tire; a LuGre tire as its `RoadCondition`; any
    other tire as its `FrictionScale`."""
    if isinstance(model, AbstractRoadParametrisation):
        return model
    if isinstance(model, LuGreParams):
        return RoadCondition(UniformLumpedLuGre(model))
    if isinstance(model, AbstractLongitudinalTire):
        if isinstance(model.params, LuGreParams):
            return RoadCondition(model)
        return FrictionScale(model)
    raise TypeError(f"an estimator's model must be a tire, LuGreParams or a road "
                    f"parametrisation, got {type(model).__name__}")
