"""Road surfaces, the tire whose steady state is eq. 19, its peak, the physical limit, and
bad input refused with a clear error."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim import cli
from vehsim.control.estimation.observer import FrictionObserver
from vehsim.control.experiments.scenarios import braking_scenario
from vehsim.control.loop import STOP_SPEED
from vehsim.control.plant.hardware import (
    BrakeHardware,
    ideal_hardware,
    realistic_hardware,
)
from vehsim.control.plant.quarter_car import BrakingScenario, SurfaceChange, braking_quarter_car
from vehsim.control.road.bound import actuated_limit, physical_limit, traction_limit
from vehsim.control.road.peak import peak_braking, peak_driving
from vehsim.control.road.surfaces import SURFACES, surface
from vehsim.tire.burckhardt import fit_errors
from vehsim.tire.steady_state import braking_mu_uniform, driving_mu_uniform
from vehsim.tire.uniform_lumped import UniformLumpedLuGre, decay


def test_unknown_surface_name_is_refused(capsys):
    with pytest.raises(ValueError, match="unknown surface 'tarmac'; known: cdc1999_1"):
        surface("tarmac")
    assert cli.main(["brake", "--surface", "tarmac"]) == 2
    assert "unknown surface 'tarmac'" in capsys.readouterr().err


def test_theta_outside_its_range_is_refused():
    with pytest.raises(ValueError, match=r"Surface 'ice'.theta must lie in \[0.3, 40\]"):
        surface("ice").with_theta(45.0)
    with pytest.raises(ValueError, match=r"model.theta \(the prior\) must lie in \[0.5, 3\]"):
        FrictionObserver(surface("cdc1999_1").with_theta(4.0), theta_min=0.5, theta_max=3.0)


def test_negative_or_too_long_delay_is_refused():
    with pytest.raises(ValueError, match=r"BrakeHardware.actuator_delay must lie in \[0, 0.04\]"):
        BrakeHardware(actuator_delay=-0.01)
    with pytest.raises(ValueError, match=r"actuator_delay must lie in \[0, 0.04\], got 0.05"):
        BrakeHardware(actuator_delay=0.05)  # 8 samples of 5 ms at most
    with pytest.raises(ValueError, match="SurfaceChange.distance must lie in"):
        SurfaceChange(surface("ice").tire(), distance=-1.0)


def test_hardware_checks_a_component_only_while_it_is_on():
    # 1 ms samples hold at most 8 ms of delay: the default 10 ms is refused with the delay
    # on and accepted with it off (never applied); likewise a lag, rate limit or tone wheel
    # switched off keeps values it never uses
    with pytest.raises(ValueError, match=r"actuator_delay must lie in \[0, 0.008\], got 0.01"):
        BrakeHardware(sample_time=0.001)
    ideal = ideal_hardware(sample_time=0.001)
    assert int(ideal.delay_samples()) == 0
    BrakeHardware(lag=False, time_constant=0.0, rate_limit=False, torque_rate=-1.0,
                  encoder=False, encoder_pulses=0.0, noise=False, speed_noise_std=-1.0)
    for name, value in (("time_constant", 0.0), ("torque_rate", -1.0), ("encoder_pulses", 0.0),
                        ("speed_noise_std", -1.0)):
        with pytest.raises(ValueError, match=f"BrakeHardware.{name} must lie in"):
            BrakeHardware(**{name: value})
    with pytest.raises(ValueError, match=r"actuator_delay must lie in \[0, 0.008\]"):
        ideal_hardware(sample_time=0.001, delay=True)


@pytest.mark.parametrize("s, v", [(-0.05, 30.0), (-0.3, 12.0), (-0.999, 20.0), (-1.0, 20.0)])
def test_steady_state_of_the_lumped_tire_is_eq_19(s, v):
    # z_ss = v_r / D with the steady-state kappa of a uniform load: eq. 19 to rounding,
    # the locked wheel (omega = 0) included
    p = surface("wet_asphalt").params
    tire, r = UniformLumpedLuGre(p), 0.3
    omega = (1.0 + s) * v / r
    z = (r * omega - v) / decay(p, v, omega, r)
    assert tire.dynamics(z, v, omega, r) == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(tire.mu(z, v, omega, r), braking_mu_uniform(p, s, v), rtol=1e-12)


def test_driving_steady_state_is_eq_18():
    p, r, omega = surface("snow").params, 0.3, 40.0
    for s in (0.02, 0.2, 0.7):
        v = (1.0 - s) * r * omega
        z = (r * omega - v) / decay(p, v, omega, r)
        tire = UniformLumpedLuGre(p)
        np.testing.assert_allclose(tire.mu(z, v, omega, r), driving_mu_uniform(p, s, omega, r),
                                   rtol=1e-12)


def test_burckhardt_fit_quality_is_as_stated():
    for name in ("dry_asphalt", "wet_asphalt", "cobblestone", "snow", "ice"):
        srf = surface(name)
        e = np.asarray(jax.jit(fit_errors, static_argnums=1)(srf.params, name))
        rms, worst = srf.fit_error
        assert math.sqrt(np.mean(e**2)) == pytest.approx(rms, abs=6e-5)
        assert np.max(np.abs(e)) == pytest.approx(worst, abs=6e-5)


def test_peak_is_the_maximum_of_eq_19_and_its_slope_is_the_implicit_one():
    p = surface("dry_asphalt").params

    def peak(theta, v):
        return peak_braking(UniformLumpedLuGre(eqx.tree_at(lambda q: q.theta, p, theta)), v)

    f = jax.jit(peak)
    s_star, mu_star = f(p.theta, 25.0)
    lam = np.linspace(0.0, 1.0, 200_001)
    dense = -np.asarray(jax.jit(jax.vmap(lambda s: braking_mu_uniform(p, -s, 25.0)))(lam))
    assert float(mu_star) == pytest.approx(dense.max(), rel=1e-10)
    assert float(s_star) == pytest.approx(-lam[np.argmax(dense)], abs=1e-5)
    # the peak is flat: the search resolves s* to ~1e-8, so differences need a wide step
    h = 3e-3
    fd = (f(p.theta + h, 25.0)[0] - f(p.theta - h, 25.0)[0]) / (2 * h)
    ad = jax.jit(jax.grad(lambda th: peak(th, 25.0)[0]))(p.theta)
    assert float(ad) == pytest.approx(float(fd), rel=1e-4)


def test_physical_limit_is_the_quadrature_of_the_peak_and_follows_a_change():
    car = braking_quarter_car(surface("snow").tire())
    v = np.linspace(STOP_SPEED, 20.0, 4001)
    mu = np.asarray(jax.jit(jax.vmap(lambda u: peak_braking(car.tire, u)[1]))(jnp.asarray(v)))
    integrand = car.mass * v / (mu * car.Fn_static)
    trapezoid = float(np.sum(0.5 * (integrand[1:] + integrand[:-1]) * np.diff(v)))
    uniform = float(physical_limit(BrakingScenario(car, 20.0))[0])
    assert uniform == pytest.approx(trapezoid, rel=1e-6)
    # a change at the start is the second surface alone; one beyond the stop is the first
    ice = surface("ice").tire()
    at_start = physical_limit(BrakingScenario(car, 20.0, SurfaceChange(ice, distance=0.0)))[0]
    alone = physical_limit(BrakingScenario(braking_quarter_car(ice), 20.0))[0]
    assert float(at_start) == pytest.approx(float(alone), rel=1e-9)
    never = physical_limit(BrakingScenario(car, 20.0, SurfaceChange(ice, distance=1e4)))[0]
    assert float(never) == pytest.approx(uniform, rel=1e-12)


def test_traction_limit_is_the_speed_the_driving_peak_reaches_in_the_time():
    """The time to accelerate from the scenario's speed to `traction_limit` at the driving
    peak, by an independent trapezoidal quadrature of m / (mu* F_n), is the duration."""
    car = braking_quarter_car(surface("snow").tire())
    v_end = float(traction_limit(BrakingScenario(car, 5.0), 2.0))
    v = np.linspace(5.0, v_end, 4001)
    mu = np.asarray(jax.jit(jax.vmap(lambda u: peak_driving(car.tire, u)[1]))(jnp.asarray(v)))
    integrand = car.mass / (mu * car.Fn_static)
    assert v_end > 5.0
    assert float(np.sum(0.5 * (integrand[1:] + integrand[:-1]) * np.diff(v))) == pytest.approx(
        2.0, rel=1e-6)


def test_every_named_surface_builds_and_belongs_to_its_family():
    families = {srf.theta_range for srf in map(surface, SURFACES)}
    assert families == {(0.5, 5.0), (0.3, 40.0)}
    for name in SURFACES:
        srf = surface(name)
        lo, hi = srf.theta_range
        assert lo <= float(srf.params.theta) <= hi and lo <= srf.prior_theta <= hi


def test_actuated_limit_is_the_physical_limit_plus_the_actuator_delay():
    # ideal hardware: the same limit; a pure delay: the car rolls free for the delay, then
    # brakes exactly as the limit does from the same speed (exact, up to the quadrature)
    scenario = braking_scenario("wet_asphalt", 25.0)[0]
    x, t = (float(a) for a in physical_limit(scenario))
    xi, ti = (float(a) for a in actuated_limit(scenario, ideal_hardware()))
    assert xi == pytest.approx(x, rel=1e-6) and ti == pytest.approx(t, rel=1e-6)
    delayed = ideal_hardware(delay=True)
    xd, td = (float(a) for a in actuated_limit(scenario, delayed))
    delay = float(delayed.actuator_delay)
    assert xd == pytest.approx(x + 25.0 * delay, rel=1e-6)
    assert td == pytest.approx(t + delay, rel=1e-6)
    xr = float(actuated_limit(scenario, realistic_hardware())[0])
    assert xr > xd  # the lag and the rate limit cost more than the delay alone
