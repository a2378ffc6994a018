r"""Tires of another family on the drive plant: a Magic Formula from a tyre property file,
put on the scenarios' roads by their peaks.

The scenarios' roads are given as the LuGre plant's friction scales $\lambda(x, y)$
(`vehsim.drive.grip`), and their grip conditions as that tire's peaks $\mu^*(\lambda)$ at
20 m/s (`vehsim.drive.scenarios`: 20 % less grip is a peak of $0.8 \times 0.52$). The
lumped LuGre tire's peak is not proportional to $\lambda$ (its contact-patch edge term does
not scale: $\mu^*(\lambda)/\mu^*(\lambda_0)$ is 0.50 where $\lambda/\lambda_0$ is 0.44),
while a Magic Formula's is proportional to its road-friction factors LMUX and LMUY. A Magic
Formula scaled by $\lambda$ itself would therefore meet a different road: its icy patch 12 %
more slippery than the LuGre plant's. On a surface of scale $\lambda$ it is instead scaled
by
$$m(\lambda) = \frac{\mu^*(\lambda)}{\mu^*(\lambda_0)},$$
($\lambda_0$ the nominal road's scale; `peak_surface_factor`, the plant's
`DrivePlant.surface_factor`), so that with its peak made the nominal road's on that road
(`mf_plant_tire`) every surface has the peak the scenario states, while the curves' shapes
(peak slip, fall-off, combined slip, load and speed dependence) stay the file's.
"""

from __future__ import annotations

import functools
import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._checks import check_range
from ..tire.lumped2d import LumpedLuGre2D
from ..tire.mf6 import MFParams, MFTire, RelaxedMFTire
from ..tire.tir import TirFile, read_tir
from ..vehicle.params import HalfCarParams, rally_gravel
from .estimator import AxleGripEstimator, braking_peak_on, peak_friction
from .grip import SurfaceFactor
from .plant import DrivePlant


REFERENCE_SPEED = 20.0
"""Speed [m/s] at which the peaks are matched (the scenarios' and the estimator's)."""

SURFACE_OCTAVES = (-6, 2)
r"""The scales of `peak_surface_factor`'s knots: $\lambda_0 2^k$ for $k$ in this range, from a
64th of the nominal road's scale (peaks near 0.01) to 4 times it (peaks above 1.6, past
three times the nominal peak), 32 knots per octave."""


def peak_surface_factor(reference_scale: float) -> SurfaceFactor:
    r"""The `SurfaceFactor` $m(\lambda) = \mu^*(\lambda)/\mu^*(\lambda_0)$ (module docstring)
    of the LuGre plant's tire (`AxleGripEstimator`'s: the lumped 2D LuGre with
    `lugre2d_bakker1987`) in pure braking at 20 m/s, $\lambda_0$ = `reference_scale` (the
    nominal road's, `nominal_scale`): knots at $\lambda_0 2^{k/32}$ over `SURFACE_OCTAVES`,
    $\lambda_0$ one of them ($m = 1$ there, exactly); constant past the ends.

    Each knot's peak is the maximum of the steady-state friction over 4001 slips
    geometrically spaced from $10^{-5}$ to 1, refined by a parabola in $\log\kappa$
    (`dense_peak`), so $m$ is the tire's own ratio to $10^{-9}$ at the knots and within
    $10^{-5}$ between them. `peak_friction`'s 112 slips, which the estimator and the planner
    use on every sample, read the same peaks within 0.9 % (its docstring)."""
    check_range("peak_surface_factor", "reference_scale", reference_scale, lower=0.0,
                lower_open=True)
    return _peak_surface_factor(float(reference_scale))


@functools.lru_cache(maxsize=8)
def _peak_surface_factor(lam0: float) -> SurfaceFactor:
    lo, hi = SURFACE_OCTAVES
    k = np.arange(32 * lo, 32 * hi + 1)
    scales = lam0 * np.exp2(k / 32.0)
    tire = AxleGripEstimator().tire
    peaks = np.asarray(jax.vmap(lambda lam: dense_peak(tire, lam, REFERENCE_SPEED))(
        jnp.asarray(scales)))
    factors = peaks / peaks[k == 0][0]
    factors[k == 0] = 1.0
    return SurfaceFactor(scales=jnp.asarray(scales), factors=jnp.asarray(factors))


@eqx.filter_jit
def dense_peak(tire, scale, speed):
    r"""$\mu^*(\lambda, V)$ of the lumped 2D LuGre `tire` on a road of friction scale
    `scale` in pure braking at `speed` [m/s], as `peak_friction` but over 4001 slips
    $\kappa$ geometrically spaced from $10^{-5}$ to 1, the largest refined by a parabola
    through it and its neighbours in $\log\kappa$: within $10^{-9}$ of a bounded scalar
    maximisation on every road at 20 m/s (set-up work, not for every sample)."""
    return braking_peak_on(tire, scale, jnp.asarray(speed, float),
                           jnp.geomspace(1e-5, 1.0, 4001))


def mf_plant_tire(tir: TirFile | MFParams | str | os.PathLike, peak: float = 0.52, *,
                  params: HalfCarParams | None = None) -> RelaxedMFTire:
    r"""A tyre property file's Magic Formula for the drive plant's axles: `RelaxedMFTire`
    (the file's relaxation lengths; its valid ranges not applied, since the half car's axle
    carries both wheels' load), with its road-friction factors LMUX and LMUY set so that its
    pure-slip peaks $\max|F_x|/F_z$ (slip ratios 0 to 1) and $\max|F_y|/F_z$ (slip angles 0
    to 1.2 rad) at the static front axle load of `params` (default `rally_gravel()`) and
    20 m/s are both `peak` (default the nominal road's 0.52). With `peak_surface_factor` it
    meets every surface of a scenario with that surface's peak (module docstring).

    `tir`: a `TirFile`, its path, or its `MFParams`."""
    check_range("mf_plant_tire", "peak", peak, lower=0.0, lower_open=True, upper=3.0)
    if isinstance(tir, str | os.PathLike):
        tir = read_tir(tir)
    P = MFParams.from_tir(tir) if isinstance(tir, TirFile) else tir
    if not isinstance(P, MFParams):
        raise TypeError("mf_plant_tire: tir must be a TirFile, a path to a .tir file or "
                        f"MFParams, got {type(tir).__name__}")
    car = rally_gravel() if params is None else params
    Fz = float(car.static_loads()[0])
    mux, muy = (float(v) for v in _pure_peaks(MFTire(P, limits=False), Fz, float(car.r)))
    if not (mux > 0 and muy > 0 and np.isfinite(mux) and np.isfinite(muy)):
        raise ValueError(f"mf_plant_tire: the file's pure-slip peaks at {Fz:.0f} N are "
                         f"mu_x {mux:g}, mu_y {muy:g}; they must be finite and positive")
    P = eqx.tree_at(lambda q: (q.LMUX, q.LMUY), P,
                    (P.LMUX * peak / mux, P.LMUY * peak / muy))
    return RelaxedMFTire(P, limits=False)


@eqx.filter_jit
def _pure_peaks(tire, Fz, r):
    V = REFERENCE_SPEED
    kappa = jnp.linspace(0.0, 1.0, 20001)
    tan_alpha = jnp.tan(jnp.linspace(0.0, 1.2, 20001))

    def forces(k, ta):
        return tire.forces(tire.init_state(), V, ta * V, (1.0 + k) * V / r, r, Fz)

    fx = jax.vmap(forces)(kappa, 0.0 * kappa)[:, 0]
    fy = jax.vmap(forces)(0.0 * tan_alpha, tan_alpha)[:, 1]
    return jnp.max(jnp.abs(fx)) / Fz, jnp.max(jnp.abs(fy)) / Fz


@eqx.filter_jit
def plant_peaks(plant: DrivePlant, scales):
    r"""The true peak friction at 20 m/s of `plant`'s tire on surfaces of the grip's scales
    `scales` (any shape): for a LuGre tire its $\mu^*(\lambda)$ (`peak_friction`); for a
    Magic Formula its pure-slip longitudinal peak at the car's static front axle load on
    its own road times its friction factor there ($m(\lambda)$ with a `surface_factor`,
    else $\lambda$): a Magic Formula's peak is proportional to LMUX. Other tires are
    refused, naming theirs."""
    scales = jnp.asarray(scales, float)
    tire = plant.tire
    if isinstance(tire, LumpedLuGre2D):
        flat = jax.vmap(lambda lam: peak_friction(tire, lam, REFERENCE_SPEED))(scales.ravel())
        return flat.reshape(scales.shape)
    if isinstance(getattr(tire, "params", None), MFParams):
        car = plant.params
        Fz = car.static_loads()[0]
        mux = _pure_peaks(MFTire(tire.params, limits=False), Fz, car.r)[0]
        factor = scales if plant.surface_factor is None else plant.surface_factor(scales)
        return mux * factor
    raise TypeError("plant_peaks knows the peaks of a LumpedLuGre2D and of a Magic Formula "
                    f"(params MFParams), got {type(tire).__name__}")
