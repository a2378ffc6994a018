r"""Road grip that varies along the road: a friction scale $\lambda(x, y)$.

A grip field gives the friction scale $\lambda > 0$ at a point $(x, y)$ of the road: the
tire's friction coefficients are multiplied by $\lambda$ there (`scale_friction`). For the
LuGre family this is the road-condition parameter of the report, $\theta = 1/\lambda$: the
bristle decay of eq. 22 (eq. 27 in combined slip), $\theta\sigma_0|v_r|/g(v_r)$, is the same
for $\mu\to\lambda\mu$ as for $\theta\to\theta/\lambda$, so the single-contact steady-state
curve is $\lambda$ times the nominal one, stretched by $\lambda$ along the slip axis (peak
$\lambda\mu^*$, same initial slope, eq. 19); a Magic Formula's road-friction factors LMUX
and LMUY do the same for it. The lumped tire's contact-patch edge term does
not scale, so its peak is not proportional to $\lambda$ (`scale_for_peak` finds the
$\lambda$ of a peak). The half-car of eqs. 49-60 reads the field at
each axle's contact point separately (`DrivePlant`), so the two axles can be on different
surfaces.

Transitions are smooth ($C^1$), so gradients through a drive that crosses them are finite:
the circular patches of `GripPatches` have a $\tanh$ edge of width `width`, the profile of
`GripProfile` moves between its stations by the cubic smoothstep $3u^2 - 2u^3$.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import check_finite, check_positive, is_concrete, plain
from .._fields import array_field
from .._math import safe_hypot
from ..tire.base import AbstractTire
from ..tire.friction_ellipse import FrictionEllipseTire
from ..tire.lugre import LuGreParams
from ..tire.lugre2d import LuGre2DParams
from ..tire.mf6 import MFParams


class AbstractGripField(eqx.Module):
    r"""The friction scale $\lambda(x, y) > 0$ of the road at a point (module docstring)."""

    @abc.abstractmethod
    def scale_at(self, x, y) -> Float[Array, ""]:
        r"""$\lambda$ at $(x, y)$ [m] (inertial frame)."""


class UniformGrip(AbstractGripField):
    r"""The same scale $\lambda$ = `scale` everywhere (1: the tire's own road)."""

    scale: Float[Array, ""] = array_field(default=1.0)

    def __check_init__(self):
        check_positive("UniformGrip", "scale", self.scale)

    def scale_at(self, x, y):
        return self.scale + 0.0 * (x + y)


def _smoothstep(u):
    u = jnp.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


class GripPatches(AbstractGripField):
    r"""Circular patches on a uniform road: $\lambda = \lambda_0$ (`base`) away from them;
    patch $i$ (centre $c_i$, radius $R_i$, scale $\lambda_i$) blends in with the weight
    $w_i = \frac12\bigl(1 - \tanh\frac{|p - c_i| - R_i}{w}\bigr)$, $w$ = `width` [m]:
    $\lambda \leftarrow \lambda + w_i(\lambda_i - \lambda)$, patch after patch (a later patch
    lies on top of an earlier one).

    **Fields:** `base` (1), `centres` [m] shape (N, 2), `radii` [m] (N,), `scales` (N,),
    `width` [m] (1).
    """

    centres: Float[Array, "N 2"] = array_field()
    radii: Float[Array, " N"] = array_field()
    scales: Float[Array, " N"] = array_field()
    base: Float[Array, ""] = array_field(default=1.0)
    width: Float[Array, ""] = array_field(default=1.0)

    def __check_init__(self):
        owner = "GripPatches"
        if jnp.ndim(self.centres) != 2 or jnp.shape(self.centres)[-1] != 2:
            raise ValueError(f"{owner}.centres must have shape (N, 2), got "
                             f"{jnp.shape(self.centres)}")
        n = jnp.shape(self.centres)[0]
        for name in ("radii", "scales"):
            if jnp.shape(getattr(self, name)) != (n,):
                raise ValueError(f"{owner}.{name} must have shape ({n},) like centres, got "
                                 f"{jnp.shape(getattr(self, name))}")
        check_finite(owner, "centres", self.centres)
        check_positive(owner, "radii", self.radii)
        check_positive(owner, "scales", self.scales)
        check_positive(owner, "base", self.base)
        check_positive(owner, "width", self.width)

    def scale_at(self, x, y):
        lam = self.base + 0.0 * (x + y)
        for i in range(self.centres.shape[0]):
            d = safe_hypot(x - self.centres[i, 0], y - self.centres[i, 1])
            w = 0.5 * (1.0 - jnp.tanh((d - self.radii[i]) / self.width))
            lam = lam + w * (self.scales[i] - lam)
        return lam


class GripProfile(AbstractGripField):
    r"""Grip along a direction: with the station $s = (p - o)\cdot(\cos\phi, \sin\phi)$,
    $\lambda = \lambda_1$ before $s_1$, $\lambda_K$ after $s_K$, and between stations
    $\lambda_j + (\lambda_{j+1} - \lambda_j)S\bigl(\frac{s - s_j}{s_{j+1} - s_j}\bigr)$,
    $S(u) = 3u^2 - 2u^3$ (a $C^1$ ramp over each interval).

    **Fields:** `stations` $s_j$ [m] (K,), increasing; `scales` $\lambda_j$ (K,);
    `origin` $o$ [m] (2,) (0, 0); `direction` $\phi$ [rad] (0: along $x$).
    """

    stations: Float[Array, " K"] = array_field()
    scales: Float[Array, " K"] = array_field()
    origin: Float[Array, " 2"] = array_field(default=(0.0, 0.0))
    direction: Float[Array, ""] = array_field(default=0.0)

    def __check_init__(self):
        owner = "GripProfile"
        shape = jnp.shape(self.stations)
        if len(shape) != 1 or shape[0] < 1 or jnp.shape(self.scales) != shape:
            raise ValueError(f"{owner}.stations and scales must be vectors of one length >= 1,"
                             f" got shapes {shape} and {jnp.shape(self.scales)}")
        check_positive(owner, "scales", self.scales)
        check_finite(owner, "stations", self.stations)
        check_positive(owner, "stations (their increments)", jnp.diff(self.stations))
        if jnp.shape(self.origin) != (2,):
            raise ValueError(f"{owner}.origin must have shape (2,), got {jnp.shape(self.origin)}")
        check_finite(owner, "origin", self.origin)
        check_finite(owner, "direction", self.direction)

    def station(self, x, y):
        """$s$ of the point $(x, y)$ [m]."""
        return ((x - self.origin[0]) * jnp.cos(self.direction)
                + (y - self.origin[1]) * jnp.sin(self.direction))

    def scale_at(self, x, y):
        s = self.station(x, y)
        lam = self.scales[0] + 0.0 * s
        for j in range(self.stations.shape[0] - 1):
            u = (s - self.stations[j]) / (self.stations[j + 1] - self.stations[j])
            lam = lam + (self.scales[j + 1] - self.scales[j]) * _smoothstep(u)
        return lam


class RelativeGrip(AbstractGripField):
    r"""The field `field` relative to the friction scale `reference`: $r = \lambda /
    \lambda_{ref}$. A map of how the road's surfaces compare that says nothing of their
    level, as pace notes or a camera's surface classification give it
    (`AxleGripEstimator.surface`; along the centre line, `RoadTable.with_grip` for
    `RecedingHorizonDriver.surface_map`)."""

    field: AbstractGripField
    reference: Float[Array, ""] = array_field(default=1.0)

    def __check_init__(self):
        check_positive("RelativeGrip", "reference", self.reference)

    def scale_at(self, x, y):
        return self.field.scale_at(x, y) / self.reference


class SurfaceFactor(eqx.Module):
    r"""How a tire of another family is put on a road given in the LuGre plant's friction
    scales: on a surface of scale $\lambda$ its friction is scaled (`scale_friction`) by
    $m(\lambda)$ instead of $\lambda$, piecewise linear through the knots (`scales`,
    `factors`) and constant past the ends (`DrivePlant.surface_factor`).
    `vehsim.peak_surface_factor` gives the $m$ under which a Magic Formula, whose peak is
    proportional to its friction factors, has on every surface the LuGre plant's peak
    relative to the nominal road: the scenarios are stated as peaks, not scales.

    **Fields:** `scales` $\lambda_j$ (n >= 2, increasing), `factors` $m_j > 0$ (n).
    """

    scales: Float[Array, " n"] = array_field()
    factors: Float[Array, " n"] = array_field()

    def __check_init__(self):
        if self.scales.ndim != 1 or self.scales.shape[0] < 2:
            raise ValueError("SurfaceFactor.scales must be a vector of at least 2 scales, got "
                             f"shape {self.scales.shape}")
        if self.factors.shape != self.scales.shape:
            raise ValueError(f"SurfaceFactor.factors must have the shape of scales "
                             f"{self.scales.shape}, got {self.factors.shape}")
        check_positive("SurfaceFactor", "scales", self.scales)
        check_positive("SurfaceFactor", "factors", self.factors)
        if is_concrete(self.scales) and not np.all(np.diff(np.asarray(self.scales)) > 0):
            raise ValueError("SurfaceFactor.scales must increase strictly, got "
                             f"{plain(self.scales)}")

    def __call__(self, scale):
        r"""$m(\lambda)$ at the scale(s) `scale`."""
        return jnp.interp(scale, self.scales, self.factors)


class PeakRatios(AbstractGripField):
    r"""A map of friction-scale ratios $r(x, y)$ (`ratios`, e.g. the pace notes'
    `RelativeGrip`) read as ratios of the LuGre plant's peaks at the level $\lambda_{ref}$ =
    `reference`: $m(\lambda_{ref}\,r)$, $m$ = `factor` (`peak_surface_factor` of
    $\lambda_{ref}$, so $m(\lambda_{ref}) = 1$). The LuGre peak is not proportional to
    its scale (the icy patch's scale ratio 0.44 is a peak ratio of 0.50), so a shape-free
    estimator, which divides measured friction by the map, needs these
    (`AxlePeakEstimator.surface`)."""

    ratios: AbstractGripField
    factor: SurfaceFactor
    reference: Float[Array, ""] = array_field(default=1.0)

    def __check_init__(self):
        check_positive("PeakRatios", "reference", self.reference)

    def scale_at(self, x, y):
        return self.factor(self.reference * self.ratios.scale_at(x, y))


def scale_friction(tire: AbstractTire, scale) -> AbstractTire:
    r"""`tire` on a road of friction scale $\lambda$ = `scale`: its friction coefficients
    times $\lambda$ (`LuGre2DParams`: $\mu_k, \mu_s$; `LuGreParams`: $\mu_c, \mu_s$; a
    Magic Formula's `MFParams`, `MFTire` and `RelaxedMFTire`: its road-friction factors
    $\lambda_{\mu x}, \lambda_{\mu y}$, LMUX and LMUY, which scale the peaks $D_x, D_y$
    and the vertical shifts, not the slip stiffnesses: peak $\lambda$ times, the same
    initial slope, as for LuGre; a `FrictionEllipseTire`, the planning car's: its peak $D$,
    with $B$ and $C$, so its stiffness $BCD$ scales too), the rest unchanged (module
    docstring); `scale` > 0."""
    check_positive("scale_friction", "scale", scale)
    params = getattr(tire, "params", None)
    if isinstance(params, LuGre2DParams):
        return eqx.tree_at(lambda t: (t.params.mu_k, t.params.mu_s), tire,
                           (scale * params.mu_k, scale * params.mu_s))
    if isinstance(params, LuGreParams):
        return eqx.tree_at(lambda t: (t.params.mu_c, t.params.mu_s), tire,
                           (scale * params.mu_c, scale * params.mu_s))
    if isinstance(params, MFParams):
        return eqx.tree_at(lambda t: (t.params.LMUX, t.params.LMUY), tire,
                           (scale * params.LMUX, scale * params.LMUY))
    if isinstance(tire, FrictionEllipseTire):
        return eqx.tree_at(lambda t: t.D, tire, scale * tire.D)
    raise TypeError("scale_friction needs a LuGre tire (params LuGre2DParams or LuGreParams), "
                    "a Magic Formula (params MFParams) or a FrictionEllipseTire, got "
                    f"{type(tire).__name__}")
