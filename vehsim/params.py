"""Named parameter presets from the literature (../shared/spec/parameters.md).

Each preset is a function returning fresh parameter modules; `preset(name)` looks one up by
name (the names the command line and result files use). Values marked "unverified" in the
spec are kept, and say so.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from .tire.friction_ellipse import rally_gravel_tire
from .tire.lugre import LuGreParams
from .vehicle.params import rally_gravel


def table3() -> LuGreParams:
    """Longitudinal LuGre, report Table 3 (the data of Fig. 7), distributed model.

    sigma0 = 181.54 1/m, sigma2 = 0.0018 s/m, mu_c = 0.8, mu_s = 1.55, v_s = 6.57 m/s,
    L = 0.2 m, alpha = 1/2 (report footnote 1). sigma1 = 0.7 s/m is not in Table 3 (it only
    enters transients); it is the value commonly quoted with this set (**unverified**).
    Source: Tsiotras (2004), Table 3; Canudas de Wit et al., VSD 39(3), 2003.
    """
    return LuGreParams(
        sigma0=181.54, sigma1=0.7, sigma2=0.0018, mu_c=0.8, mu_s=1.55, v_s=6.57,
        alpha=0.5, theta=1.0, L=0.2,
    )


def cdc1999(theta: float = 1.0) -> LuGreParams:
    """Longitudinal LuGre of Canudas de Wit and Tsiotras, CDC 1999.

    sigma0 = 40 1/m, sigma1 = 4.9487 s/m, sigma2 = 0.0018 s/m, mu_c = 0.5, mu_s = 0.9,
    v_s = 12.5 m/s, L = 0.25 m, alpha = 1/2 (their operating point is v = 20 m/s). The road
    condition `theta` scales the bristle decay, so steady friction scales roughly as g/theta
    (1/theta in {1, 0.8, 0.6, 0.4}: dry to slippery).
    Source: Canudas de Wit and Tsiotras, "Dynamic tire friction models for vehicle traction
    control", 38th IEEE CDC, 1999, pp. 3746-3751.
    """
    return LuGreParams(
        sigma0=40.0, sigma1=4.9487, sigma2=0.0018, mu_c=0.5, mu_s=0.9, v_s=12.5,
        alpha=0.5, theta=theta, L=0.25,
    )


PRESETS: dict[str, Callable[[], Any]] = {
    "table3": table3,
    "cdc1999": cdc1999,
    # issue 5: the maneuver spec's vehicle and tire (../shared/spec/maneuvers.md)
    "rally_gravel": rally_gravel,
    "rally_gravel_tire": rally_gravel_tire,
}


def preset(name: str):
    """The preset called ``name`` (see `PRESETS`)."""
    try:
        return PRESETS[name]()
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; known: {sorted(PRESETS)}") from None
