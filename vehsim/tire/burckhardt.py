r"""Burckhardt's steady-state friction curves and the LuGre road family fitted to them.

$$\mu_B(\lambda) = c_1\bigl(1 - e^{-c_2\lambda}\bigr) - c_3\lambda,\qquad \lambda = -s\in[0, 1]$$
the braking slip (docs/parameters.md, with the sources' caveats). `fit_burckhardt_family`
fits eq. 19 (uniform load, $v$ = 20 m/s) to five of them with **one tire** and a road
condition $\theta$ per road, the model of Canudas de Wit and Tsiotras (1999): shared
$\sigma_0$, $v_s$, $\alpha$ and $\mu_c/\mu_s$, and $\theta$ per road, with $\mu_s = 1$ (so
that $g/\theta$ is the road's friction level), and held: $L$ of the CDC 1999 set, $\sigma_1$
= 0.7 s/m (the damping quoted with Table 3's $\sigma_0$ = 181.54 1/m, nearer the fitted
stiffness than the CDC set's 4.9487 s/m with its $\sigma_0$ = 40; it only enters
transients) and $\sigma_2 = 0$. (The CDC set's $\sigma_2$ = 0.0018 s/m fits Burckhardt's curves at
20 m/s better, but adds $\sigma_2v$ = 0.054 to a locked wheel's friction at 30 m/s: as much
as ice has, so that a locked wheel would out-brake any ABS on ice.) Cobblestone, whose
peak lies at 40 % slip where the others peak below 20 %, gets its own $\sigma_0$: no
$\theta$ moves the peak that far. The fitted values are the presets of
`vehsim.control.road.surfaces`.

`RelaxedBurckhardt` is a tire whose steady state is Burckhardt's curve itself, through a
relaxation length (the structure of `RelaxedMagicFormula`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float

from .._checks import check_count, check_nonnegative, check_positive
from .._fields import array_field
from .._math import one_minus_exp_over, safe_abs
from .lugre import AbstractLongitudinalTire, LuGreParams, relaxed_deflection_rate
from .steady_state import braking_mu_uniform


BURCKHARDT = {
    "dry_asphalt": (1.2801, 23.99, 0.52),
    "wet_asphalt": (0.857, 33.822, 0.347),
    "cobblestone": (1.3713, 6.4565, 0.6691),
    "snow": (0.1946, 94.129, 0.0646),
    "ice": (0.05, 306.39, 0.0),
}
"""$(c_1, c_2, c_3)$ of the five roads (docs/parameters.md; cobblestone is the dry row)."""

FIT_SPEED = 20.0
"""Speed [m/s] at which eq. 19 is fitted (the CDC 1999 operating point)."""

HELD = dict(sigma1=0.7, sigma2=0.0, mu_s=1.0, L=0.25)
"""Held fields of the fitted family (sigma1, sigma2, L from the CDC 1999 set)."""


def burckhardt_mu(coefficients, slip):
    r"""$\mu_B(\lambda) = c_1(1 - e^{-c_2\lambda}) - c_3\lambda$ for $(c_1, c_2, c_3)$ at
    braking slip $\lambda = $ `slip` $\ge 0$, continued as an odd function,
    $\mu_B(-\lambda) = -\mu_B(\lambda)$, to driving slip (where the formula itself grows
    as $e^{c_2|\lambda|}$): its slope at $\lambda = 0$ is $c_1c_2 - c_3$ from both sides, and
    in both modes of differentiation."""
    c1, c2, c3 = coefficients
    braking = slip >= 0
    lam_b = jnp.where(braking, slip, 0.0)  # double where: each branch only sees its own side
    lam_d = jnp.where(braking, 0.0, slip)
    return c1 * (jnp.where(braking, -jnp.expm1(-c2 * lam_b), jnp.expm1(c2 * lam_d))) - c3 * slip


def fit_slips() -> np.ndarray:
    """The slip grid of the fits: dense below 30 % (the peaks), sparser up to a locked wheel."""
    return np.concatenate([np.linspace(0.002, 0.3, 60), np.linspace(0.31, 1.0, 30)])


def family_params(u) -> list[LuGreParams]:
    r"""The five roads' `LuGreParams` from the fit coordinates $u = (\log v_s, \log\alpha,
    \log\sigma_0, \log\sigma_{0,\mathrm{cobblestone}}, \operatorname{logit}\mu_c/\mu_s,
    \log\theta_1..\log\theta_5)$."""
    v_s, alpha, sigma0, sigma0_cobble = (jnp.exp(u[i]) for i in range(4))
    mu_c = jax.nn.sigmoid(u[4]) * HELD["mu_s"]
    out = []
    for i, name in enumerate(BURCKHARDT):
        s0 = sigma0_cobble if name == "cobblestone" else sigma0
        out.append(LuGreParams(sigma0=s0, v_s=v_s, alpha=alpha, mu_c=mu_c,
                               theta=jnp.exp(u[5 + i]), **HELD))
    return out


def fit_errors(params: LuGreParams, name: str, speed: float = FIT_SPEED):
    """(eq. 19 - Burckhardt) / Burckhardt's peak, on `fit_slips`, at `speed`."""
    lam = jnp.asarray(fit_slips())
    target = burckhardt_mu(BURCKHARDT[name], lam)
    model = -jax.vmap(lambda s: braking_mu_uniform(params, s, speed))(-lam)
    return (model - target) / jnp.max(target)


def fit_burckhardt_family(max_steps: int = 500):
    """Least-squares fit of the family (module docstring) by optimistix's
    Levenberg-Marquardt. **Returns:** ``(u, params by road name, optx result)``."""
    check_count("fit_burckhardt_family", "max_steps", max_steps, sep=": ")

    def residuals(u, _):
        return jnp.concatenate([fit_errors(p, n) for p, n in zip(family_params(u), BURCKHARDT)])

    u0 = jnp.concatenate([jnp.log(jnp.asarray([10.0, 0.5, 200.0, 60.0])), jnp.asarray([-1.0]),
                          jnp.log(jnp.asarray([1.0, 1.4, 1.2, 6.0, 20.0]))])
    sol = optx.least_squares(residuals, optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12), u0,
                             max_steps=max_steps, throw=False)
    return sol.value, dict(zip(BURCKHARDT, family_params(sol.value))), sol.result


class BurckhardtParams(eqx.Module):
    r"""Burckhardt's curve $\mu_B(\lambda) = c_1(1 - e^{-c_2\lambda}) - c_3\lambda$ with a
    relaxation length.

    **Fields:** `c1` [-] (> 0), `c2` [-] (> 0), `c3` [-] ($\ge 0$), `relaxation_length`
    $\sigma_\kappa$ [m] (> 0). Default: dry asphalt (`BURCKHARDT`), 0.25 m.
    """

    c1: Float[Array, "*batch"] = array_field(default=BURCKHARDT["dry_asphalt"][0])
    c2: Float[Array, "*batch"] = array_field(default=BURCKHARDT["dry_asphalt"][1])
    c3: Float[Array, "*batch"] = array_field(default=BURCKHARDT["dry_asphalt"][2])
    relaxation_length: Float[Array, "*batch"] = array_field(default=0.25)

    def __check_init__(self):
        owner = "BurckhardtParams"
        check_positive(owner, "c1", self.c1)
        check_positive(owner, "c2", self.c2)
        check_nonnegative(owner, "c3", self.c3)
        check_positive(owner, "relaxation_length", self.relaxation_length)


class RelaxedBurckhardt(AbstractLongitudinalTire):
    r"""Burckhardt's curve driven by a transient slip with relaxation length $\sigma_\kappa$.

    $$\dot u = v_r - |v|\,\frac{u}{\sigma_\kappa},\qquad
      \mu = \operatorname{sgn}(s')\,\mu_B(|s'|) = c_1c_2s'\varphi(c_2|s'|) - c_3s',\qquad
      s' = \frac{u}{\sigma_\kappa},$$
    $\varphi(x) = (1 - e^{-x})/x$ (smooth through $s' = 0$): the curve made odd, so that a
    driven wheel gets the mirror of the braking curve. Burckhardt, *Fahrwerktechnik:
    Radschlupf-Regelsysteme* (Vogel, 1993) for the curve and its coefficients
    (`BURCKHARDT`); Pacejka (2012), ch. 7 for the relaxation length. In braking the peak is
    at $\lambda^* = \ln(c_1c_2/c_3)/c_2$ with $\mu^* = c_1 - c_3/c_2 - c_3\lambda^*$
    (at $\lambda = 1$ where $c_1c_2e^{-c_2} \ge c_3$), at every speed. No closed-form
    steady state is coded: `steady_state` is computed (`solve_steady_state`).

    **Arguments:** `params`, a `BurckhardtParams`.
    """

    params: BurckhardtParams

    def init_state(self):
        return jnp.zeros(())

    def dynamics(self, state, v, omega, r):
        return relaxed_deflection_rate(state, v, omega, r, self.params.relaxation_length)

    def mu(self, state, v, omega, r):
        p = self.params
        s = state / p.relaxation_length
        return p.c1 * p.c2 * s * one_minus_exp_over(p.c2 * safe_abs(s)) - p.c3 * s
