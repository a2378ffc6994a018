r"""Choosing 2D LuGre parameters whose steady state matches the Magic Formula (report Fig. 15).

The report says the LuGre parameters were chosen to match static tire models. We make that
choice reproducible: a least-squares fit, through the closed-form steady state of the
distributed model (`steady_state_forces`), of the pure-slip curves $F_x(\kappa)$ at
$\alpha = 0$ and $F_y(\alpha)$ at $\kappa = 0$ of a Magic Formula, at one load and speed:
$$\min_\theta\;\sum_j\Bigl(\frac{F^\text{LuGre}_j(\theta) - F^\text{MF}_j}{F_z}\Bigr)^2,$$
solved by `optimistix.LevenbergMarquardt`. The free parameters are
$\sigma_{0x}, \sigma_{0y}, \mu_{kx}, \mu_{ky}, \mu_{sx}-\mu_{kx}, \mu_{sy}-\mu_{ky}, v_s, \gamma$
(through their logarithms, so they stay positive); $L$, $\sigma_1$, $\sigma_2$ are held.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from .distributed2d import steady_state_forces
from .load import AbstractLoadDistribution, UniformLoad
from .lugre2d import LuGre2DParams
from .magic_formula import MagicFormula1987Params, combined_forces


class MatchResult(eqx.Module):
    """Fitted parameters, residuals and optimistix result of `fit_to_magic_formula`."""

    params: LuGre2DParams
    rms_residual: jax.Array
    max_residual: jax.Array
    result: optx.RESULTS
    num_steps: jax.Array


def _unpack(theta, fixed: LuGre2DParams):
    e = jnp.exp(theta)
    mu_k = e[2:4]
    return LuGre2DParams(
        sigma0=e[0:2], sigma1=fixed.sigma1, sigma2=fixed.sigma2, mu_k=mu_k,
        mu_s=mu_k + e[4:6], v_s=e[6], gamma=e[7], L=fixed.L,
    )


def _pack(p: LuGre2DParams):
    # a small floor keeps log finite when a start has mu_s = mu_k
    gap = jnp.maximum(p.mu_s - p.mu_k, 1e-3)
    return jnp.log(jnp.concatenate([p.sigma0, p.mu_k, gap, jnp.stack([p.v_s, p.gamma])]))


def default_slip_grid():
    """Slip ratios in [-0.5, 0.5] and slip angles in (0, 20] deg used for the fit."""
    kappa = jnp.concatenate([jnp.linspace(-0.5, -0.01, 20), jnp.linspace(0.01, 0.5, 20)])
    alpha = jnp.deg2rad(jnp.linspace(0.5, 20.0, 30))
    return kappa, alpha


def match_residuals(params: LuGre2DParams, mf: MagicFormula1987Params, Fz, v, kappa, alpha,
                    load: AbstractLoadDistribution | None = None):
    r"""Normalised residuals $(F^\text{LuGre} - F^\text{MF})/F_z$ on the pure-slip grids."""
    load = UniformLoad() if load is None else load

    def lugre(k, a):
        return steady_state_forces(params, load, v, k, a, Fz)

    zeros_k, zeros_a = jnp.zeros_like(kappa), jnp.zeros_like(alpha)
    fx = jax.vmap(lugre)(kappa, zeros_k)[:, 0] - combined_forces(mf, kappa, zeros_k, Fz)[:, 0]
    fy = jax.vmap(lugre)(zeros_a, alpha)[:, 1] - combined_forces(mf, zeros_a, alpha, Fz)[:, 1]
    return jnp.concatenate([fx, fy]) / Fz


def fit_to_magic_formula(
    mf: MagicFormula1987Params,
    init: LuGre2DParams,
    Fz=4000.0,
    v=20.0,
    kappa=None,
    alpha=None,
    load: AbstractLoadDistribution | None = None,
    *,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    max_steps: int = 256,
    throw: bool = True,
) -> MatchResult:
    r"""Fit the steady state of the distributed 2D LuGre model to the Magic Formula `mf`.

    **Arguments:** `mf` Magic Formula coefficients; `init` starting `LuGre2DParams` (also
    supplies the held `L`, `sigma1`, `sigma2`); load `Fz` [N] and speed `v` [m/s];
    `kappa`, `alpha` [rad] grids (default `default_slip_grid()`); `load` shape (uniform);
    `throw`: raise if Levenberg-Marquardt does not converge (else check `result`).

    **Returns:** a `MatchResult` with the fitted parameters and the RMS and maximum of the
    normalised residual $|F^\text{LuGre} - F^\text{MF}|/F_z$.
    """
    if kappa is None or alpha is None:
        k0, a0 = default_slip_grid()
        kappa = k0 if kappa is None else jnp.asarray(kappa)
        alpha = a0 if alpha is None else jnp.asarray(alpha)

    def fn(theta, args):
        return match_residuals(_unpack(theta, init), mf, Fz, v, kappa, alpha, load)

    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    sol = optx.least_squares(fn, solver, _pack(init), max_steps=max_steps, throw=throw)
    params = _unpack(sol.value, init)
    res = fn(sol.value, None)
    return MatchResult(
        params=params, rms_residual=jnp.sqrt(jnp.mean(res**2)),
        max_residual=jnp.max(jnp.abs(res)), result=sol.result,
        num_steps=sol.stats["num_steps"],
    )
