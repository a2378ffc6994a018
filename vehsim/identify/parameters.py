r"""The fitted quantities of the lumped LuGre model (eqs. 10, 22-25), and the unconstrained
coordinates $u$ the fits work in.

Every quantity is positive by construction: $u = \log\theta$, except
$u_{\mu_s} = \log(\mu_s-\mu_c)$, so that $\mu_c\le\mu_s$ always; with $\mu_s$ held fixed
while $\mu_c$ is fitted, $u_{\mu_c} = \operatorname{logit}(\mu_c/\mu_s)$, so that
$0<\mu_c<\mu_s$.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._fields import float_array
from ..tire.lugre import LuGreParams, LumpedLuGre


PARAMETER_NAMES = ("sigma0", "sigma1", "sigma2", "mu_c", "mu_s", "v_s", "kappa0", "alpha", "theta")
LUMPED_PARAMETERS = ("sigma0", "sigma1", "sigma2", "mu_c", "mu_s", "v_s", "kappa0")
# sigma2 (viscous, ~1e-3 s/m) is nearly collinear with (mu_c, mu_s, v_s) over the speeds of a
# braking (Stribeck curve plus a linear term): on real data freeing it sends mu_c to its
# bound. It is fixed at the initial guess by default; free it with `free=LUMPED_PARAMETERS`.
DEFAULT_FREE = ("sigma0", "sigma1", "mu_c", "mu_s", "v_s", "kappa0")
UNITS = {"sigma0": "1/m", "sigma1": "s/m", "sigma2": "s/m", "mu_c": "1", "mu_s": "1",
         "v_s": "m/s", "kappa0": "1", "alpha": "1", "theta": "1"}


def default_initial_guess() -> LumpedLuGre:
    """A generic dry-asphalt starting point (L = 0.2 m, alpha = 1/2, theta = 1)."""
    return LumpedLuGre(
        LuGreParams(sigma0=150.0, sigma1=1.0, sigma2=0.004, mu_c=0.7, mu_s=1.2, v_s=5.0,
                    alpha=0.5, theta=1.0, L=0.2),
        kappa0=1.5,
    )


def parameter_values(model: LumpedLuGre) -> dict[str, Any]:
    """The fitted quantities of `model` by name (eqs. 10, 22-25)."""
    p = model.params
    return {n: (model.kappa0 if n == "kappa0" else getattr(p, n)) for n in PARAMETER_NAMES}


def with_values(model: LumpedLuGre, values: dict[str, Any]) -> LumpedLuGre:
    """`model` with the named quantities replaced (no validation: works under tracing)."""
    names = [n for n in values if n != "kappa0"]
    if names:
        model = eqx.tree_at(lambda m: [getattr(m.params, n) for n in names], model,
                            [float_array(values[n]) for n in names])
    if "kappa0" in values:
        model = eqx.tree_at(lambda m: m.kappa0, model, float_array(values["kappa0"]))
    return model


def to_unconstrained(model: LumpedLuGre, names: Sequence[str], keep_mu_s=False):
    r"""$u$: logs of the named quantities, with $\log(\mu_s-\mu_c)$ in place of $\mu_s$; with
    `keep_mu_s` (a bool, may be traced: $\mu_s$ held fixed while $\mu_c$ is fitted)
    $\operatorname{logit}(\mu_c/\mu_s)$ in place of $\log\mu_c$."""
    vals = parameter_values(model)
    out = []
    for n in names:
        x = vals[n] - vals["mu_c"] if n == "mu_s" else vals[n]
        u = jnp.log(float_array(x))
        if n == "mu_c" and keep_mu_s is not False:
            ratio = jnp.where(keep_mu_s, vals["mu_c"] / vals["mu_s"], 0.5)
            u = jnp.where(keep_mu_s, jnp.log(ratio) - jnp.log1p(-ratio), u)
        out.append(u)
    return jnp.stack(out)


def from_unconstrained(u, model: LumpedLuGre, names: Sequence[str],
                       keep_mu_s=False) -> LumpedLuGre:
    r"""Inverse of `to_unconstrained`: every `u` gives a valid parameter set. With
    `keep_mu_s`, $\mu_s$ stays at its value in `model` and
    $\mu_c = \mu_s\,\mathrm{sigmoid}(u_{\mu_c})$."""
    vals = {n: jnp.exp(u[i]) for i, n in enumerate(names) if n != "mu_s"}
    if "mu_c" in vals and keep_mu_s is not False:
        ratio = jax.nn.sigmoid(u[list(names).index("mu_c")])
        vals["mu_c"] = jnp.where(keep_mu_s, model.params.mu_s * ratio, vals["mu_c"])
    if "mu_s" in names:
        mu_c = vals.get("mu_c", model.params.mu_c)
        vals["mu_s"] = jnp.where(keep_mu_s, model.params.mu_s,
                                 mu_c + jnp.exp(u[list(names).index("mu_s")]))
    return with_values(model, vals)


def keeps_mu_s(mask):
    """True where `mu_s` is held fixed while `mu_c` is fitted (`mask` over PARAMETER_NAMES)."""
    return (~mask[PARAMETER_NAMES.index("mu_s")]) & mask[PARAMETER_NAMES.index("mu_c")]


def values_batch(model: LumpedLuGre, us, keep_mu_s=False):
    """The values of `PARAMETER_NAMES` for each row of `us` (batch, 9)."""
    return jax.vmap(lambda u: jnp.stack([float_array(x) for x in parameter_values(
        from_unconstrained(u, model, PARAMETER_NAMES, keep_mu_s)).values()]))(us)


def dtheta_du(theta_all, names: Sequence[str]) -> np.ndarray:
    r"""$\partial\theta/\partial u$ of `from_unconstrained` at the values `theta_all` (of
    `PARAMETER_NAMES`), for the free `names`: shape (9, p)."""
    idx = {n: i for i, n in enumerate(PARAMETER_NAMES)}
    T = np.zeros((len(PARAMETER_NAMES), len(names)))
    for j, n in enumerate(names):
        if n == "mu_s":
            T[idx["mu_s"], j] = theta_all[idx["mu_s"]] - theta_all[idx["mu_c"]]
        else:
            T[idx[n], j] = theta_all[idx[n]]
            if n == "mu_c" and "mu_s" not in names:  # mu_c = mu_s sigmoid(u), mu_s held
                T[idx[n], j] *= 1.0 - theta_all[idx["mu_c"]] / theta_all[idx["mu_s"]]
            if n == "mu_c":  # mu_s = mu_c + exp(u_mu_s) moves with mu_c when mu_s is free
                T[idx["mu_s"], j] = theta_all[idx["mu_c"]] if "mu_s" in names else 0.0
    return T
