r"""Choosing 2D LuGre parameters whose steady state matches the Magic Formula (report Fig. 15).

The report says the LuGre parameters were chosen to match static tire models. We make that
choice reproducible: a least-squares fit, through the closed-form steady state of the
distributed model (`steady_state_forces`, eqs. 31-33), of the pure-slip curves
$F_x(\kappa)$ at $\alpha = 0$, and $F_y(\alpha)$ and $M_z(\alpha)$ at $\kappa = 0$, of a
Magic Formula, at several loads $F_z$ and one speed:
$$\min_\theta\;\sum_{F_z}\sum_{Q\in\{F_x, F_y, M_z\}}\sum_j
  \Bigl(\frac{Q^\text{LuGre}_j(\theta; F_z) - Q^\text{MF}_j(F_z)}
             {\max_j|Q^\text{MF}_j(F_z)|}\Bigr)^2,$$
each curve relative to its peak, solved by `optimistix.LevenbergMarquardt`. The Magic
Formula is any steady characteristic (`vehsim.tire.characteristic`): the report's 1987
one, or the Magic Formula 5.2 / 6.1 / 6.2 of a tyre property file (`MFParams`,
`MFTire`, a `TirFile`), whose loads, reference load and slip grid default to the file's
(`MFCharacteristic`), and whose start `lugre_initial_guess` reads off its curves. The free
parameters are $\sigma_{0x}, \sigma_{0y}, \mu_{kx}, \mu_{ky}, \mu_{sx}-\mu_{kx},
\mu_{sy}-\mu_{ky}$, and $v_s, \gamma$ unless held (next paragraph), through their
logarithms, so they stay positive; $\sigma_1$, $\sigma_2$ are held (they do not enter the
steady state, or are set to zero).

**What curves at one speed determine of the friction.** At the wheel speed $v$ of the fit
the bristles slide at $|v_r| = v|\kappa|$, $v\sin|\alpha|$ (0.2-10 m/s on the default grids
at 20 m/s), and the steady forces see eq. 29's $g(|v_r|) = \mu_k + (\mu_s - \mu_k)
e^{-(|v_r|/v_s)^\gamma}$ only there, and only where the patch slides: at small slip the
deflection grows linearly, $F = F_z\sigma_0\sigma L/2$, without $g$. $\mu_s$ is $g$ at
standstill and $v_s$ the speed it falls off at, both below the speeds seen; curves at one
speed fix $g$ over that decade, not the four numbers per axis that draw it. Fitted
together, they walk along a valley of near-equal $g$: on the shipped tyre property file
the loss changes by 1e-5 between 50 and 400 steps while $\mu_s$ grows to $10^5$, $v_s$
falls to $10^{-7}$ m/s and $\gamma$ to 0.14, and Levenberg-Marquardt never converges
(holding $\gamma$ alone does not stop it). So by default (argument `hold`;
`AbstractCharacteristic.held_stribeck`) $v_s$ and $\gamma$, the shape of the Stribeck
curve, are held at the start's values (`lugre_initial_guess`: 3 m/s, 0.7), and $\mu_k$,
$\mu_s$, its levels, fitted: that fit converges, with the valley's errors (docs/tir.md).
Only the 1987 formula's fit keeps them free, as its presets were found (there the fit
converges, to $v_s$ = 4.98 m/s, $\gamma$ = 1.13). Read $g$ at the grid's sliding speeds
as what a fit found, rather than $\mu_s$; fitting $v_s$ and $\gamma$ needs curves at
several speeds.

**Convergence** is judged as MINPACK does (Moré, Garbow and Hillstrom 1980;
`vehsim._optimality`): a fit is `successful` where Levenberg-Marquardt converges or, having
stopped short, its optimum passes the gradient-cosine test ($\le 10^{-6}$) or the
Gauss-Newton step predicts a relative loss reduction $\le 10^{-6}$ (`MatchResult.message`
says which); else it keeps the solver's result.

**The normal load is fitted too** (`fit_load=True`): its shape, a quartic in the Bernstein
form $q(\xi) \propto \sum_{k=0}^4 w_k\binom4k\xi^k(1-\xi)^{4-k}$ with weights $w_k \ge 0$
($w_2 = 1$; fitted through their square roots; any such shape is non-negative, equal weights give the uniform load, and
unequal ones skew it: a general polynomial of Fig. 16a), and the patch length as a power
of the load, $L = L_0(F_z/F_{z,0})^p$: with the shape, this is the only way the model's
normalised forces $F/F_z$ can depend on the load.

What the fit can and cannot do follows from eq. 33 at steady state. Along the patch the
deflection $z_y(\xi)$ grows monotonically from the leading edge, where bristles enter
undeflected, towards $v_{ry}/C_{0y}$, so for a load symmetric about the centre
$M_z = \sigma_{0y}F_zL\int_0^1 q\,z_y\,(1/2-\xi)\,d\xi \le 0$ at every slip angle (pair
$\xi$ with $1-\xi$): it is aligning, and tends to zero as the patch saturates. The sign
change of the Magic Formula's $M_z$ at large slip angles needs the load's centre of
pressure ahead of the patch centre: then $M_z \to F_yL\int_0^1 q\,(1/2-\xi)\,d\xi > 0$
as the whole patch slides.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float

from .._optimality import FTOL, GTOL, max_gradient_cosine, predicted_reduction
from .._results import RESULTS, as_result, is_successful, result_message, result_name
from .characteristic import AbstractCharacteristic, _default_slip_grid, tire_characteristic
from .distributed2d import steady_state_forces
from .load import AbstractLoadDistribution, PolynomialLoad, UniformLoad
from .lugre2d import LuGre2DParams


QUANTITIES = ("F_x", "F_y", "M_z")
"""The curves fitted, in the order of the error arrays."""

STRIBECK = ("v_s", "gamma")
"""The Stribeck velocity and exponent of eq. 29: the parameters `fit_to_magic_formula`
can hold (`hold`)."""

_DEGREE = 4
_BERNSTEIN = np.array([  # row k: monomial coefficients of binom(4, k) x^k (1 - x)^(4 - k)
    np.pad(math.comb(_DEGREE, k) * np.polynomial.polynomial.polypow([1.0, -1.0],
                                                                     _DEGREE - k),
           (k, 0))[: _DEGREE + 1]
    for k in range(_DEGREE + 1)])


def bernstein_load(weights: Float[Array, " 5"]) -> PolynomialLoad:
    r"""The load $q(\xi)\propto\sum_k w_k\binom4k\xi^k(1-\xi)^{4-k}$ (normalised), for
    weights $w_k \ge 0$ (module docstring)."""
    return PolynomialLoad(jnp.asarray(weights) @ jnp.asarray(_BERNSTEIN))


class MatchResult(eqx.Module):
    r"""What `fit_to_magic_formula` found: `params` (with $L = L_0$, the patch length at
    `reference_load`), the normal-load shape `load` (its Bernstein `load_weights` when it
    was fitted, else None), the exponent `patch_exponent` $p$ of
    $L = L_0(F_z/F_{z,0})^p$, the `loads` fitted, the errors relative to each curve's peak
    `rms_error` and `max_error` (shape (loads, 3): $F_x, F_y, M_z$); `peak` (loads, 3): each
    Magic Formula curve's peak $\max_j|Q_j^\text{MF}|$ [N, N, N m], so that
    `rms_error * peak` and `max_error * peak` are the errors in N and N m; the outcome
    `result` (a `vehsim.RESULTS` item: `successful` where Levenberg-Marquardt converged or
    MINPACK's tests find the optimum stationary, module docstring), the solver's own
    `solver_result` and `num_steps`, the tests' `gradient_cosine` and
    `predicted_reduction` (relative), and the Stribeck parameters `held`."""

    params: LuGre2DParams
    load: AbstractLoadDistribution
    load_weights: Float[Array, " 5"] | None
    patch_exponent: Float[Array, ""]
    reference_load: Float[Array, ""]
    loads: Float[Array, " n"]
    rms_error: Float[Array, "n 3"]
    max_error: Float[Array, "n 3"]
    peak: Float[Array, "n 3"]
    result: RESULTS = eqx.field(converter=as_result)
    num_steps: Array
    solver_result: RESULTS = eqx.field(converter=as_result)
    gradient_cosine: Float[Array, ""]
    predicted_reduction: Float[Array, ""]
    held: tuple[str, ...] = eqx.field(static=True, default=())

    @property
    def message(self) -> str:
        """Why `result`, in words, with the numbers of MINPACK's tests."""
        steps = int(self.num_steps)
        tests = (f"gradient cosine {float(self.gradient_cosine):.2g}, predicted relative "
                 f"loss reduction {float(self.predicted_reduction):.2g}")
        if bool(is_successful(self.result)):
            if bool(is_successful(self.solver_result)):
                return f"converged after {steps} Levenberg-Marquardt steps ({tests})"
            return (f"stationary by MINPACK's tests ({tests}; either <= {GTOL:g}), although "
                    f"Levenberg-Marquardt stopped with {result_name(self.solver_result)} "
                    f"after {steps} steps")
        if bool(self.result == RESULTS.nonfinite):
            return "the fit produced non-finite values"
        return (f"Levenberg-Marquardt stopped after {steps} steps: "
                f"{result_message(self.solver_result)} ({tests}; both > {GTOL:g})")

    def params_at(self, Fz) -> LuGre2DParams:
        """The parameters at load `Fz` [N] (the patch length scaled to it)."""
        return scaled_patch(self.params, self.patch_exponent, self.reference_load, Fz)


def scaled_patch(params: LuGre2DParams, exponent, reference_load, Fz) -> LuGre2DParams:
    r"""`params` with $L = L_0(F_z/F_{z,0})^p$ ($L_0$ = `params.L`, $p$ = `exponent`)."""
    L = params.L * (jnp.asarray(Fz, dtype=float) / reference_load) ** exponent
    return eqx.tree_at(lambda q: q.L, params, L)


def default_slip_grid():
    """Slip ratios in [-0.5, 0.5] and slip angles in (0, 20] deg used for the fit (of the
    1987 Magic Formula; a tyre property file's: `MFCharacteristic.slip_grid`)."""
    return _default_slip_grid()


def magic_formula_curves(mf, Fz, kappa, alpha):
    r"""The Magic Formula's pure-slip $(F_x(\kappa), F_y(\alpha), M_z(\alpha))$ at load
    `Fz` [N] on the `kappa` and `alpha` [rad] grids (`mf`: anything
    `tire_characteristic` takes)."""
    return tire_characteristic(mf).pure_curves(Fz, kappa, alpha)


def lugre_curves(params: LuGre2DParams, load: AbstractLoadDistribution, Fz, v, kappa, alpha):
    r"""The steady distributed LuGre model's pure-slip $(F_x(\kappa), F_y(\alpha),
    M_z(\alpha))$ at load `Fz` [N] and speed `v` [m/s] (`params.L`: the patch length at
    this load)."""

    def lugre(k, a):
        return steady_state_forces(params, load, v, k, a, Fz)

    lat = jax.vmap(lugre)(jnp.zeros_like(alpha), alpha)
    return jax.vmap(lugre)(kappa, jnp.zeros_like(kappa))[:, 0], lat[:, 1], lat[:, 2]


def _relative(lugre, target):
    return tuple((lu - t) / jnp.max(jnp.abs(t)) for lu, t in zip(lugre, target))


def match_errors(params: LuGre2DParams, load: AbstractLoadDistribution, mf, Fz, v, kappa,
                 alpha):
    r"""$(Q^\text{LuGre} - Q^\text{MF})/\max|Q^\text{MF}|$ at load `Fz` for $Q = F_x$ on
    the `kappa` grid and $Q = F_y, M_z$ on the `alpha` grid (a tuple of three arrays;
    `params.L` is the patch length at this load; `mf`: anything `tire_characteristic`
    takes)."""
    return _relative(lugre_curves(params, load, Fz, v, kappa, alpha),
                     magic_formula_curves(mf, Fz, kappa, alpha))


class _Fit(eqx.Module):
    """The fit's fixed data: what is held, the grids, the loads and the switches."""

    init: LuGre2DParams
    load: AbstractLoadDistribution
    mf: AbstractCharacteristic
    loads: Float[Array, " n"]
    reference_load: Float[Array, ""]
    v: Float[Array, ""]
    kappa: Float[Array, " k"]
    alpha: Float[Array, " a"]
    weights0: Float[Array, " 5"]
    exponent0: Float[Array, ""]
    moment: bool = eqx.field(static=True)
    fit_load: bool = eqx.field(static=True)
    symmetric: bool = eqx.field(static=True)
    held: tuple[str, ...] = eqx.field(static=True, default=())

    def _free(self) -> list[int]:
        """Indices of the fitted entries of (sigma0, mu_k, mu_s - mu_k, v_s, gamma)."""
        return [i for i in range(8) if i < 6 or STRIBECK[i - 6] not in self.held]

    def pack(self, p: LuGre2DParams):
        # a small floor keeps log finite when a start has mu_s = mu_k
        gap = jnp.maximum(p.mu_s - p.mu_k, 1e-3)
        theta = jnp.log(jnp.concatenate([p.sigma0, p.mu_k, gap, jnp.stack([p.v_s, p.gamma])]))
        if self.held:
            theta = theta[jnp.array(self._free())]
        if self.fit_load:  # log L0, p, sqrt(w_k / w_2) (k = 0, 1, 3, 4, or 0, 1 if symmetric)
            w = jnp.sqrt(self.weights0 / self.weights0[2])
            free = jnp.array([0, 1] if self.symmetric else [0, 1, 3, 4])
            theta = jnp.concatenate([theta, jnp.stack([jnp.log(p.L), self.exponent0]),
                                     w[free]])
        return theta

    def unpack(self, theta):
        """(params at the reference load, load shape, its weights or None, patch exponent)
        of `theta`."""
        n = 8 - len(self.held)
        e = jnp.exp(theta[:n])
        init = self.init
        if self.held:  # the held Stribeck parameters back in their places
            fitted = iter(e[6:])
            e = jnp.concatenate([e[:6], jnp.stack([
                jnp.asarray(getattr(init, q), dtype=e.dtype) if q in self.held
                else next(fitted) for q in STRIBECK])])
        L, exponent, load, weights = init.L, jnp.zeros(()), self.load, None
        if self.fit_load:
            L, exponent = jnp.exp(theta[n]), theta[n + 1]
            w = theta[n + 2:] ** 2  # squares: zero weights (a shape vanishing at an edge) reachable
            w = w[jnp.array([0, 1, 1, 0])] if self.symmetric else w
            weights = jnp.stack([w[0], w[1], jnp.ones(()), w[2], w[3]])
            load = bernstein_load(weights)
        params = LuGre2DParams(sigma0=e[0:2], sigma1=init.sigma1, sigma2=init.sigma2,
                               mu_k=e[2:4], mu_s=e[2:4] + e[4:6], v_s=e[6], gamma=e[7], L=L)
        return params, load, weights, exponent

    def targets(self):
        """The Magic Formula's three curves at each load, (loads, points) each."""
        return jax.vmap(lambda Fz: self.mf.pure_curves(Fz, self.kappa, self.alpha))(self.loads)

    def errors(self, theta, targets):
        """The relative errors of `match_errors`: (F_x, F_y, M_z), each (loads, points)."""
        params, load, _, exponent = self.unpack(theta)

        def at(Fz, target):
            at_load = scaled_patch(params, exponent, self.reference_load, Fz)
            return _relative(lugre_curves(at_load, load, Fz, self.v, self.kappa, self.alpha),
                             target)

        return jax.vmap(at)(self.loads, targets)

    def residuals(self, theta, targets):
        errors = self.errors(theta, targets)
        return jnp.concatenate([e.ravel() for e in (errors if self.moment else errors[:2])])


def _judge(solver_result, theta, J, r):
    r"""The outcome of a least-squares fit stopped at `theta` with residuals `r` and their
    Jacobian `J` (in the solver's coordinates) by a solver that said `solver_result`:
    `(result, gradient cosine, predicted relative reduction)` with `result` `nonfinite`
    where `theta` or `r` is not finite, else `successful` where the solver converged or
    MINPACK's tests find the point stationary (cosine $\le$ `GTOL` or reduction $\le$
    `FTOL`), else `solver_result`."""
    cosine, reduction = max_gradient_cosine(J, r), predicted_reduction(J, r)
    stationary = (cosine <= GTOL) | (reduction <= FTOL)
    finite = jnp.all(jnp.isfinite(theta)) & jnp.all(jnp.isfinite(r))
    solver_result = as_result(solver_result)
    result = RESULTS.where(finite, RESULTS.where(is_successful(solver_result) | stationary,
                                                 RESULTS.successful, solver_result),
                           RESULTS.nonfinite)
    return result, cosine, reduction


@eqx.filter_jit
def _solve(fit: _Fit, init: LuGre2DParams, solver, max_steps: int, throw: bool):
    targets = fit.targets()
    sol = optx.least_squares(fit.residuals, solver, fit.pack(init), targets,
                             max_steps=max_steps, throw=False)
    theta, lm = sol.value, RESULTS.promote(sol.result)
    J = jax.jacfwd(fit.residuals)(theta, targets)
    result, cosine, reduction = _judge(lm, theta, J, fit.residuals(theta, targets))
    if throw:
        theta = result.error_if(theta, result != RESULTS.successful)
    params, shape, weights, exponent = fit.unpack(theta)
    errors = fit.errors(theta, targets)  # F_x, F_y, M_z, each (loads, points)
    rms = jnp.stack([jnp.sqrt(jnp.mean(e**2, axis=-1)) for e in errors], axis=-1)
    worst = jnp.stack([jnp.max(jnp.abs(e), axis=-1) for e in errors], axis=-1)
    peak = jnp.stack([jnp.max(jnp.abs(t), axis=-1) for t in targets], axis=-1)
    return MatchResult(params=params, load=shape, load_weights=weights, patch_exponent=exponent,
                       reference_load=fit.reference_load, loads=fit.loads, rms_error=rms,
                       max_error=worst, peak=peak, result=result,
                       num_steps=sol.stats["num_steps"], solver_result=lm,
                       gradient_cosine=cosine, predicted_reduction=reduction, held=fit.held)


def lugre_initial_guess(mf, Fz=None, *, sigma1=(0.7, 0.7)) -> LuGre2DParams:
    r"""A start for `fit_to_magic_formula` read off the Magic Formula `mf` (anything
    `tire_characteristic` takes) at load `Fz` [N] (default its nominal load), for the
    uniform load.

    At small slip the steady bristle deflection grows linearly from the leading edge,
    $z = \sigma L\xi$ (eq. 15 with $k\xi \to 0$; $\sigma = \kappa$ or $\tan\alpha$), so
    $F = F_z\sigma_0\sigma L/2$ and $M_z = -F_yL/6$: the patch length is six times the
    pneumatic trail $t = -\partial_\alpha M_z/\partial_\alpha F_y$ at $\alpha = 0$
    (kept within [0.05, 0.5] m), and $\sigma_{0x} = 2K_x/(F_zL)$,
    $\sigma_{0y} = 2K_y/(F_zL)$ with the slopes $K_x = \partial_\kappa F_x$,
    $K_y = \partial_\alpha F_y$ at zero slip. $\mu_s$ is 1.05 times each curve's peak
    $F/F_z$ on `slip_grid`, $\mu_k$ 0.95 times its value at the grid's largest slip;
    $v_s = 3$ m/s, $\gamma = 0.7$; `sigma1` [s/m] held as given, $\sigma_2 = 0$."""
    char = tire_characteristic(mf)
    Fz = char.nominal_load() if Fz is None else float(Fz)

    def fx(k):
        return char.forces(k, 0.0, Fz)[0]

    def lat(a):
        return char.forces(0.0, a, Fz)[1:]

    kx = float(jax.grad(fx)(0.0))
    ky, kz = (float(d) for d in jax.jacfwd(lat)(0.0))
    L = float(np.clip(-6.0 * kz / ky, 0.05, 0.5)) if ky > 0 else 0.2
    kappa, alpha = char.slip_grid()
    cx, cy, _ = (np.abs(np.asarray(c)) / Fz for c in char.pure_curves(Fz, kappa, alpha))
    far_x = cx[np.argmax(np.abs(np.asarray(kappa)))]
    far_y = cy[np.argmax(np.abs(np.asarray(alpha)))]
    mu_s = 1.05 * np.array([cx.max(), cy.max()])
    mu_k = np.minimum(0.95 * np.array([far_x, far_y]), 0.95 * mu_s)
    sigma0 = np.maximum(2.0 * np.array([kx, ky]) / (Fz * L), 1.0)
    return LuGre2DParams(sigma0=sigma0, sigma1=sigma1, sigma2=(0.0, 0.0), mu_k=mu_k,
                         mu_s=mu_s, v_s=3.0, gamma=0.7, L=L)


def _held(char: AbstractCharacteristic, hold) -> tuple[str, ...]:
    if hold is None:
        return tuple(char.held_stribeck())
    hold = (hold,) if isinstance(hold, str) else tuple(hold)
    for q in hold:
        if q not in STRIBECK:
            raise ValueError(f"hold: expected names among {STRIBECK}, got {q!r}")
    return tuple(q for q in STRIBECK if q in hold)


def fit_to_magic_formula(
    mf,
    init: LuGre2DParams | None = None,
    loads=None,
    v=20.0,
    kappa=None,
    alpha=None,
    load: AbstractLoadDistribution | None = None,
    *,
    moment: bool = True,
    fit_load: bool = True,
    symmetric_load: bool = False,
    load_weights=(1.0, 1.0, 1.0, 1.0, 1.0),
    patch_exponent: float = 0.0,
    reference_load: float | None = None,
    hold=None,
    rtol: float = 1e-6,
    atol: float = 1e-6,
    max_steps: int = 1024,
    throw: bool = True,
) -> MatchResult:
    r"""Fit the steady state of the distributed 2D LuGre model to the Magic Formula `mf`.

    **Arguments:** `mf` the Magic Formula: the report's 1987 one
    (`MagicFormula1987Params`), a tyre property file's (`TirFile`, `MFParams`, `MFTire`
    with its camber and pressure), or any `AbstractCharacteristic`; `init` starting
    `LuGre2DParams` (also supplies the held `sigma1`, `sigma2`, and the start of $L_0$;
    default `lugre_initial_guess(mf)`); `loads` [N] fitted together (default the
    characteristic's `fit_loads`: 2, 4, 6 kN for the 1987 formula, $0.5, 1, 1.5\,F'_{z0}$
    for a file) and the speed `v` [m/s]; `kappa`, `alpha` [rad] grids (default its
    `slip_grid`: `default_slip_grid()` for the 1987 formula); `moment`: fit $M_z$ too;
    `fit_load`: fit the load shape and
    the patch length law (module docstring), starting from the Bernstein weights
    `load_weights` (default: the uniform shape; `symmetric_load`: keep $w_{4-k} = w_k$)
    and the exponent `patch_exponent`; else
    hold `load` (default uniform) and $L$; `reference_load` $F_{z,0}$ [N] of the patch
    length law (default its `nominal_load`: 4 kN for the 1987 formula, $F'_{z0}$ for a
    file); `hold`: the Stribeck parameters of eq. 29 held at `init`'s values, names of
    `STRIBECK` (default `held_stribeck()` of the characteristic: both, except for the 1987
    formula; module docstring: curves at one speed do not determine them; ``()`` fits
    both); `throw`: raise unless the fit is `successful` (module docstring; else check
    `result` and `message`).

    **Returns:** a `MatchResult`: fitted parameters, load shape and patch-length exponent,
    and the RMS and maximum errors of each curve at each load, relative to its peak (and
    the peaks, for the errors in N and N m), the outcome `result` with its `message`.
    """
    char = tire_characteristic(mf)
    held = _held(char, hold)
    init = lugre_initial_guess(char) if init is None else init
    loads = char.fit_loads() if loads is None else loads
    reference_load = char.nominal_load() if reference_load is None else reference_load
    if kappa is None or alpha is None:
        k0, a0 = char.slip_grid()
        kappa = k0 if kappa is None else jnp.asarray(kappa)
        alpha = a0 if alpha is None else jnp.asarray(alpha)
    fit = _Fit(init, UniformLoad() if load is None else load, char,
               jnp.asarray(loads, dtype=float), jnp.asarray(reference_load, dtype=float),
               jnp.asarray(v, dtype=float), jnp.asarray(kappa), jnp.asarray(alpha),
               jnp.asarray(load_weights, dtype=float),
               jnp.asarray(patch_exponent, dtype=float), bool(moment), bool(fit_load),
               bool(symmetric_load), held)
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    return _solve(fit, init, solver, int(max_steps), bool(throw))
