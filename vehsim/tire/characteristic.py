r"""Steady-state tire characteristics: $(F_x, F_y, M_z)$ at slip ratio, slip angle and load.

What `vehsim.fit_to_magic_formula` fits the LuGre model to (report Fig. 15): anything that
gives the steady forces at $(\kappa, \alpha, F_z)$, in the signs of `vehsim.AbstractTire`
and `vehsim.tire.lugre2d` ($\alpha > 0$ when the wheel slides to its right; then
$F_y > 0$ and an aligning $M_z < 0$; $F_x > 0$ driving). The pure-slip curves are the
combined forces at zero slip angle ($F_x(\kappa)$) and zero slip ratio ($F_y(\alpha)$,
$M_z(\alpha)$).

- `MagicFormula1987Characteristic`: the 1987 Magic Formula of the report
  (`vehsim.tire.magic_formula`), already in these signs.
- `MFCharacteristic`: the Magic Formula 5.2 / 6.1 / 6.2 of a tyre property file
  (`vehsim.tire.mf6`), whose ISO-W axes have $\tan\alpha = V_{sy}/|V_{cx}|$ with $y$ to
  the left: a wheel sliding to its right has $\alpha_\text{ISO} < 0$, so
  $\alpha_\text{ISO} = -\alpha$ while $F_x$, $F_y$, $M_z$ point the same ways in both.

`tire_characteristic` turns the Magic Formula objects vehsim knows into one of these.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._fields import array_field
from .magic_formula import MagicFormula1987, MagicFormula1987Params, combined_forces
from .mf6 import MFParams, MFTire, RelaxedMFTire, _optional_array, mf_forces
from .tir import TirFile


class AbstractCharacteristic(eqx.Module):
    r"""A steady-state tire characteristic (module docstring): `forces` at slip ratio
    $\kappa$, slip angle $\alpha$ [rad] and load $F_z$ [N], broadcast together, stacked
    $(F_x, F_y, M_z)$ [N, N, N m] on a last axis of 3."""

    @abc.abstractmethod
    def forces(self, kappa, alpha, Fz) -> Float[Array, "*batch 3"]:
        """Combined-slip $(F_x, F_y, M_z)$."""

    @abc.abstractmethod
    def nominal_load(self) -> float:
        """A load [N] the coefficients are stated for (the fit's reference load)."""

    @abc.abstractmethod
    def fit_loads(self) -> tuple[float, ...]:
        """Loads [N] at which the LuGre model is fitted by default."""

    @abc.abstractmethod
    def slip_grid(self) -> tuple[Array, Array]:
        """Slip ratios and slip angles [rad] on which it is fitted by default."""

    def held_stribeck(self) -> tuple[str, ...]:
        r"""The Stribeck parameters of eq. 29 (of ``("v_s", "gamma")``) the LuGre fit
        holds by default: both, as pure-slip curves at one speed do not determine them
        (`vehsim.fit_to_magic_formula`)."""
        return ("v_s", "gamma")

    def pure_curves(self, Fz, kappa, alpha):
        r"""$(F_x(\kappa)|_{\alpha=0},\;F_y(\alpha)|_{\kappa=0},\;M_z(\alpha)|_{\kappa=0})$
        at load `Fz` [N] on the `kappa` and `alpha` [rad] grids."""
        zeros_k, zeros_a = jnp.zeros_like(kappa), jnp.zeros_like(alpha)
        lat = self.forces(zeros_a, alpha, Fz)
        return self.forces(kappa, zeros_k, Fz)[:, 0], lat[:, 1], lat[:, 2]


def _default_slip_grid():
    """Slip ratios in [-0.5, 0.5] and slip angles in (0, 20] deg (`default_slip_grid`)."""
    kappa = jnp.concatenate([jnp.linspace(-0.5, -0.01, 20), jnp.linspace(0.01, 0.5, 20)])
    alpha = jnp.deg2rad(jnp.linspace(0.5, 20.0, 30))
    return kappa, alpha


class MagicFormula1987Characteristic(AbstractCharacteristic):
    """The 1987 Magic Formula (`vehsim.tire.magic_formula.combined_forces`); fitted by
    default at 2, 4 and 6 kN (reference 4 kN) on `default_slip_grid` (its curves are odd,
    so positive slip angles suffice)."""

    params: MagicFormula1987Params

    def forces(self, kappa, alpha, Fz):
        return combined_forces(self.params, kappa, alpha, Fz)

    def nominal_load(self) -> float:
        return 4000.0

    def fit_loads(self) -> tuple[float, ...]:
        return (2000.0, 4000.0, 6000.0)

    def slip_grid(self):
        return _default_slip_grid()

    def held_stribeck(self) -> tuple[str, ...]:
        r"""None: the presets `lugre2d_bakker1987_mz` were fitted with $v_s$ and $\gamma$
        free, and that fit converges (to $v_s$ = 4.98 m/s, $\gamma$ = 1.13)."""
        return ()


class MFCharacteristic(AbstractCharacteristic):
    r"""A tyre property file's Magic Formula (`vehsim.tire.mf6.mf_forces` at
    $\alpha_\text{ISO} = -\alpha$, module docstring), at camber `camber` [rad] and
    pressure `pressure` [Pa] (default the file's ``INFLPRES``), its valid ranges applied
    (`limits`).

    Fitted by default at $0.5, 1, 1.5\,F'_{z0}$ ($F'_{z0} = \lambda_{Fz0}F_{z0}$, the
    reference; kept within [``FZMIN``, ``FZMAX``], each distinct load once), on the slip ratios of
    `default_slip_grid` and slip angles of both signs, $0.5° \le |\alpha| \le 20°$ (its
    shifts make the curves not odd), each kept within the file's valid ranges.
    """

    params: MFParams
    camber: Float[Array, ""] = array_field(default=0.0)
    pressure: Float[Array, ""] | None = eqx.field(default=None, converter=_optional_array)
    limits: bool = eqx.field(static=True, default=True)

    def forces(self, kappa, alpha, Fz):
        return mf_forces(self.params, kappa, -jnp.asarray(alpha), Fz, self.camber,
                         self.pressure, limits=self.limits)

    def nominal_load(self) -> float:
        return float(self.params.LFZO * self.params.FNOMIN)

    def fit_loads(self) -> tuple[float, ...]:
        lo, hi = float(self.params.FZMIN), float(self.params.FZMAX)
        # distinct: a narrow [FZMIN, FZMAX] clips two of them to the same load
        return tuple(dict.fromkeys(float(np.clip(f * self.nominal_load(), lo, hi))
                                   for f in (0.5, 1.0, 1.5)))

    def slip_grid(self):
        P = self.params
        kappa, alpha = _default_slip_grid()
        alpha = jnp.concatenate([-alpha[::-1], alpha])
        kappa = kappa[(kappa >= float(P.KPUMIN)) & (kappa <= float(P.KPUMAX))]
        # alpha here is -alpha_ISO: the file's range [ALPMIN, ALPMAX] turned round
        alpha = alpha[(-alpha >= float(P.ALPMIN)) & (-alpha <= float(P.ALPMAX))]
        return kappa, alpha


def tire_characteristic(tire) -> AbstractCharacteristic:
    """The `AbstractCharacteristic` of `tire`: an `AbstractCharacteristic` itself, a 1987
    Magic Formula (`MagicFormula1987Params`, `MagicFormula1987`), or a tyre property
    file's (`TirFile`, `MFParams`, `MFTire`, `RelaxedMFTire`: their camber, pressure and
    limits kept). Anything else is refused with a `TypeError`."""
    if isinstance(tire, AbstractCharacteristic):
        return tire
    if isinstance(tire, MagicFormula1987Params):
        return MagicFormula1987Characteristic(tire)
    if isinstance(tire, MagicFormula1987):
        return MagicFormula1987Characteristic(tire.params)
    if isinstance(tire, TirFile):
        return MFCharacteristic(MFParams.from_tir(tire))
    if isinstance(tire, MFParams):
        return MFCharacteristic(tire)
    if isinstance(tire, MFTire | RelaxedMFTire):
        return MFCharacteristic(tire.params, tire.camber, tire.pressure, tire.limits)
    raise TypeError(
        "a tire characteristic is an AbstractCharacteristic, a MagicFormula1987Params or "
        "MagicFormula1987, or a TirFile, MFParams, MFTire or RelaxedMFTire; got "
        f"{type(tire).__name__}")
