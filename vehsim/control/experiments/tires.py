r"""Plant tires of other shapes than the named surfaces' lumped LuGre, by name: for braking
with a controller and an observer built for a LuGre road (`braking_scenario(name,
tire=other_tire(...))`), and for the limit of any tire (`physical_limit`).

Peak braking slip $s^*$ and friction $\mu^*$ at 30 m/s (`peak_braking`, radius 0.3 m),
against dry asphalt's lumped LuGre, $s^* = -0.194$, $\mu^* = 1.098$:

- ``mf_sharp``: a pure-slip Magic Formula with a relaxation length (`RelaxedMagicFormula`,
  $B$ = 14, $C$ = 1.6, $D$ = 1.1, $E$ = 0.2, $\sigma_\kappa$ = 0.25 m): a sharp, high peak
  at small slip, $s^* = -0.116$, $\mu^* = 1.1$, falling to 0.76 at a locked wheel;
  speed-independent.
- ``mf_low_flat``: a low-grip Magic Formula ($B$ = 10, $C$ = 1.3, $D$ = 0.45, $E$ = 0,
  $\sigma_\kappa$ = 0.25 m): a low, flat peak at large slip, $s^* = -0.263$, $\mu^* = 0.45$,
  still 0.42 at a locked wheel; speed-independent.
- ``burckhardt_dry``: Burckhardt's dry-asphalt curve ($c_1$ = 1.2801, $c_2$ = 23.99,
  $c_3$ = 0.52; Burckhardt 1993, `vehsim.tire.burckhardt.BURCKHARDT`) through a relaxation
  length of 0.25 m (`RelaxedBurckhardt`): $s^* = -0.170$, $\mu^* = 1.170$, 0.76 locked;
  speed-independent; its steady state is computed (`solve_steady_state`), not coded.
- ``lumped_table3``: the lumped LuGre of eqs. 22-23 with the report's Table 3 parameters
  (`vehsim.params.table3`) and a constant $\kappa_0$ = 1.5 (`LumpedLuGre`; eq. 25, the
  middle of the report's range): a broad, flat peak at large slip, $s^* = -0.380$,
  $\mu^* = 0.958$, 0.943 locked; Stribeck speed dependence (at 10 m/s $-0.423$, 1.075).
- ``distributed_quartic``: the distributed LuGre (eqs. 11-14, `DistributedLuGre`) with
  the quartic load of Fig. 16a (`QuarticLoad`) and dry asphalt's fitted parameters, 10
  Chebyshev nodes (degree 9; its discrete steady state is the limit's curve, within
  $1.6\cdot10^{-4}$ of eq. 17's quadrature): $s^* = -0.177$, $\mu^* = 1.140$, 0.743 locked
  (at 10 m/s $-0.305$, 1.203).
"""

from __future__ import annotations

from ...tire.burckhardt import BURCKHARDT, BurckhardtParams, RelaxedBurckhardt
from ...tire.distributed import DistributedLuGre
from ...tire.load import QuarticLoad
from ...tire.lugre import AbstractLongitudinalTire, LumpedLuGre
from ...tire.params import table3
from ...tire.relaxed_magic_formula import MagicFormulaParams, RelaxedMagicFormula
from ..road.surfaces import surface


DISTRIBUTED_DEGREE = 9
"""Chebyshev degree of ``distributed_quartic`` (10 nodes: small, for the loop's implicit
steps)."""


def _mf_sharp():
    return RelaxedMagicFormula(MagicFormulaParams(B=14.0, C=1.6, D=1.1, E=0.2,
                                                  relaxation_length=0.25))


def _mf_low_flat():
    return RelaxedMagicFormula(MagicFormulaParams(B=10.0, C=1.3, D=0.45, E=0.0,
                                                  relaxation_length=0.25))


def _burckhardt_dry():
    c1, c2, c3 = BURCKHARDT["dry_asphalt"]
    return RelaxedBurckhardt(BurckhardtParams(c1=c1, c2=c2, c3=c3, relaxation_length=0.25))


def _lumped_table3():
    return LumpedLuGre(table3(), kappa0=1.5)


def _distributed_quartic():
    return DistributedLuGre(surface("dry_asphalt").params, QuarticLoad(), n=DISTRIBUTED_DEGREE)


_TIRES = {"mf_sharp": _mf_sharp, "mf_low_flat": _mf_low_flat,
          "burckhardt_dry": _burckhardt_dry, "lumped_table3": _lumped_table3,
          "distributed_quartic": _distributed_quartic}

OTHER_TIRES: tuple[str, ...] = tuple(_TIRES)
"""The names `other_tire` knows."""


def other_tire(name: str) -> AbstractLongitudinalTire:
    """The plant tire called `name` (see `OTHER_TIRES` and the module docstring); an unknown
    name raises `ValueError`."""
    if name not in _TIRES:
        raise ValueError(f"unknown tire {name!r}; known: {', '.join(OTHER_TIRES)}")
    return _TIRES[name]()
