r"""The Magic Formula of the tyre property files: MF 5.2 (PAC2002), 6.1 and 6.2, steady state.

Equation numbers are those of Pacejka, *Tire and Vehicle Dynamics*, 3rd ed. (2012),
section 4.3.2 (4.E1-4.E78, the MF 6.1 set); "paper" is Besselink, Schmeitz and Pacejka
(2010), *An improved Magic Formula/Swift tyre model that can handle inflation pressure
changes*, Vehicle System Dynamics 48 sup. 1 (the MF-Tyre 6.1 the `.tir` files are fitted
with), equations (A..). Where the two differ we follow the paper for the coefficients the
files carry and say so; where neither fixes a detail we follow MFeval (Furlan), the
published implementation checked against TNO's solver.

**Axes and signs** are those of the file (ISO-W / TYDEX W, the MF-Tyre convention): slip
ratio $\kappa = -V_{sx}/|V_{cx}|$ ($> 0$ driving), slip angle $\alpha$ with
$\tan\alpha = V_{sy}/|V_{cx}|$ ($V_{sy}$ the lateral slip speed, $y$ to the left), camber
$\gamma$ [rad], load $F_z$ [N], pressure $p$ [Pa]. $F_y$ is to the left and $M_z$
counter-clockwise seen from above: with the usual $p_{Ky1} < 0$ a wheel sliding to its right
($\alpha < 0$) gets $F_y > 0$, as `vehsim.AbstractTire` wants.

**Pure slip** (4.E9-4.E47): $F_{x0} = D_x\sin(C_x\arctan(B_x\kappa_x - E_x(B_x\kappa_x -
\arctan B_x\kappa_x))) + S_{Vx}$ and likewise $F_{y0}$, with the load, camber and pressure
dependence of $D$, $K = BCD$, $E$ and the shifts; $M_{z0} = -t_0F_{y0,\gamma=0} + M_{zr0}$.
**Combined slip** (4.E50-4.E78): $F_x = G_{x\alpha}F_{x0}$, $F_y = G_{y\kappa}F_{y0} +
S_{Vy\kappa}$, $M_z = -tF'_y + M_{zr} + sF_x$. **Moments** $M_x$ (4.E69 with the
$q_{sx12..14}$ terms of MF-Tyre 6.1) and $M_y$ (paper A48; MF 5.2: the MF-Tyre 5.2 form).

**Versions.** MF 6.1 and 6.2 share these equations (6.2 changes the vertical model and the
loaded radius, not modelled here). MF 5.2 differs in: camber scaled by
$\lambda_{\gamma x,y,z}$ (``LGAX``, ``LGAY``, ``LGAZ``) and entering $F_y$ through
$S_{Hy} = (p_{Hy1} + p_{Hy2}df_z)\lambda_{Hy} + p_{Hy3}\gamma_y$ instead of the camber
stiffness $K_{y\gamma0}$ (4.E27, 4.E30); $M_z = -t(F_y - S_{Vy\kappa}) + M_{zr} + sF_x$;
$M_y$ proportional to $F_z$; the relaxation lengths from ``PTX1-3``, ``PTY1-2``. The version
is an array field, so tires of different versions batch together.

**Choices where the published forms differ** (each agrees with the others to rounding on
the files we read when the scaling factors are 1):

- $\alpha^* = \tan\alpha$, $\gamma^* = \sin\gamma$ (4.E3, 4.E4, as the book, for
  $V_{cx} > 0$). Running backwards uses the same characteristics: we drop the
  $\mathrm{sgn}V_{cx}$ factors of 4.E3, 4.E42, 4.E47 (and MFeval's sign flips of
  $F_{x0}$, $F_{y0}$), which would make the forces jump at standstill; with
  $\kappa = -V_{sx}/|V_{cx}|$ and $\tan\alpha = V_{sy}/|V_{cx}|$ the forces still oppose
  the slip. $M_y$ keeps its $\mathrm{sgn}V_x$ (it vanishes at rest).
- Camber signs in the trail: $B_t \propto 1 + q_{Bz4}\gamma + q_{Bz5}|\gamma|$ (paper A58; the
  book's 4.E40 uses a $q_{Bz6}$ the files lack) and $D_t \propto 1 + q_{Dz3}\gamma +
  q_{Dz4}\gamma^2$ (paper A60; the book's 4.E43 has $|\gamma|$).
- The trail's normalising load is $F'_{z0} = \lambda_{Fz0}F_{z0}$ in $D_t$ (4.E42, A60);
  MFeval multiplies $t$ by $\lambda_{Fz0}$ once more to match TNO's solver, which we do
  not; $s$ uses $F_y/F'_{z0}$ (4.E76).
- Equivalent slips $\alpha_{t,eq} = \sqrt{\alpha_t^2 + (K_{x\kappa}/K'_{y\alpha})^2\kappa^2}$
  (4.E77-4.E78; MFeval uses the paper's arctan/tan form, equal to third order). $t$ and
  $M_{zr}$ are even in them, so the sign factor is dropped (it makes no difference).
- The side force in the combined $M_z$ (MF 6.1): $F'_y = G_{y\kappa}F_{y0}$ both at
  $\gamma = 0$ (4.E74). MFeval and TyreDyn, to match TNO's solver, take $G_{y\kappa}$ at the
  actual camber; the two differ only where $r_{By4} \ne 0$ (its $\gamma^{*2}$ term in
  $B_{y\kappa}$), by 0.2 % of $M_z$ at $r_{By4} = 20$, $\gamma = 0.1$ rad.
- $M_{zr} = D_r\cos(C_r\arctan B_r\alpha_{r,eq})\cos\alpha$: one factor $\cos\alpha$
  ($\cos\alpha'$ of 4.E36 at steady state) in pure and combined slip alike.
- Friction scaling: $\lambda'_\mu = \lambda^*_\mu = \lambda_\mu$ (4.E7 with
  $\lambda_{\mu V} = 0$, 4.E8 with $A_\mu = 1$, as TNO's solver; the book suggests 10).
- The clamp $E \le 1$ (4.E14, 4.E24, 4.E44, 4.E56, 4.E64) is applied with the limits.
- Singularities: the book guards $B = K/(CD + \varepsilon)$ and the divisions by
  $K_{y\alpha}$ with small numbers $\varepsilon$ (4.E6a). We divide per unit load instead
  ($K/F_z$ by $CD/F_z$, in closed form down to $F_z = 0$) and take 0 where a divisor is
  exactly 0 (double ``where``): the published value wherever it is defined, and finite
  values and gradients at zero load, zero friction and zero stiffness.

**Low speed** (`vx` given; MF-Tyre's VXLOW handling as MFeval reads it): below
$V_{XLOW}$ the slips fall linearly to 0 with $|V_x|/V_{XLOW}$ (the slip angle with
$(|V_x| + |V_{sy}|)/V_{XLOW}$), and the shifts $S_{Hx}, S_{Vx}, S_{Hy}, S_{Vy},
S_{Vy\kappa}$, the trail and the residual moment by $\tfrac12(1 - \cos(\pi|V_x|/V_{XLOW}))$,
so every force and moment vanishes at standstill with finite gradients.

**Limits** (``limits=True``, as the file states them): $\kappa$ to [KPUMIN, KPUMAX],
$\alpha$ to [ALPMIN, ALPMAX] and within `ALPHA_BOUND` of 0 (files state ALPMAX = 1.5708 for
$\pi/2$, past the pole of the $\tan\alpha$ the formulas take), $\gamma$ to [CAMMIN, CAMMAX], $p$ to [PRESMIN, PRESMAX],
$F_z$ to at most FZMAX (and at least 0). FZMIN is not a clamp: raising a smaller load to
it would give a force at zero load (MFeval uses it only inside the moments).

Not modelled: turn slip (all $\zeta_i = 1$), the vertical model, the loaded and effective
rolling radii (the vehicle supplies $r$), TYRESIDE mirroring (the file's characteristics
are used as written).
"""

from __future__ import annotations

import math
import warnings
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import (
    check_finite,
    check_nonnegative,
    check_not_nan,
    check_order,
    check_positive,
    check_range,
    check_type,
)
from .._fields import array_field, float_array
from .._math import safe_abs, safe_div, safe_pow_abs, safe_sqrt
from .base import AbstractTire
from .lugre import AbstractLongitudinalTire
from .tir import ORDERED_PAIRS


_C = Float[Array, "*batch"]
VERSIONS = (5.2, 6.1, 6.2)


class MFParams(eqx.Module):
    r"""Coefficients of a Magic Formula tyre property file, in SI units (module docstring).

    Each field is the `.tir` key of the same name (an array: new values never recompile,
    and a batch of tires is a module with leading axes). Absent keys take their neutral
    values: coefficients 0, scaling factors 1, ``PKY4 = 2``, ranges unbounded. `version`
    is 5.2, 6.1 or 6.2. Build one from a file with `MFParams.from_tir`.
    """

    version: _C = array_field(default=6.1)
    # Operating conditions and geometry ([VERTICAL], [DIMENSION], [OPERATING_CONDITIONS], [MODEL])
    FNOMIN: _C = array_field(default=4000.0)
    UNLOADED_RADIUS: _C = array_field(default=0.3)
    NOMPRES: _C = array_field(default=2.2e5)
    INFLPRES: _C = array_field(default=2.2e5)
    LONGVL: _C = array_field(default=16.7)
    VXLOW: _C = array_field(default=1.0)
    # Valid ranges, applied as limits ([*_RANGE]; absent = unbounded)
    FZMIN: _C = array_field(default=0.0)
    FZMAX: _C = array_field(default=math.inf)
    KPUMIN: _C = array_field(default=-math.inf)
    KPUMAX: _C = array_field(default=math.inf)
    ALPMIN: _C = array_field(default=-math.inf)
    ALPMAX: _C = array_field(default=math.inf)
    CAMMIN: _C = array_field(default=-math.inf)
    CAMMAX: _C = array_field(default=math.inf)
    PRESMIN: _C = array_field(default=0.0)
    PRESMAX: _C = array_field(default=math.inf)
    # Scaling factors ([SCALING_COEFFICIENTS]; absent = 1)
    LFZO: _C = array_field(default=1.0)
    LCX: _C = array_field(default=1.0)
    LMUX: _C = array_field(default=1.0)
    LEX: _C = array_field(default=1.0)
    LKX: _C = array_field(default=1.0)
    LHX: _C = array_field(default=1.0)
    LVX: _C = array_field(default=1.0)
    LGAX: _C = array_field(default=1.0)
    LCY: _C = array_field(default=1.0)
    LMUY: _C = array_field(default=1.0)
    LEY: _C = array_field(default=1.0)
    LKY: _C = array_field(default=1.0)
    LHY: _C = array_field(default=1.0)
    LVY: _C = array_field(default=1.0)
    LGAY: _C = array_field(default=1.0)
    LKYC: _C = array_field(default=1.0)
    LKZC: _C = array_field(default=1.0)
    LTR: _C = array_field(default=1.0)
    LRES: _C = array_field(default=1.0)
    LGAZ: _C = array_field(default=1.0)
    LXAL: _C = array_field(default=1.0)
    LYKA: _C = array_field(default=1.0)
    LVYKA: _C = array_field(default=1.0)
    LS: _C = array_field(default=1.0)
    LSGKP: _C = array_field(default=1.0)
    LSGAL: _C = array_field(default=1.0)
    LMX: _C = array_field(default=1.0)
    LVMX: _C = array_field(default=1.0)
    LMY: _C = array_field(default=1.0)
    # Longitudinal force ([LONGITUDINAL_COEFFICIENTS]; absent = 0)
    PCX1: _C = array_field(default=0.0)
    PDX1: _C = array_field(default=0.0)
    PDX2: _C = array_field(default=0.0)
    PDX3: _C = array_field(default=0.0)
    PEX1: _C = array_field(default=0.0)
    PEX2: _C = array_field(default=0.0)
    PEX3: _C = array_field(default=0.0)
    PEX4: _C = array_field(default=0.0)
    PKX1: _C = array_field(default=0.0)
    PKX2: _C = array_field(default=0.0)
    PKX3: _C = array_field(default=0.0)
    PHX1: _C = array_field(default=0.0)
    PHX2: _C = array_field(default=0.0)
    PVX1: _C = array_field(default=0.0)
    PVX2: _C = array_field(default=0.0)
    PPX1: _C = array_field(default=0.0)
    PPX2: _C = array_field(default=0.0)
    PPX3: _C = array_field(default=0.0)
    PPX4: _C = array_field(default=0.0)
    RBX1: _C = array_field(default=0.0)
    RBX2: _C = array_field(default=0.0)
    RBX3: _C = array_field(default=0.0)
    RCX1: _C = array_field(default=0.0)
    REX1: _C = array_field(default=0.0)
    REX2: _C = array_field(default=0.0)
    RHX1: _C = array_field(default=0.0)
    PTX1: _C = array_field(default=0.0)
    PTX2: _C = array_field(default=0.0)
    PTX3: _C = array_field(default=0.0)
    # Overturning moment ([OVERTURNING_COEFFICIENTS])
    QSX1: _C = array_field(default=0.0)
    QSX2: _C = array_field(default=0.0)
    QSX3: _C = array_field(default=0.0)
    QSX4: _C = array_field(default=0.0)
    QSX5: _C = array_field(default=0.0)
    QSX6: _C = array_field(default=0.0)
    QSX7: _C = array_field(default=0.0)
    QSX8: _C = array_field(default=0.0)
    QSX9: _C = array_field(default=0.0)
    QSX10: _C = array_field(default=0.0)
    QSX11: _C = array_field(default=0.0)
    QSX12: _C = array_field(default=0.0)
    QSX13: _C = array_field(default=0.0)
    QSX14: _C = array_field(default=0.0)
    PPMX1: _C = array_field(default=0.0)
    # Lateral force ([LATERAL_COEFFICIENTS]; absent = 0 but PKY4 = 2)
    PCY1: _C = array_field(default=0.0)
    PDY1: _C = array_field(default=0.0)
    PDY2: _C = array_field(default=0.0)
    PDY3: _C = array_field(default=0.0)
    PEY1: _C = array_field(default=0.0)
    PEY2: _C = array_field(default=0.0)
    PEY3: _C = array_field(default=0.0)
    PEY4: _C = array_field(default=0.0)
    PEY5: _C = array_field(default=0.0)
    PKY1: _C = array_field(default=0.0)
    PKY2: _C = array_field(default=0.0)
    PKY3: _C = array_field(default=0.0)
    PKY4: _C = array_field(default=2.0)
    PKY5: _C = array_field(default=0.0)
    PKY6: _C = array_field(default=0.0)
    PKY7: _C = array_field(default=0.0)
    PHY1: _C = array_field(default=0.0)
    PHY2: _C = array_field(default=0.0)
    PHY3: _C = array_field(default=0.0)
    PVY1: _C = array_field(default=0.0)
    PVY2: _C = array_field(default=0.0)
    PVY3: _C = array_field(default=0.0)
    PVY4: _C = array_field(default=0.0)
    PPY1: _C = array_field(default=0.0)
    PPY2: _C = array_field(default=0.0)
    PPY3: _C = array_field(default=0.0)
    PPY4: _C = array_field(default=0.0)
    PPY5: _C = array_field(default=0.0)
    RBY1: _C = array_field(default=0.0)
    RBY2: _C = array_field(default=0.0)
    RBY3: _C = array_field(default=0.0)
    RBY4: _C = array_field(default=0.0)
    RCY1: _C = array_field(default=0.0)
    REY1: _C = array_field(default=0.0)
    REY2: _C = array_field(default=0.0)
    RHY1: _C = array_field(default=0.0)
    RHY2: _C = array_field(default=0.0)
    RVY1: _C = array_field(default=0.0)
    RVY2: _C = array_field(default=0.0)
    RVY3: _C = array_field(default=0.0)
    RVY4: _C = array_field(default=0.0)
    RVY5: _C = array_field(default=0.0)
    RVY6: _C = array_field(default=0.0)
    PTY1: _C = array_field(default=0.0)
    PTY2: _C = array_field(default=0.0)
    # Rolling resistance moment ([ROLLING_COEFFICIENTS])
    QSY1: _C = array_field(default=0.0)
    QSY2: _C = array_field(default=0.0)
    QSY3: _C = array_field(default=0.0)
    QSY4: _C = array_field(default=0.0)
    QSY5: _C = array_field(default=0.0)
    QSY6: _C = array_field(default=0.0)
    QSY7: _C = array_field(default=0.0)
    QSY8: _C = array_field(default=0.0)
    # Aligning moment ([ALIGNING_COEFFICIENTS])
    QBZ1: _C = array_field(default=0.0)
    QBZ2: _C = array_field(default=0.0)
    QBZ3: _C = array_field(default=0.0)
    QBZ4: _C = array_field(default=0.0)
    QBZ5: _C = array_field(default=0.0)
    QBZ9: _C = array_field(default=0.0)
    QBZ10: _C = array_field(default=0.0)
    QCZ1: _C = array_field(default=0.0)
    QDZ1: _C = array_field(default=0.0)
    QDZ2: _C = array_field(default=0.0)
    QDZ3: _C = array_field(default=0.0)
    QDZ4: _C = array_field(default=0.0)
    QDZ6: _C = array_field(default=0.0)
    QDZ7: _C = array_field(default=0.0)
    QDZ8: _C = array_field(default=0.0)
    QDZ9: _C = array_field(default=0.0)
    QDZ10: _C = array_field(default=0.0)
    QDZ11: _C = array_field(default=0.0)
    QEZ1: _C = array_field(default=0.0)
    QEZ2: _C = array_field(default=0.0)
    QEZ3: _C = array_field(default=0.0)
    QEZ4: _C = array_field(default=0.0)
    QEZ5: _C = array_field(default=0.0)
    QHZ1: _C = array_field(default=0.0)
    QHZ2: _C = array_field(default=0.0)
    QHZ3: _C = array_field(default=0.0)
    QHZ4: _C = array_field(default=0.0)
    PPZ1: _C = array_field(default=0.0)
    PPZ2: _C = array_field(default=0.0)
    SSZ1: _C = array_field(default=0.0)
    SSZ2: _C = array_field(default=0.0)
    SSZ3: _C = array_field(default=0.0)
    SSZ4: _C = array_field(default=0.0)
    # Carcass stiffness ([STRUCTURAL]; MF 6.x relaxation lengths)
    LONGITUDINAL_STIFFNESS: _C = array_field(default=0.0)
    LATERAL_STIFFNESS: _C = array_field(default=0.0)
    PCFX1: _C = array_field(default=0.0)
    PCFX2: _C = array_field(default=0.0)
    PCFX3: _C = array_field(default=0.0)
    PCFY1: _C = array_field(default=0.0)
    PCFY2: _C = array_field(default=0.0)
    PCFY3: _C = array_field(default=0.0)
    def __check_init__(self):
        owner = "MFParams"
        for name in ("FNOMIN", "UNLOADED_RADIUS", "NOMPRES", "INFLPRES", "LONGVL", "VXLOW",
                     "LFZO"):
            check_positive(owner, name, getattr(self, name))
        check_range(owner, "version", self.version, lower=5.2, upper=6.2)
        for lo, hi in ORDERED_PAIRS:  # a limit may be infinite (none), never NaN
            for name in (lo, hi):
                check_not_nan(owner, name, getattr(self, name))
            check_order(owner, lo, getattr(self, lo), hi, getattr(self, hi))
        limits = {name for pair in ORDERED_PAIRS for name in pair}
        for name in FIELD_NAMES:
            if name not in limits:
                check_finite(owner, name, getattr(self, name))
        for name in ("PCX1", "PCY1", "QCZ1", "PKY2"):  # shape factors, > 0 in any .tir
            check_nonnegative(owner, name, getattr(self, name))

    @classmethod
    def from_tir(cls, tir) -> MFParams:
        """The coefficients of a `vehsim.TirFile` (values converted to SI)."""
        kwargs = {name: tir.get(name) for name in FIELD_NAMES if name in tir}
        kwargs["version"] = float(tir.version)
        unused = [f"{k} = {kwargs[k]:g}" for k in ("LGAX", "LGAY", "LGAZ")
                  if kwargs["version"] >= 6.0 and k in kwargs and float(kwargs[k]) != 1.0]
        if unused:
            warnings.warn(f"{', '.join(unused)}: MF 5.2 camber scalings, which MF "
                          f"{kwargs['version']:g} does not have (it scales camber through "
                          "LKYC and LKZC); not used", stacklevel=2)
        if "NOMPRES" not in kwargs:  # MF 5.2 has no pressure terms: any positive value
            kwargs["NOMPRES"] = kwargs.get("INFLPRES", 2.2e5)
        kwargs.setdefault("INFLPRES", kwargs["NOMPRES"])
        return cls(**kwargs)


FIELD_NAMES = ("FNOMIN", "UNLOADED_RADIUS", "NOMPRES", "INFLPRES", "LONGVL", "VXLOW", "FZMIN",
               "FZMAX", "KPUMIN", "KPUMAX", "ALPMIN", "ALPMAX", "CAMMIN", "CAMMAX", "PRESMIN",
               "PRESMAX", "LFZO", "LCX", "LMUX", "LEX", "LKX", "LHX", "LVX", "LGAX", "LCY",
               "LMUY", "LEY", "LKY", "LHY", "LVY", "LGAY", "LKYC", "LKZC", "LTR", "LRES",
               "LGAZ", "LXAL", "LYKA", "LVYKA", "LS", "LSGKP", "LSGAL", "LMX", "LVMX", "LMY",
               "PCX1", "PDX1", "PDX2", "PDX3", "PEX1", "PEX2", "PEX3", "PEX4", "PKX1", "PKX2",
               "PKX3", "PHX1", "PHX2", "PVX1", "PVX2", "PPX1", "PPX2", "PPX3", "PPX4", "RBX1",
               "RBX2", "RBX3", "RCX1", "REX1", "REX2", "RHX1", "PTX1", "PTX2", "PTX3", "QSX1",
               "QSX2", "QSX3", "QSX4", "QSX5", "QSX6", "QSX7", "QSX8", "QSX9", "QSX10",
               "QSX11", "QSX12", "QSX13", "QSX14", "PPMX1", "PCY1", "PDY1", "PDY2", "PDY3",
               "PEY1", "PEY2", "PEY3", "PEY4", "PEY5", "PKY1", "PKY2", "PKY3", "PKY4", "PKY5",
               "PKY6", "PKY7", "PHY1", "PHY2", "PHY3", "PVY1", "PVY2", "PVY3", "PVY4", "PPY1",
               "PPY2", "PPY3", "PPY4", "PPY5", "RBY1", "RBY2", "RBY3", "RBY4", "RCY1", "REY1",
               "REY2", "RHY1", "RHY2", "RVY1", "RVY2", "RVY3", "RVY4", "RVY5", "RVY6", "PTY1",
               "PTY2", "QSY1", "QSY2", "QSY3", "QSY4", "QSY5", "QSY6", "QSY7", "QSY8", "QBZ1",
               "QBZ2", "QBZ3", "QBZ4", "QBZ5", "QBZ9", "QBZ10", "QCZ1", "QDZ1", "QDZ2",
               "QDZ3", "QDZ4", "QDZ6", "QDZ7", "QDZ8", "QDZ9", "QDZ10", "QDZ11", "QEZ1",
               "QEZ2", "QEZ3", "QEZ4", "QEZ5", "QHZ1", "QHZ2", "QHZ3", "QHZ4", "PPZ1", "PPZ2",
               "SSZ1", "SSZ2", "SSZ3", "SSZ4", "LONGITUDINAL_STIFFNESS", "LATERAL_STIFFNESS",
               "PCFX1", "PCFX2", "PCFX3", "PCFY1", "PCFY2", "PCFY3")


class MFOutput(eqx.Module):
    r"""Everything `mf_evaluate` computes, each an array of the operating points' shape.

    - `Fx`, `Fy`, `Mz`, `Mx`, `My`: combined-slip forces [N] and moments [N m];
    - `Fx0`, `Fy0`, `Mz0`: the pure-slip ones;
    - `mux`, `muy`: peak friction coefficients (4.E13, 4.E23);
    - `Kxk` [N], `Kya` [N/rad]: slip and cornering stiffnesses (4.E15, 4.E25);
    - `t` [m]: pneumatic trail (4.E73), `Mzr` [N m]: residual moment (4.E75);
    - `Gxa`, `Gyk`: combined-slip weighting functions (4.E51, 4.E59), `SVyk` [N]: the
      $\kappa$-induced side force (4.E66).
    """

    Fx: Array
    Fy: Array
    Mz: Array
    Mx: Array
    My: Array
    Fx0: Array
    Fy0: Array
    Mz0: Array
    mux: Array
    muy: Array
    Kxk: Array
    Kya: Array
    t: Array
    Mzr: Array
    Gxa: Array
    Gyk: Array
    SVyk: Array


def _optional_array(x):
    """None, or `x` as a float array (so a new value never recompiles)."""
    return None if x is None else float_array(x)


def _sgn1(x):
    """sgn(x) with sgn(0) = 1 (MFeval's reading of sgn(alpha_y) in 4.E24)."""
    return jnp.where(x < 0, -1.0, 1.0)


def _mf(B, C, D, E, x):
    r"""$D\sin(C\arctan(Bx - E(Bx - \arctan Bx)))$."""
    bx = B * x
    return D * jnp.sin(C * jnp.arctan(bx - E * (bx - jnp.arctan(bx))))


def _weighting(C, B, E, x):
    r"""$\cos(C\arctan(Bx - E(Bx - \arctan Bx)))$ (4.E51-4.E52, 4.E59-4.E60)."""
    bx = B * x
    return jnp.cos(C * jnp.arctan(bx - E * (bx - jnp.arctan(bx))))


ALPHA_BOUND = 0.5 * math.pi * (1.0 - 1e-9)
r"""Largest $|\alpha|$ [rad] the limits let through: just below the pole of $\tan\alpha$ at
$\pi/2$, where the slip's sign would turn."""


def _sin_n_atan_over(u, n):
    r"""$\sin(n\arctan u)/u$, equal to $n$ at $u = 0$ (smooth: it is even in $u$)."""
    small = u == 0
    u_safe = jnp.where(small, 1.0, u)
    return jnp.where(small, n * jnp.ones_like(u), jnp.sin(n * jnp.arctan(u_safe)) / u_safe)


def _sin_n_atan_over_uc(Fz, fz0p, c, n):
    r"""$\sin(n\arctan u)/(u c)$ with $u = F_z/(F_{z0}' c)$: the cornering stiffness per
    unit load of 4.E25 over $PKY1$, finite where $c$ = PKY2 + PKY5 $\gamma^2$ is 0 (PKY2 = 0,
    as `MFParams()` has it): for $|u| > 1$ it is $\sin(n\theta)F_{z0}'/F_z$ with $\theta = \arctan u
    = \mathrm{sgn}(u)\pi/2 - \arctan(1/u)$, so that no $1/c$ is formed, and both branches
    are evaluated where they are used (double `where`). At $F_z = c = 0$, where it is
    infinite, $c$ is taken as $10^{-12}$."""
    big = jnp.abs(Fz) > jnp.abs(c * fz0p)  # |u| > 1, so Fz != 0
    Fz_b = jnp.where(big, Fz, 1.0)
    sign_u = jnp.sign(Fz_b) * jnp.where(c < 0, -1.0, 1.0)  # c = 0: the limit c -> 0+
    theta = sign_u * (0.5 * jnp.pi) - jnp.arctan(jnp.where(big, c * fz0p / Fz_b, 0.0))
    large = jnp.sin(n * theta) * fz0p / Fz_b
    c_s = jnp.where(big, 1.0, jnp.where(c == 0, 1e-12, c))
    small = _sin_n_atan_over(jnp.where(big, 0.0, Fz / (fz0p * c_s)), n) / c_s
    return jnp.where(big, large, small)


def _clamp_e(E, limits):
    return jnp.minimum(E, 1.0) if limits else E


def _lateral_pure(P, Fz, dfz, dpi, alpha_s, gy, w, limits):
    """(Fy0, muy, Kya per unit load, By, Cy, SHy, SVy per unit load) at camber `gy`
    (4.E19-4.E30; MF 5.2 shifts where `version` < 6)."""
    is52 = P.version < 6.0
    lmuy_p = P.LMUY
    c = (P.PKY2 + P.PKY5 * gy**2) * (1.0 + P.PPY2 * dpi)
    kyn = (P.PKY1 * (1.0 + P.PPY1 * dpi) * (1.0 - P.PKY3 * safe_abs(gy))
           * _sin_n_atan_over_uc(Fz, P.FNOMIN * P.LFZO, c, P.PKY4) * P.LKY)
    svyg_n = (P.PVY3 + P.PVY4 * dfz) * gy * P.LKYC * lmuy_p  # S_Vyg / Fz (4.E28)
    kyg0_n = (P.PKY6 + P.PKY7 * dfz) * (1.0 + P.PPY5 * dpi) * P.LKYC  # K_yg0 / Fz (4.E30)
    shy_61 = (P.PHY1 + P.PHY2 * dfz) * P.LHY + safe_div(kyg0_n * gy - svyg_n, kyn)  # 4.E27
    shy_52 = (P.PHY1 + P.PHY2 * dfz) * P.LHY + P.PHY3 * gy * P.LKYC
    shy = jnp.where(is52, shy_52, shy_61) * w
    svy_n = ((P.PVY1 + P.PVY2 * dfz) * P.LVY * lmuy_p + svyg_n) * w  # 4.E29 / Fz
    ay = alpha_s + shy  # 4.E20
    cy = P.PCY1 * P.LCY  # 4.E21
    muy = ((P.PDY1 + P.PDY2 * dfz) * (1.0 + P.PPY3 * dpi + P.PPY4 * dpi**2)
           * (1.0 - P.PDY3 * gy**2) * P.LMUY)  # 4.E23
    ey = _clamp_e((P.PEY1 + P.PEY2 * dfz) * (1.0 + P.PEY5 * gy**2
                                             - (P.PEY3 + P.PEY4 * gy) * _sgn1(ay)) * P.LEY,
                  limits)  # 4.E24
    by = safe_div(kyn, cy * muy)  # 4.E26, per unit load
    fy0 = _mf(by, cy, muy * Fz, ey, ay) + svy_n * Fz  # 4.E19, 4.E22
    return fy0, muy, kyn, by, cy, shy, svy_n


def _combined_lateral_weight(P, kappa, dfz, alpha_s, gy, limits):
    """G_yk (4.E59-4.E65)."""
    byk = (P.RBY1 + P.RBY4 * gy**2) * jnp.cos(jnp.arctan(P.RBY2 * (alpha_s - P.RBY3))) * P.LYKA
    cyk = P.RCY1
    eyk = _clamp_e(P.REY1 + P.REY2 * dfz, limits)
    shyk = P.RHY1 + P.RHY2 * dfz
    return (_weighting(cyk, byk, eyk, kappa + shyk) / _weighting(cyk, byk, eyk, shyk))


def _operating_point(P, kappa, alpha, gamma, Fz, p, vx, limits, reduce_slips):
    """Inputs after the limits and the low-speed reduction, the low-speed weight and sgn Vx."""
    kappa, alpha, gamma, Fz = (jnp.asarray(x, dtype=float) for x in (kappa, alpha, gamma, Fz))
    p = P.INFLPRES if p is None else jnp.asarray(p, dtype=float)
    Fz = jnp.maximum(Fz, 0.0)
    if vx is None:
        w, sgn_vx, vabs = 1.0, 1.0, P.LONGVL
    else:
        vx = jnp.asarray(vx, dtype=float)
        vabs = safe_abs(vx)
        low = vabs < P.VXLOW
        w = jnp.where(low, 0.5 * (1.0 - jnp.cos(jnp.pi * vabs / P.VXLOW)), 1.0)
        sgn_vx = _sgn1(vx)
        if reduce_slips:
            kappa = kappa * jnp.minimum(vabs / P.VXLOW, 1.0)
            speed = vabs + safe_abs(jnp.tan(alpha) * vabs)
            alpha = alpha * jnp.minimum(speed / P.VXLOW, 1.0)
    if limits:
        kappa = jnp.clip(kappa, P.KPUMIN, P.KPUMAX)
        alpha = jnp.clip(alpha, jnp.maximum(P.ALPMIN, -ALPHA_BOUND),
                         jnp.minimum(P.ALPMAX, ALPHA_BOUND))
        gamma = jnp.clip(gamma, P.CAMMIN, P.CAMMAX)
        p = jnp.clip(p, P.PRESMIN, P.PRESMAX)
        Fz = jnp.minimum(Fz, P.FZMAX)
    return kappa, alpha, gamma, Fz, p, w, sgn_vx, vabs


def mf_evaluate(params: MFParams, kappa, alpha, Fz, gamma=0.0, p=None, vx=None, *,
                limits: bool = True, _reduce_slips: bool = True) -> MFOutput:
    r"""Forces and moments of the Magic Formula at the given operating points.

    **Arguments** (broadcast together; axes and signs of the module docstring):

    - `params`: `MFParams`.
    - `kappa` [-], `alpha` [rad], `Fz` [N], `gamma` [rad] (default 0).
    - `p`: inflation pressure [Pa] (default the file's ``INFLPRES``).
    - `vx`: wheel speed $V_x$ [m/s]; when given, the low-speed reduction applies and
      $M_y$ uses it (else $M_y$ is at ``LONGVL``, with no reduction).
    - `limits`: apply the file's valid ranges and the $E \le 1$ clamps (default True).

    **Returns:** `MFOutput`.
    """
    P = params
    kappa, alpha, gamma, Fz, p, w, sgn_vx, vabs = _operating_point(
        P, kappa, alpha, gamma, Fz, p, vx, limits, _reduce_slips)
    is52 = P.version < 6.0
    fz0p = P.LFZO * P.FNOMIN  # 4.E1
    dfz = (Fz - fz0p) / fz0p  # 4.E2a
    dpi = (p - P.NOMPRES) / P.NOMPRES  # 4.E2b
    alpha_s = jnp.tan(alpha)  # 4.E3
    gamma_s = jnp.sin(gamma)  # 4.E4
    # MF 5.2's camber scalings; MF 6.1 has none (it scales camber through LKYC, LKZC)
    gx, gy, gz = (gamma_s * jnp.where(is52, L, 1.0) for L in (P.LGAX, P.LGAY, P.LGAZ))
    R0 = P.UNLOADED_RADIUS

    # pure longitudinal slip, 4.E9-4.E18
    cx = P.PCX1 * P.LCX
    mux = ((P.PDX1 + P.PDX2 * dfz) * (1.0 + P.PPX3 * dpi + P.PPX4 * dpi**2)
           * (1.0 - P.PDX3 * gx**2) * P.LMUX)
    kxn = ((P.PKX1 + P.PKX2 * dfz) * jnp.exp(P.PKX3 * dfz)
           * (1.0 + P.PPX1 * dpi + P.PPX2 * dpi**2) * P.LKX)  # K_xk / Fz
    bx = safe_div(kxn, cx * mux)  # 4.E16, per unit load
    shx = (P.PHX1 + P.PHX2 * dfz) * P.LHX * w
    svx = Fz * (P.PVX1 + P.PVX2 * dfz) * P.LVX * P.LMUX * w
    kx = kappa + shx
    ex = _clamp_e((P.PEX1 + P.PEX2 * dfz + P.PEX3 * dfz**2) * (1.0 - P.PEX4 * jnp.sign(kx))
                  * P.LEX, limits)
    fx0 = _mf(bx, cx, mux * Fz, ex, kx) + svx  # 4.E9

    # pure lateral slip, 4.E19-4.E30
    fy0, muy, kyn, by, cy, shy, svy_n = _lateral_pure(P, Fz, dfz, dpi, alpha_s, gy, w, limits)
    fy0_g0, *_ = _lateral_pure(P, Fz, dfz, dpi, alpha_s, jnp.zeros_like(gy), w, limits)

    # aligning moment, 4.E31-4.E47 (trail camber signs: paper A58, A60)
    sht = P.QHZ1 + P.QHZ2 * dfz + (P.QHZ3 + P.QHZ4 * dfz) * gz  # 4.E35
    shf = shy + safe_div(svy_n, kyn)  # 4.E38
    ar = alpha_s + shf  # 4.E37
    at = alpha_s + sht  # 4.E34
    dt = ((P.QDZ1 + P.QDZ2 * dfz) * (1.0 - P.PPZ1 * dpi) * (1.0 + P.QDZ3 * gz + P.QDZ4 * gz**2)
          * Fz * (R0 / fz0p) * P.LTR)  # 4.E42-4.E43, A60
    bt = ((P.QBZ1 + P.QBZ2 * dfz + P.QBZ3 * dfz**2) * (1.0 + P.QBZ4 * gz + P.QBZ5 * safe_abs(gz))
          * P.LKY / P.LMUY)  # 4.E40, A58
    ct = P.QCZ1  # 4.E41
    et = _clamp_e((P.QEZ1 + P.QEZ2 * dfz + P.QEZ3 * dfz**2)
                  * (1.0 + (P.QEZ4 + P.QEZ5 * gz) * (2.0 / jnp.pi) * jnp.arctan(bt * ct * at)),
                  limits)  # 4.E44
    dr = (Fz * R0 * ((P.QDZ6 + P.QDZ7 * dfz) * P.LRES
                     + ((P.QDZ8 + P.QDZ9 * dfz) * (1.0 + P.PPZ2 * dpi)
                        + (P.QDZ10 + P.QDZ11 * dfz) * safe_abs(gz)) * gz * P.LKZC)
          * P.LMUY)  # 4.E47
    br = P.QBZ9 * P.LKY / P.LMUY + P.QBZ10 * by * cy  # 4.E45
    cos_a = jnp.cos(alpha)

    def trail(a_eq):  # 4.E33, 4.E73
        return _weighting(ct, bt, et, a_eq) * dt * cos_a * w

    def residual(a_eq):  # 4.E36, 4.E75 (C_r = 1)
        return dr * jnp.cos(jnp.arctan(br * a_eq)) * cos_a * w

    t0, mzr0 = trail(at), residual(ar)
    mz0 = -t0 * jnp.where(is52, fy0, fy0_g0) + mzr0  # 4.E31-4.E32

    # combined slip, 4.E50-4.E67
    bxa = (P.RBX1 + P.RBX3 * gx**2) * jnp.cos(jnp.arctan(P.RBX2 * kappa)) * P.LXAL  # 4.E54
    cxa, exa, shxa = P.RCX1, _clamp_e(P.REX1 + P.REX2 * dfz, limits), P.RHX1
    gxa = _weighting(cxa, bxa, exa, alpha_s + shxa) / _weighting(cxa, bxa, exa, shxa)
    fx = gxa * fx0  # 4.E50
    gyk = _combined_lateral_weight(P, kappa, dfz, alpha_s, gy, limits)
    dvyk = (muy * Fz * (P.RVY1 + P.RVY2 * dfz + P.RVY3 * gy)
            * jnp.cos(jnp.arctan(P.RVY4 * alpha_s)))  # 4.E67
    svyk = dvyk * jnp.sin(P.RVY5 * jnp.arctan(P.RVY6 * kappa)) * P.LVYKA * w  # 4.E66
    fy = gyk * fy0 + svyk  # 4.E58

    # combined aligning moment, 4.E71-4.E78
    kk = safe_div(kxn, kyn) ** 2 * kappa**2
    at_eq = safe_sqrt(at**2 + kk)  # 4.E77 (t is even in it)
    ar_eq = safe_sqrt(ar**2 + kk)  # 4.E78 (M_zr is even in it)
    t, mzr = trail(at_eq), residual(ar_eq)
    s = R0 * (P.SSZ1 + P.SSZ2 * (fy / fz0p) + (P.SSZ3 + P.SSZ4 * dfz) * gamma_s) * P.LS  # 4.E76
    gyk_g0 = _combined_lateral_weight(P, kappa, dfz, alpha_s, jnp.zeros_like(gy), limits)
    fy_prime = gyk_g0 * fy0_g0  # 4.E74
    mz = jnp.where(is52, -t * (fy - svyk), -t * fy_prime) + mzr + s * fx  # 4.E71-4.E72

    # overturning moment: 4.E69 with the q_sx12..14 terms of MF-Tyre 6.1
    fz0 = P.FNOMIN
    mx = (R0 * Fz * P.LMX * (P.QSX1 * P.LVMX - P.QSX2 * gamma * (1.0 + P.PPMX1 * dpi)
                             - P.QSX12 * gamma * safe_abs(gamma) + P.QSX3 * fy / fz0
                             + P.QSX4 * jnp.cos(P.QSX5 * jnp.arctan((P.QSX6 * Fz / fz0) ** 2))
                             * jnp.sin(P.QSX7 * gamma + P.QSX8 * jnp.arctan(P.QSX9 * fy / fz0))
                             + P.QSX10 * jnp.arctan(P.QSX11 * Fz / fz0) * gamma)
          + R0 * fy * P.LMX * (P.QSX13 + P.QSX14 * safe_abs(gamma)))
    # rolling resistance moment: paper A48 (MF 5.2: the MF-Tyre 5.2 form), against rolling
    v_ratio = vabs / P.LONGVL
    base = P.QSY1 + P.QSY2 * fx / fz0 + P.QSY3 * v_ratio + P.QSY4 * v_ratio**4
    my_61 = -R0 * fz0 * P.LMY * ((base + (P.QSY5 + P.QSY6 * Fz / fz0) * gamma**2)
                                 * safe_pow_abs(Fz / fz0, P.QSY7)
                                 * (p / P.NOMPRES) ** P.QSY8)
    my_52 = -R0 * Fz * P.LMY * base
    my = jnp.where(is52, my_52, my_61) * sgn_vx * w

    return MFOutput(Fx=fx, Fy=fy, Mz=mz, Mx=mx, My=my, Fx0=fx0, Fy0=fy0, Mz0=mz0, mux=mux,
                    muy=muy, Kxk=kxn * Fz, Kya=kyn * Fz, t=t, Mzr=mzr, Gxa=gxa, Gyk=gyk,
                    SVyk=svyk)


def mf_forces(params: MFParams, kappa, alpha, Fz, gamma=0.0, p=None, vx=None, *,
              limits: bool = True):
    r"""Combined-slip $(F_x, F_y, M_z)$ [N, N, N m], stacked on a last axis of 3
    (`mf_evaluate` for the arguments and everything else)."""
    out = mf_evaluate(params, kappa, alpha, Fz, gamma, p, vx, limits=limits)
    return jnp.stack([out.Fx, out.Fy, out.Mz], axis=-1)


def mf_relaxation_lengths(params: MFParams, Fz, gamma=0.0, p=None):
    r"""Relaxation lengths $(\sigma_\kappa, \sigma_\alpha)$ [m] at load $F_z$.

    From ``PTX1-3``, ``PTY1-2`` (MF 5.2, and any file that has no carcass stiffness):
    $\sigma_\kappa = F_z(p_{Tx1} + p_{Tx2}df_z)e^{-p_{Tx3}df_z}(R_0/F_{z0})\lambda_{\sigma\kappa}$,
    $\sigma_\alpha = p_{Ty1}\sin(2\arctan(F_z/(p_{Ty2}F'_{z0})))(1 - p_{Ky3}|\gamma|)R_0
    \lambda_{Fz0}\lambda_{\sigma\alpha}$ (MF-Tyre 5.2). MF 6.x files with ``[STRUCTURAL]``
    stiffnesses: $\sigma_\kappa = |K_{x\kappa}/C_x|$, $\sigma_\alpha = |K_{y\alpha}/C_y|$,
    $C_{x,y} = c_{x,y0}(1 + p_{Cf1}df_z + p_{Cf2}df_z^2)(1 + p_{Cf3}dp_i)$ (paper, eqs. 17-19).
    """
    P = params
    out = mf_evaluate(P, 0.0, 0.0, Fz, gamma, p, limits=False)
    Fz = jnp.maximum(jnp.asarray(Fz, dtype=float), 0.0)
    p = P.INFLPRES if p is None else jnp.asarray(p, dtype=float)
    fz0p = P.LFZO * P.FNOMIN
    dfz = (Fz - fz0p) / fz0p
    dpi = (p - P.NOMPRES) / P.NOMPRES
    sk_52 = (Fz * (P.PTX1 + P.PTX2 * dfz) * jnp.exp(-P.PTX3 * dfz) * (P.UNLOADED_RADIUS / P.FNOMIN)
             * P.LSGKP)
    pty2 = jnp.where(P.PTY2 == 0, 1.0, P.PTY2)
    sa_52 = (P.PTY1 * jnp.sin(2.0 * jnp.arctan(Fz / (pty2 * fz0p)))
             * (1.0 - P.PKY3 * safe_abs(jnp.asarray(gamma, dtype=float)))
             * P.UNLOADED_RADIUS * P.LFZO * P.LSGAL)
    cx = (P.LONGITUDINAL_STIFFNESS * (1.0 + P.PCFX1 * dfz + P.PCFX2 * dfz**2)
          * (1.0 + P.PCFX3 * dpi))
    cy = P.LATERAL_STIFFNESS * (1.0 + P.PCFY1 * dfz + P.PCFY2 * dfz**2) * (1.0 + P.PCFY3 * dpi)
    stiff = (P.version > 6.0) & (P.LONGITUDINAL_STIFFNESS > 0) & (P.LATERAL_STIFFNESS > 0)
    cx_safe = jnp.where(stiff, cx, 1.0)
    cy_safe = jnp.where(stiff, cy, 1.0)
    sk = jnp.where(stiff, safe_abs(out.Kxk / cx_safe), sk_52)
    sa = jnp.where(stiff, safe_abs(out.Kya / cy_safe), sa_52)
    return sk, sa


def _wheel_slips(params: MFParams, vx, vy, omega, r):
    r"""$\kappa = (\omega r - v_x)/\max(|v_x|, V_{XLOW})$ and
    $\tan\alpha = v_y/\max(|v_x|, V_{XLOW})$ (MF-Tyre's low-speed slips, finite at rest)."""
    den = jnp.maximum(safe_abs(vx), params.VXLOW)
    return (omega * r - vx) / den, vy / den


def _check_wheel_fields(tire) -> None:
    """The fields the Magic Formula tires share: `camber` finite, `pressure` (when given),
    `sigma_min` and `Fz` (when the tire has them) > 0."""
    owner = type(tire).__name__
    check_type(owner, "params", tire.params, MFParams)
    check_finite(owner, "camber", tire.camber)
    for name in ("pressure", "sigma_min", "Fz"):
        value = getattr(tire, name, None)
        if value is not None:
            check_positive(owner, name, value)


class MFTire(AbstractTire):
    r"""A tyre property file's Magic Formula as a static `AbstractTire` (state of shape
    `(0,)`): $(F_x, F_y, M_z)$ = `mf_forces` at the wheel's slips.

    $\kappa = (\omega r - v_x)/\max(|v_x|, V_{XLOW})$, $\tan\alpha = v_y/\max(|v_x|,
    V_{XLOW})$ (the file's axes: $v_y$ to the left), so slips, forces and gradients are
    finite at standstill, where the low-speed weight of the module docstring also takes the
    shifts, trail and residual moment to 0.

    **Fields:** `params` (`MFParams`), `camber` $\gamma$ [rad] (default 0), `pressure`
    [Pa] (default: the file's ``INFLPRES``), `limits` (apply the file's ranges).
    """

    params: MFParams
    camber: Float[Array, ""] = array_field(default=0.0)
    pressure: Float[Array, ""] | None = eqx.field(default=None, converter=_optional_array)
    limits: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        _check_wheel_fields(self)

    def init_state(self):
        return jnp.zeros((0,))

    def dynamics(self, state, vx, vy, omega, r, Fz):
        return jnp.zeros((0,))

    def forces(self, state, vx, vy, omega, r, Fz):
        kappa, tan_alpha = _wheel_slips(self.params, vx, vy, omega, r)
        out = mf_evaluate(self.params, kappa, jnp.arctan(tan_alpha), Fz, self.camber,
                          self.pressure, vx, limits=self.limits, _reduce_slips=False)
        return jnp.stack([out.Fx, out.Fy, out.Mz])


class RelaxedMFTire(AbstractTire):
    r"""The Magic Formula driven by relaxed slips: a first-order lag with the file's
    relaxation lengths (Pacejka 2012, ch. 7, the single-contact-point transient model).

    State $(\kappa', \tan\alpha')$, with $V = \max(|v_x|, V_{XLOW})$ and
    $\sigma_\kappa, \sigma_\alpha$ from `mf_relaxation_lengths` (at least `sigma_min`):
    $$\sigma_\kappa\dot\kappa' = (\omega r - v_x) - V\kappa',\qquad
      \sigma_\alpha\dot{(\tan\alpha')} = v_y - V\tan\alpha'.$$
    At constant speed the relaxed slips tend to those of `MFTire` with time constants
    $\sigma/V$, and the forces are `mf_forces` at the relaxed slips.

    **Fields:** as `MFTire`, and `sigma_min` [m] (default 0.01), the floor that keeps
    the lag finite at zero load.
    """

    params: MFParams
    camber: Float[Array, ""] = array_field(default=0.0)
    pressure: Float[Array, ""] | None = eqx.field(default=None, converter=_optional_array)
    sigma_min: Float[Array, ""] = array_field(default=0.01)
    limits: bool = eqx.field(static=True, default=True)
    load_proportional: ClassVar[bool] = False

    def __check_init__(self):
        _check_wheel_fields(self)

    def init_state(self):
        return jnp.zeros((2,))

    def dynamics(self, state, vx, vy, omega, r, Fz):
        p = self.params
        den = jnp.maximum(safe_abs(vx), p.VXLOW)
        sk, sa = mf_relaxation_lengths(p, Fz, self.camber, self.pressure)
        sk, sa = jnp.maximum(sk, self.sigma_min), jnp.maximum(sa, self.sigma_min)
        return jnp.stack([((omega * r - vx) - den * state[0]) / sk,
                          (vy - den * state[1]) / sa])

    def forces(self, state, vx, vy, omega, r, Fz):
        out = mf_evaluate(self.params, state[0], jnp.arctan(state[1]), Fz, self.camber,
                          self.pressure, vx, limits=self.limits, _reduce_slips=False)
        return jnp.stack([out.Fx, out.Fy, out.Mz])


class MFLongitudinalTire(AbstractLongitudinalTire):
    r"""The Magic Formula's $F_x$ as an `AbstractLongitudinalTire` (quarter car, braking
    loop): the relaxed slip ratio $\kappa'$ of `RelaxedMFTire` at zero slip angle, and
    $\mu = F_x(\kappa')/F_z$ at the load `Fz` the tire carries (the Magic Formula is not
    load-proportional, so $\mu$ is that of this load; default ``FNOMIN``).

    $$\sigma_\kappa\dot\kappa' = (\omega r - v) - \max(|v|, V_{XLOW})\,\kappa'.$$

    **Fields:** `params` (`MFParams`), `Fz` [N], `camber` [rad], `pressure` [Pa],
    `sigma_min` [m], `limits`, as `RelaxedMFTire`.
    """

    params: MFParams
    Fz: Float[Array, ""] | None = eqx.field(default=None, converter=_optional_array)
    camber: Float[Array, ""] = array_field(default=0.0)
    pressure: Float[Array, ""] | None = eqx.field(default=None, converter=_optional_array)
    sigma_min: Float[Array, ""] = array_field(default=0.01)
    limits: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        _check_wheel_fields(self)

    def _load(self):
        return self.params.FNOMIN if self.Fz is None else jnp.asarray(self.Fz, dtype=float)

    def init_state(self):
        return jnp.zeros(())

    def dynamics(self, state, v, omega, r):
        p = self.params
        sk, _ = mf_relaxation_lengths(p, self._load(), self.camber, self.pressure)
        den = jnp.maximum(safe_abs(v), p.VXLOW)
        return ((omega * r - v) - den * state) / jnp.maximum(sk, self.sigma_min)

    def mu(self, state, v, omega, r):
        Fz = self._load()
        out = mf_evaluate(self.params, state, 0.0, Fz, self.camber, self.pressure, v,
                          limits=self.limits, _reduce_slips=False)
        return out.Fx / Fz


def mf_summary(params: MFParams, Fz=None, p=None) -> dict:
    r"""Summary values of one tire at load `Fz` (default the scaled nominal load
    $F'_{z0} = \lambda_{Fz0}F_{z0}$, where the coefficients' stated values hold), zero camber:
    the peaks of $|F_{x0}|/F_z$ (driving and braking) and $|F_{y0}|/F_z$ with the slips
    where they occur (found on a grid of 2001 slips, $|\kappa| \le 1$,
    $|\alpha| \le 30°$), the slip and cornering stiffnesses $K_{x\kappa}$ [N],
    $K_{y\alpha}$ [N/rad], the slopes at zero slip $\partial F_x/\partial\kappa$ [N]
    (``dFx_dkappa_0``) and $\partial F_y/\partial\alpha$ [N/rad] (``dFy_dalpha_0``: the
    cornering stiffness as measured, which the shifts $S_{Hy}$, $S_{Vy}$ and the curvature
    set slightly apart from $K_{y\alpha}$), and what the coefficients state: $\mu_x = p_{Dx1}\lambda_{\mu x}$,
    $\mu_y = p_{Dy1}\lambda_{\mu y}$ at the nominal load, and the cornering stiffness
    $p_{Ky1}F'_{z0}\sin(p_{Ky4}\arctan(F_z/(p_{Ky2}F'_{z0})))$ (4.E25 at zero camber and
    nominal pressure)."""
    P = params
    Fz = float(P.LFZO * P.FNOMIN) if Fz is None else float(Fz)
    check_positive("mf_summary", "Fz", Fz)
    kappa = np.linspace(-1.0, 1.0, 2001)
    alpha = np.deg2rad(np.linspace(-30.0, 30.0, 2001))
    ox = mf_evaluate(P, kappa, 0.0, Fz, 0.0, p, limits=False)
    oy = mf_evaluate(P, 0.0, alpha, Fz, 0.0, p, limits=False)
    fx, fy = np.asarray(ox.Fx0) / Fz, np.asarray(oy.Fy0) / Fz
    drive, brake = kappa > 0, kappa < 0
    i_d, i_b = np.argmax(fx[drive]), np.argmin(fx[brake])
    i_y = np.argmax(np.abs(fy))
    o0 = mf_evaluate(P, 0.0, 0.0, Fz, 0.0, p, limits=False)
    slope_x = jax.grad(lambda k: mf_evaluate(P, k, 0.0, Fz, 0.0, p, limits=False).Fx)(0.0)
    slope_y = jax.grad(lambda a: mf_evaluate(P, 0.0, a, Fz, 0.0, p, limits=False).Fy)(0.0)
    fz0p = float(P.LFZO * P.FNOMIN)
    stated_k = float(P.PKY1 * fz0p * np.sin(P.PKY4 * np.arctan(Fz / (P.PKY2 * fz0p))))
    return {
        "version": round(float(P.version), 1), "Fz": Fz,
        "mu_x_drive": float(fx[drive][i_d]), "kappa_at_mu_x_drive": float(kappa[drive][i_d]),
        "mu_x_brake": float(-fx[brake][i_b]), "kappa_at_mu_x_brake": float(kappa[brake][i_b]),
        "mu_y": float(np.abs(fy)[i_y]), "alpha_deg_at_mu_y": float(np.rad2deg(alpha[i_y])),
        "Kxk": float(o0.Kxk), "Kya": float(o0.Kya),
        "dFx_dkappa_0": float(slope_x), "dFy_dalpha_0": float(slope_y),
        "stated_mu_x": float(P.PDX1 * P.LMUX), "stated_mu_y": float(P.PDY1 * P.LMUY),
        "stated_Kya": stated_k,
    }

