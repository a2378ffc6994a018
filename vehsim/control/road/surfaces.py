r"""Named road surfaces for the lumped LuGre tire (`UniformLumpedLuGre`).

Two families, each one tire on several roads that differ by the road condition $\theta$
(Canudas de Wit and Tsiotras 1999: $\dot z = v_r - \theta\sigma_0|v_r|z/g(v_r)$, so the
friction level scales as $g/\theta$; larger $\theta$ is more slippery):

- ``cdc1999_1``, ``cdc1999_0.8``, ``cdc1999_0.6``, ``cdc1999_0.4``: the CDC 1999 set
  (`vehsim.params.cdc1999`) at $1/\theta$ = 1, 0.8, 0.6, 0.4, the values of the report's
  Fig. 7b (whose curves are drawn with Table 3's data). It is a soft tire ($\sigma_0L$ = 10,
  against 75 for the fitted family): at 30 m/s its eq. 19 rises all the way to the locked
  wheel, so there the best braking is a locked wheel; its peak leaves $s = -1$ only at
  lower speeds (about -0.8 at 10 m/s for $\theta$ = 1).
- ``dry_asphalt``, ``wet_asphalt``, ``cobblestone``, ``snow``, ``ice``: the LuGre family
  fitted to Burckhardt's curves (`vehsim.tire.burckhardt`): $\sigma_0$ = 301.5 1/m
  (cobblestone 72.00), $v_s$ = 17.95 m/s, $\alpha$ = 1.853, $\mu_s$ = 1, $\mu_c$ = 0.5689,
  $\sigma_1$ = 0.7 s/m, $\sigma_2$ = 0, $L$ = 0.25 m, and $\theta$ per road: dry asphalt
  0.8093, wet asphalt 1.211, cobblestone 0.8662, snow 5.283, ice 18.59.

**Fit quality** (eq. 19 minus Burckhardt's curve over braking slip 0.002-1, relative to
Burckhardt's peak; RMS / max): at the fit speed 20 m/s dry asphalt 4.4 % / 8.5 %, wet
asphalt 4.5 % / 8.1 %, cobblestone 3.1 % / 10.4 %, snow 3.2 % / 17.0 % (the knee), ice 9.7 % /
25.8 % (Burckhardt's ice rises to its plateau within 1 % slip, sharper than eq. 19 can). At
10 and 30 m/s the LuGre curves move with speed through $g(vs)$ (Fig. 7a) where Burckhardt's
static curves do not: 5-11 % RMS (ice 15 % at 30 m/s).

Each surface also carries the admissible range of $\theta$ in its family (the estimators'
projection) and the prior an estimator starts from (the family's driest road: an estimate
of a grippier road than the true one drives the slip past the true peak, where $\theta$ is
identifiable; the other way round it stays in the linear range, where it is not).
"""

from __future__ import annotations

import dataclasses

from ..._checks import check_order, check_range
from ...tire.lugre import LuGreParams
from ...tire.params import cdc1999
from ...tire.uniform_lumped import UniformLumpedLuGre


_BURCKHARDT_TIRE = dict(sigma0=301.52818508, sigma1=0.7, sigma2=0.0, mu_c=0.56888825,
                        mu_s=1.0, v_s=17.95266838, alpha=1.85257065, L=0.25)
_BURCKHARDT_THETA = {"dry_asphalt": 0.80925581, "wet_asphalt": 1.21057950,
                     "cobblestone": 0.86615674, "snow": 5.28298157, "ice": 18.59314464}
_COBBLESTONE_SIGMA0 = 72.00242720
_BURCKHARDT_FIT = {  # RMS and max error relative to the peak, at 20 m/s
    "dry_asphalt": (0.0435, 0.0854), "wet_asphalt": (0.0445, 0.0810),
    "cobblestone": (0.0313, 0.1035), "snow": (0.0323, 0.1704), "ice": (0.0971, 0.2576),
}
_CDC_INVERSE_THETA = {"cdc1999_1": 1.0, "cdc1999_0.8": 0.8, "cdc1999_0.6": 0.6,
                      "cdc1999_0.4": 0.4}


@dataclasses.dataclass(frozen=True)
class Surface:
    """A named road: the LuGre parameters of the tire on it (`params.theta` is the road
    condition), the admissible `theta_range` of its family, the estimators' `prior_theta`,
    where the values come from, and the fit quality (RMS, max) if fitted."""

    name: str
    params: LuGreParams
    theta_range: tuple[float, float]
    prior_theta: float
    source: str
    fit_error: tuple[float, float] | None = None

    def __post_init__(self):
        lo, hi = self.theta_range
        owner = f"Surface {self.name!r}"
        check_order(owner, "theta_range[0]", lo, "theta_range[1]", hi)
        check_range(owner, "prior_theta", self.prior_theta, lower=lo, upper=hi)

    def tire(self) -> UniformLumpedLuGre:
        """The plant's tire on this road."""
        return UniformLumpedLuGre(self.params)

    def with_theta(self, theta) -> LuGreParams:
        """The same tire at another road condition (checked against `theta_range`)."""
        lo, hi = self.theta_range
        check_range(f"Surface {self.name!r}", "theta", theta, lower=lo, upper=hi)
        return dataclasses.replace(self.params, theta=theta)


def _cdc(name: str) -> Surface:
    theta = 1.0 / _CDC_INVERSE_THETA[name]
    return Surface(name, cdc1999(theta), (0.5, 5.0), 1.0,
                   "CDC 1999 set (vehsim.params.cdc1999), report Fig. 7b")


def _burckhardt(name: str) -> Surface:
    tire = dict(_BURCKHARDT_TIRE)
    if name == "cobblestone":
        tire["sigma0"] = _COBBLESTONE_SIGMA0
    return Surface(name, LuGreParams(theta=_BURCKHARDT_THETA[name], **tire), (0.3, 40.0),
                   _BURCKHARDT_THETA["dry_asphalt"],
                   "LuGre fit to Burckhardt's curve (vehsim.tire.burckhardt)",
                   _BURCKHARDT_FIT[name])


SURFACES: tuple[str, ...] = tuple(_CDC_INVERSE_THETA) + tuple(_BURCKHARDT_THETA)
"""The names `surface` knows, CDC 1999 family first."""


def surface(name: str) -> Surface:
    """The named `Surface` (see `SURFACES`); an unknown name raises `ValueError`."""
    if name in _CDC_INVERSE_THETA:
        return _cdc(name)
    if name in _BURCKHARDT_THETA:
        return _burckhardt(name)
    raise ValueError(f"unknown surface {name!r}; known: {', '.join(SURFACES)}")
