"""Derivatives at the edge points of models outside the tires (zero slip, zero speed, zero
noise, a switched-off lag), in both modes, against a closed form or finite differences:
each of these was NaN or 0 where the function is smooth or has a symmetric kink."""

import jax
import jax.numpy as jnp
import numpy as np

import vehsim as vs
from vehsim.control.plant.hardware import brake_torque
from vehsim.optimal.primitives import rally_gravel_car
from vehsim.optimal.shooting import ManeuverOCP, PointMassOCP


def _both(f, x):
    """(reverse, forward) derivative of scalar f at x, along each axis of x."""
    x = jnp.asarray(x, float)
    return np.asarray(jax.grad(f)(x)), np.asarray(jax.jacfwd(f)(x))


def test_burckhardt_belief_slope_at_zero_slip_is_c1_c2_minus_c3():
    """sgn(s) f(|s|) is smooth at s = 0, with slope c1 c2 - c3 (per unit of s)."""
    c = jnp.array([1.28, 23.99, 0.52])
    b = vs.BurckhardtBelief(params=c)
    v, r = 20.0, 0.3
    exact = (c[0] * c[1] - c[2]) / b.relaxation_length
    rev, fwd = _both(lambda z: b.mu(z, v, v / r, r), 0.0)
    np.testing.assert_allclose([rev, fwd], [exact, exact], rtol=1e-12)
    # its steady state through omega at free rolling (slip (omega r - v) / v): (c1 c2 - c3)
    # r / v, which a central difference confirms to its truncation error
    ss = lambda om: b.steady_state_mu(v, om, r)  # noqa: E731
    exact = (c[0] * c[1] - c[2]) * r / v
    fd = (ss(v / r + 1e-5) - ss(v / r - 1e-5)) / 2e-5
    rev, fwd = _both(ss, v / r)
    np.testing.assert_allclose([rev, fwd, fd], [exact] * 3, rtol=1e-5)
    np.testing.assert_allclose([rev, fwd], [exact, exact], rtol=1e-12)
    # and the values beyond the cap |s| = 1 are the capped curve's
    np.testing.assert_allclose(b._curve(jnp.asarray(-3.0)),
                               -(c[0] * (1 - np.exp(-c[1])) - c[2]), rtol=1e-14)


def test_zero_sensor_noise_has_the_symmetric_derivative_zero():
    """sigma_v = |(sigma_V, r sigma_omega)| / sqrt 2: a cone at zero noise, derivative 0 (as
    |x|'s at 0), where the square root's was NaN in both modes."""
    def f(z):
        return vs.slip_velocity_std(vs.DriveSensors(wheel_speed_std=z[0], velocity_std=z[1]),
                                    z[2])

    for grad in _both(f, [0.0, 0.0, 0.3]):
        np.testing.assert_array_equal(grad, 0.0)
    rev, fwd = _both(f, [0.1, 0.02, 0.3])
    fd = [(f(jnp.array([0.1, 0.02, 0.3]).at[i].add(1e-7))
           - f(jnp.array([0.1, 0.02, 0.3]).at[i].add(-1e-7))) / 2e-7 for i in range(3)]
    np.testing.assert_allclose([rev, fwd], [fd, fd], rtol=1e-6)


def test_speed_and_max_exit_cost_at_standstill_are_finite():
    car = rally_gravel_car()
    road = vs.CentrelineRoad.from_segments([("straight", 20.0), ("arc", 15.0, 90.0)], 6.0)
    curvilinear = vs.CurvilinearManeuverOCP.from_road(road, car, num_stages=8,
                                                      objective="max-exit")
    maneuver = ManeuverOCP(vehicle=car, road=vs.road("corner90"), objective="max-exit",
                           num_stages=4, steps_per_stage=1)
    point = PointMassOCP(road=vs.road("corner90"), objective="max-exit", num_stages=4,
                         steps_per_stage=1)
    for f, x, i in ((curvilinear.speed, jnp.zeros(9), (2, 3)),
                    (curvilinear.terminal_cost, jnp.zeros(9), (2, 3)),
                    (maneuver.terminal_cost, jnp.zeros(10).at[9].set(2.0), (3, 4)),
                    (point.terminal_cost, jnp.zeros(5).at[4].set(2.0), (2, 3))):
        for grad in _both(f, x):
            np.testing.assert_array_equal(grad, 0.0)
        # away from standstill the speed's derivative is the unit velocity
        y = x.at[i[0]].set(3.0).at[i[1]].set(4.0)
        rev, fwd = _both(f, y)
        sign = 1.0 if f == curvilinear.speed else -1.0
        np.testing.assert_allclose([rev[list(i)], fwd[list(i)]], [sign * np.array([0.6, 0.8])] * 2,
                                   rtol=1e-12)


def test_a_switched_off_lag_with_no_time_constant_has_finite_derivatives():
    """The lag off, its time constant is not checked and may be 0: the unused branch's
    exp(-t/0) at t = 0 made reverse mode NaN."""
    hw = vs.ideal_hardware(time_constant=0.0)
    rev, fwd = _both(lambda target: brake_torque(hw, 100.0, target, 0.0), 800.0)
    assert rev == fwd == 1.0


def test_forward_mode_through_the_open_loop_prediction_names_the_adjoint():
    """The open-loop prediction passes its default adjoint explicitly: forward mode through
    it raised JAX's generic custom_vjp error rather than the message naming the remedy,
    which then works."""
    import diffrax as dfx
    import equinox as eqx
    import pytest

    from vehsim._integrate import FORWARD_MODE_MESSAGE

    model = vs.LumpedLuGre(vs.params.cdc1999(), kappa0=1.2)
    n = 11
    d = vs.BrakingData(t=jnp.linspace(0.0, 0.05, n), v=jnp.full(n, 20.0),
                       omega=jnp.full(n, 60.0), F_x=jnp.full(n, -1000.0),
                       F_n=jnp.full(n, 3500.0), r=jnp.asarray(0.3))
    s0 = jnp.asarray(float(model.params.sigma0))

    def f(s, adjoint=None):
        m = eqx.tree_at(lambda m: m.params.sigma0, model, s)
        return vs.predict_open_loop(m, d, adjoint=adjoint)[-1]

    with pytest.raises(TypeError, match="pass adjoint=diffrax.ForwardMode()") as err:
        jax.jvp(f, (s0,), (jnp.ones(()),))
    assert str(err.value) == FORWARD_MODE_MESSAGE
    fwd = jax.jvp(lambda s: f(s, dfx.ForwardMode()), (s0,), (jnp.ones(()),))[1]
    np.testing.assert_allclose(fwd, jax.grad(f)(s0), rtol=1e-9)


def test_a_peak_at_lock_is_the_end_of_the_range_with_its_derivatives():
    """On a surface whose braking curve still rises at lock the peak is the end s* = -1,
    exactly, and its derivatives in v are those of the end point (ds*/dv = 0,
    dmu*/dv = the curve's at lock): the search stopped 7e-11 short of it, where the rule
    for an interior peak gave dmu*/dv 19 % off and ds*/dv = -0.156. The physical limit's
    distance inherits it."""
    import equinox as eqx

    tire = vs.surface("cdc1999_1").tire()
    peak = lambda v: jnp.stack(vs.peak_braking(tire, v, 0.3))  # noqa: E731
    s, mu = peak(20.0)
    assert s == -1.0
    fd = (peak(20.0 + 1e-3) - peak(20.0 - 1e-3)) / 2e-3
    for jac in (jax.jacfwd(peak)(20.0), jax.jacrev(peak)(20.0)):
        np.testing.assert_allclose(jac, fd, rtol=1e-6, atol=1e-12)
    scenario, _ = vs.braking_scenario("cdc1999_1", 30.0)

    def distance(theta):
        return vs.physical_limit(eqx.tree_at(lambda q: q.car.tire.params.theta, scenario,
                                             theta))[0]

    theta = scenario.car.tire.params.theta
    fd = (distance(theta + 1e-4) - distance(theta - 1e-4)) / 2e-4
    rev, fwd = _both(distance, theta)
    np.testing.assert_allclose([rev, fwd], [fd, fd], rtol=1e-6)


def test_the_peak_friction_at_standstill_is_its_limit_not_zero():
    """At V = 0 every slip velocity is 0 and the steady state has no friction: the peak was
    0 there, while it rises towards 2.6 as V falls (2.14 at 0.1 m/s). Below the floor
    it is the peak at the floor, close to the limit, with slope 0 in both modes."""
    from vehsim.drive.estimator import PEAK_SPEED_FLOOR, peak_friction
    from vehsim.drive.horizon import _plant_tire

    tire = _plant_tire()
    peak = lambda v: peak_friction(tire, 1.0, v)  # noqa: E731
    at_floor = float(peak(PEAK_SPEED_FLOOR))
    assert float(peak(1e-3)) < at_floor < 2.61
    assert float(peak(0.0)) == at_floor
    for grad in _both(peak, 0.0):
        np.testing.assert_array_equal(grad, 0.0)
    # above the floor the slope is the central difference's
    fd = (peak(0.1 + 1e-6) - peak(0.1 - 1e-6)) / 2e-6
    np.testing.assert_allclose(_both(peak, 0.1), [fd, fd], rtol=1e-5)
