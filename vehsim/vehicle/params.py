r"""Half-car (bicycle) vehicle parameters (report section 2.5, eqs. 49-60).

One axle stands for the two wheels of the real car: the wheel inertias, suspension
stiffnesses and damping coefficients are *per axle* (both wheels together).
"""

import equinox as eqx
from jaxtyping import Array, Float

from .._checks import check_positive, check_range
from .._constants import GRAVITY
from .._fields import array_field


class HalfCarParams(eqx.Module):
    r"""Parameters of the half-car of eqs. 49-60 (SI units).

    **Fields:**

    - `m` [kg]: vehicle mass $m$ (= suspended mass; wheel mass neglected, as in the report).
    - `Iz` [kg m^2]: yaw (polar) moment of inertia $J$ of eqs. 51, 63.
    - `Iy` [kg m^2]: pitch moment of inertia $I_y$ of eq. 55.
    - `lF`, `lR` [m]: distances of the front and rear axle from the centre of gravity;
      each $\ge 0$ and $\ell_F + \ell_R > 0$.
    - `h` [m]: centre-of-gravity height at equilibrium ($z = 0$), $h \ge 0$.
    - `r` [m]: wheel rolling radius.
    - `Iw_F`, `Iw_R` [kg m^2]: front and rear axle spin inertias $I_F$, $I_R$ (eqs. 52-53).
    - `K_F`, `K_R` [N/m]: front and rear axle suspension stiffness (eqs. 59-60), $> 0$.
    - `C_F`, `C_R` [N s/m]: front and rear axle suspension damping (eqs. 59-60), $\ge 0$.
    - `g` [m/s^2]: gravitational acceleration.

    All fields are arrays: a batch of vehicles is a `HalfCarParams` with leading batch
    axes, and gradients with respect to any field work.
    """

    m: Float[Array, "..."] = array_field()
    Iz: Float[Array, "..."] = array_field()
    lF: Float[Array, "..."] = array_field()
    lR: Float[Array, "..."] = array_field()
    h: Float[Array, "..."] = array_field()
    r: Float[Array, "..."] = array_field()
    Iw_F: Float[Array, "..."] = array_field()
    Iw_R: Float[Array, "..."] = array_field()
    Iy: Float[Array, "..."] = array_field(default=2500.0)
    K_F: Float[Array, "..."] = array_field(default=65_000.0)
    K_R: Float[Array, "..."] = array_field(default=65_000.0)
    C_F: Float[Array, "..."] = array_field(default=5_000.0)
    C_R: Float[Array, "..."] = array_field(default=5_000.0)
    g: Float[Array, "..."] = array_field(default=GRAVITY)

    def __check_init__(self):
        owner = "HalfCarParams"
        check_positive(owner, "m", self.m)
        check_positive(owner, "Iz", self.Iz)
        check_positive(owner, "Iy", self.Iy)
        check_range(owner, "lF", self.lF, lower=0.0)
        check_range(owner, "lR", self.lR, lower=0.0)
        check_positive(owner, "lF + lR (wheelbase)", self.lF + self.lR)
        check_range(owner, "h", self.h, lower=0.0)
        check_positive(owner, "r", self.r)
        check_positive(owner, "Iw_F", self.Iw_F)
        check_positive(owner, "Iw_R", self.Iw_R)
        check_positive(owner, "K_F", self.K_F)
        check_positive(owner, "K_R", self.K_R)
        check_range(owner, "C_F", self.C_F, lower=0.0)
        check_range(owner, "C_R", self.C_R, lower=0.0)
        check_positive(owner, "g", self.g)

    @property
    def wheelbase(self):
        r"""$\ell_F + \ell_R$ [m]."""
        return self.lF + self.lR

    def static_loads(self):
        r"""$(f_{Fz}^o, f_{Rz}^o) = mg(\ell_R, \ell_F)/(\ell_F+\ell_R)$ (eqs. 57-58) [N]."""
        w = self.m * self.g / self.wheelbase
        return w * self.lR, w * self.lF


def rally_gravel() -> HalfCarParams:
    r"""The "rally-gravel" half-car of the benchmark maneuvers (docs/maneuvers.md; after
    Velenis, Tsiotras and Lu).

    From the maneuver definition: m = 1450 kg, Iz = 2740 kg m^2, lF = 1.3 m, lR = 1.4 m, h = 0.4 m,
    r = 0.3 m, Iw = 1.8 kg m^2 per axle, g = 9.81 m/s^2.

    Not in the maneuver definition (only the full model's suspension uses them; chosen as plausible values
    for a soft rally car, **not from a source**): pitch inertia Iy = 2500 kg m^2 (about
    0.9 Iz, typical of a compact car); axle stiffness K_F = K_R = 65 kN/m, giving a heave
    frequency $\sqrt{(K_F+K_R)/m}/2\pi \approx 1.5$ Hz; axle damping C_F = C_R = 5 kN s/m,
    a heave damping ratio $(C_F+C_R)/(2\sqrt{(K_F+K_R)m}) \approx 0.36$.
    """
    return HalfCarParams(
        m=1450.0, Iz=2740.0, lF=1.3, lR=1.4, h=0.4, r=0.3, Iw_F=1.8, Iw_R=1.8,
        Iy=2500.0, K_F=65_000.0, K_R=65_000.0, C_F=5_000.0, C_R=5_000.0, g=GRAVITY,
    )
