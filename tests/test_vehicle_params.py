"""Half-car parameters: presets and validation."""

import jax
import numpy as np
import pytest

from vehsim import HalfCarParams, preset, rally_gravel


def test_rally_gravel_is_the_spec_vehicle():
    p = preset("rally_gravel")
    np.testing.assert_allclose(
        [p.m, p.Iz, p.lF, p.lR, p.h, p.r, p.Iw_F, p.Iw_R, p.g],
        [1450, 2740, 1.3, 1.4, 0.4, 0.3, 1.8, 1.8, 9.81],
    )
    FzF, FzR = p.static_loads()  # eqs. 57-58
    np.testing.assert_allclose([FzF, FzR], [1450 * 9.81 * 1.4 / 2.7, 1450 * 9.81 * 1.3 / 2.7])


@pytest.mark.parametrize(
    "changes, match",
    [({"m": -1.0}, "HalfCarParams.m must"), ({"lF": 0.0, "lR": 0.0}, "lF \\+ lR"),
     ({"lF": -0.5}, "HalfCarParams.lF must"), ({"K_F": 0.0}, "HalfCarParams.K_F must"),
     ({"K_R": -5.0}, "HalfCarParams.K_R must"), ({"Iz": 0.0}, "HalfCarParams.Iz must"),
     ({"C_R": -1.0}, "HalfCarParams.C_R must"), ({"h": -0.1}, "HalfCarParams.h must")],
)
def test_invalid_vehicles_raise(changes, match):
    kw = {k: getattr(rally_gravel(), k) for k in HalfCarParams.__dataclass_fields__}
    kw.update(changes)
    with pytest.raises(ValueError, match=match):
        HalfCarParams(**kw)


def test_checks_are_skipped_under_jit():
    f = jax.jit(lambda m: HalfCarParams(m=m, Iz=1.0, lF=1.0, lR=1.0, h=0.3, r=0.3,
                                        Iw_F=1.0, Iw_R=1.0).static_loads()[0])
    np.testing.assert_allclose(f(2.0), 2.0 * 9.81 / 2)
