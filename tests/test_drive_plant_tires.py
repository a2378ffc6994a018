"""A tire of another family on the drive plant: the Magic Formula of a .tir file meets every
surface of a scenario with the peak the scenario states (`vehsim.drive.plant_tires`)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vehsim as vs
from vehsim.drive.plant_tires import _pure_peaks
from vehsim.tire.tir import read_tir, shipped_tires


SAMPLE = shipped_tires()["sample_185_80R14_mf61"]
CAR = vs.rally_gravel()
FZ_FRONT = float(CAR.m * CAR.g * CAR.lR / (CAR.lF + CAR.lR))


def pure_peaks(tire, Fz=FZ_FRONT):
    """The pure-slip peaks (mu_x, mu_y) of a Magic Formula tire at load Fz, 20 m/s."""
    return tuple(float(v) for v in _pure_peaks(vs.MFTire(tire.params, limits=False), Fz,
                                               float(CAR.r)))


@pytest.fixture(scope="module")
def mf():
    return vs.mf_plant_tire(SAMPLE)


def test_mf_plant_tire_has_the_peak_asked_for_on_the_nominal_road(mf):
    """Both pure-slip peaks at the static front axle load are the peak asked for (default
    the nominal 0.52), whichever way the file is given; the curves' shape is the file's
    (the peak slip does not move with the friction factors), and its relaxation lengths
    make it a dynamic tire."""
    assert isinstance(mf, vs.RelaxedMFTire) and not mf.limits
    np.testing.assert_allclose(pure_peaks(mf), (0.52, 0.52), rtol=1e-6)
    raw = vs.MFParams.from_tir(read_tir(SAMPLE))
    assert pure_peaks(vs.RelaxedMFTire(raw, limits=False))[0] > 0.8  # the file's own road
    for given in (str(SAMPLE), read_tir(SAMPLE), raw):
        other = vs.mf_plant_tire(given, 0.7)
        np.testing.assert_allclose(pure_peaks(other), (0.7, 0.7), rtol=1e-6)
        np.testing.assert_allclose(float(other.params.LMUX / mf.params.LMUX), 0.7 / 0.52,
                                   rtol=1e-12)
    with pytest.raises(ValueError, match="peak must"):
        vs.mf_plant_tire(SAMPLE, 0.0)
    with pytest.raises(TypeError, match="mf_plant_tire: tir must be"):
        vs.mf_plant_tire(vs.params.lugre2d_bakker1987())


@jax.jit
def _braking_mu(logk, lam, V):
    k = jnp.exp(logk)
    v_r = jnp.stack([-k * V, 0.0 * k])
    return jnp.linalg.norm(vs.scaled_steady_state_mu(vs.AxleGripEstimator().tire, lam, v_r,
                                                     (1 - k) * V))


def _lugre_peak(lam, V=20.0):
    """The LuGre plant's peak in pure braking by scipy's bounded scalar search on log slip
    (an independent maximisation of the same steady-state friction)."""
    from scipy.optimize import minimize_scalar

    def mu(logk):
        return float(_braking_mu(logk, lam, V))

    coarse = np.linspace(np.log(1e-5), 0.0, 400)
    j = int(np.argmax([mu(x) for x in coarse]))
    res = minimize_scalar(lambda x: -mu(x), bounds=(coarse[max(j - 1, 0)], coarse[j + 1]),
                          method="bounded", options={"xatol": 1e-10})
    return -res.fun


def test_peak_surface_factor_is_the_lugre_peaks_ratio():
    r"""$m(\lambda) = \mu^*(\lambda)/\mu^*(\lambda_0)$: exactly 1 on the nominal road, the
    LuGre plant's peak ratio (scipy's maximisation) at its knots to 1e-9 and within 1e-5
    between them, increasing, constant
    past its ends; `plant_peak`'s reading (`peak_friction`) within 0.7 % of it on every
    road, the most slippery included."""
    lam0 = vs.nominal_scale()
    m = vs.peak_surface_factor(lam0)
    assert float(m(lam0)) == 1.0
    ref0 = _lugre_peak(lam0)
    for k in (-150, -40, 17, 60):  # at the knots, the tire's own ratio to rounding
        lam = lam0 * 2.0 ** (k / 32)
        assert float(m(lam)) == pytest.approx(_lugre_peak(lam) / ref0, rel=1e-9), k
    for lam in (0.01, 0.03, 0.1771, 0.3066, 0.55, 1.3):
        want = _lugre_peak(lam) / ref0
        assert float(m(lam)) == pytest.approx(want, rel=1e-5), lam
        assert float(m(lam)) == pytest.approx(vs.plant_peak(lam) / 0.52, rel=7e-3), lam
    # the LuGre peak is not proportional to the scale: on the icy patch's scale
    icy = vs.scale_for_peak(0.26)
    assert float(m(icy)) == pytest.approx(0.5, rel=7e-3) and icy / lam0 < 0.45
    assert np.all(np.diff(np.asarray(m.factors)) > 0)
    assert float(m(1e-6)) == float(m.factors[0]) and float(m(100.0)) == float(m.factors[-1])
    assert float(m.scales[0]) < 0.007 < 1.5 < float(m.scales[-1])  # ice to 3x gravel
    # differentiable where the plant reads it
    g = jax.grad(lambda x: m(x))(jnp.asarray(0.3))
    assert np.isfinite(float(g)) and float(g) > 0


@pytest.mark.parametrize("grip", ["minus20", "icy", "rising"])
def test_mf_plant_meets_each_surface_with_the_scenarios_peak(mf, grip):
    """On the scenario's plant (`drive_scenario(tire=...)`) the Magic Formula under an axle
    has the scenario's peak there (`ScenarioGrip.peak`, the LuGre plant's): 20 % less, half
    on the icy patch, 60 % at the rising road's start. Scaled by the grip's LuGre scale
    itself it would be 4 %, 12 % and 8 % lower."""
    sc = vs.drive_scenario("corner90", grip, tire=mf)
    plant = sc.plant
    assert isinstance(plant.surface_factor, vs.SurfaceFactor)
    road = sc.road
    s_low = {"minus20": 0.5 * road.length, "icy": float(np.mean(vs.main_corner("corner90"))),
             "rising": 0.0}[grip]
    x, y = road.position(s_low)
    # the car placed with its front axle on that point of the centre line
    psi = float(road.heading(s_low))
    state = sc.state0.car.at[:3].set(jnp.asarray([float(x) - float(CAR.lF) * np.cos(psi),
                                                  float(y) - float(CAR.lF) * np.sin(psi),
                                                  psi]))
    front = plant.car_at(state).tire
    lam = float(plant.grip_scales(state)[0])
    want = 0.52 * _lugre_peak(lam) / _lugre_peak(vs.nominal_scale())
    np.testing.assert_allclose(pure_peaks(front), (want, want), rtol=1e-5)
    # the scenario's stated peak (peak_friction's reading) within its 0.7 %
    stated = float(sc.grip.peak_at(s_low))
    assert stated == pytest.approx({"minus20": 0.416, "icy": 0.26, "rising": 0.312}[grip],
                                   rel=5e-3)  # the patch's tanh edge: 0.2607 at its centre
    assert want == pytest.approx(stated, rel=7e-3)
    unmatched = vs.scale_friction(mf, lam / vs.nominal_scale())
    assert pure_peaks(unmatched)[0] < 0.97 * want


def test_a_lugre_plant_meets_the_scales_themselves():
    """The default tire, or any LuGre one, is scaled by the grip's scale (the report's
    theta = 1/lambda): no surface factor."""
    assert vs.drive_scenario("corner90", "icy").plant.surface_factor is None
    lugre = vs.LumpedLuGre2D(vs.params.lugre2d_bakker1987())
    assert vs.drive_scenario("corner90", "icy", tire=lugre).plant.surface_factor is None
    assert vs.plant_surface_factor(None) is None


@pytest.mark.parametrize("scales, factors, field", [
    ([1.0], [1.0], "scales must be a vector of at least 2"),
    ([1.0, 2.0], [1.0, 2.0, 3.0], "factors must have the shape"),
    ([1.0, 0.5], [1.0, 2.0], "scales must increase strictly"),
    ([0.0, 0.5], [1.0, 2.0], "scales"),
    ([0.5, 1.0], [1.0, -2.0], "factors"),
])
def test_surface_factor_refuses_bad_knots_naming_the_field(scales, factors, field):
    with pytest.raises(ValueError, match="SurfaceFactor.*" + field):
        vs.SurfaceFactor(scales=jnp.asarray(scales), factors=jnp.asarray(factors))
    with pytest.raises(ValueError, match="reference_scale"):
        vs.peak_surface_factor(0.0)


def test_plant_peaks_are_each_tires_own(mf):
    """`plant_peaks` (the drive figure's truth): the LuGre plant's peak_friction; a Magic
    Formula's pure-slip peak at the static front axle load times its friction factor, the
    surface factor's where the plant has one, the scale itself where not; another tire is
    refused by name."""
    from vehsim.drive.plant_tires import plant_peaks

    lam = jnp.asarray([[0.2, 0.4], [0.3066, 0.9]])
    lugre = vs.DrivePlant()
    want = [[float(vs.peak_friction(lugre.tire, x, 20.0)) for x in row] for row in lam]
    np.testing.assert_allclose(plant_peaks(lugre, lam), want, rtol=1e-12)
    factor = vs.peak_surface_factor(vs.nominal_scale())
    matched = vs.DrivePlant(tire=mf, surface_factor=factor)
    got = np.asarray(plant_peaks(matched, lam))
    for (i, j), x in np.ndenumerate(np.asarray(lam)):  # against the scaled tire's own curve
        scaled = vs.scale_friction(mf, factor(x))
        assert got[i, j] == pytest.approx(pure_peaks(scaled)[0], rel=1e-6)
    plain = np.asarray(plant_peaks(vs.DrivePlant(tire=mf), lam))
    np.testing.assert_allclose(plain, pure_peaks(mf)[0] * np.asarray(lam), rtol=1e-12)
    with pytest.raises(TypeError, match="plant_peaks knows.*LinearTire"):
        plant_peaks(_linear_plant(), lam)


def _linear_plant():
    """A plant whose tire plant_peaks does not know (DrivePlant refuses a tire it cannot
    scale, so the tire is swapped in after construction)."""
    import equinox as eqx

    return eqx.tree_at(lambda p: p.tire, vs.DrivePlant(), vs.LinearTire(5e4, 4e4))
