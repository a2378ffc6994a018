"""Half-car with wheel and suspension dynamics (eqs. 49-60) through `simulate`."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import fd_grad

from vehsim import (
    HalfCar,
    IsotropicLumpedLuGre,
    LinearTire,
    LumpedLuGre,
    LumpedLuGre2D,
    ReducedHalfCar,
    brake_in_turn,
    rally_gravel,
    rally_gravel_tire,
    simulate,
)
from vehsim._signals import as_controls
from vehsim.params import cdc1999, lugre2d_bakker1987


TOL = dict(rtol=1e-10, atol=1e-10)
CAR = HalfCar(rally_gravel(), rally_gravel_tire())


@eqx.filter_jit
@eqx.debug.assert_max_traces(max_traces=1)
def run_car(car, ts, inputs, state0):
    """The hot path: one compilation serves every `CAR`-shaped run below (new parameter,
    input, time and initial-state values never retrace)."""
    return simulate(car, ts, inputs, state0, **TOL)


run = eqx.filter_jit(simulate)


def test_rest_settles_to_static_loads_and_straight_keeps_speed():
    p = CAR.params
    y0 = CAR.init_state().at[8].set(0.03).at[10].set(-0.01)  # heave up, nose up
    tr = run_car(CAR, jnp.linspace(0.0, 10.0, 41), jnp.zeros(3), y0)
    assert abs(float(tr["Fz_F"][0] - p.static_loads()[0])) > 500.0  # really displaced
    np.testing.assert_allclose([tr["Fz_F"][-1], tr["Fz_R"][-1]], p.static_loads(), rtol=1e-7)
    np.testing.assert_allclose([tr["z"][-1], tr["theta"][-1]], 0.0, atol=1e-9)
    tr = run_car(CAR, jnp.linspace(0.0, 10.0, 41), jnp.zeros(3), CAR.init_state(vx=20.0))
    np.testing.assert_allclose(tr["vx"], 20.0, rtol=1e-12)
    np.testing.assert_allclose(tr["x"], 20.0 * tr.ts, rtol=1e-12)
    np.testing.assert_allclose(np.stack([tr["Fx_F"], tr["Fy_R"], tr["yaw_rate"]]), 0.0, atol=1e-9)


def test_dynamic_tire_straight_and_pure_slip_is_lumped_lugre():
    lugre = cdc1999()
    tire = IsotropicLumpedLuGre(lugre, kappa0=1.2)
    z, v, om, r = jnp.array([1e-3, 0.0]), 20.0, 62.0, 0.3
    ref = LumpedLuGre(lugre, kappa0=1.2)
    np.testing.assert_allclose(tire.dynamics(z, v, 0.0, om, r, 1.0)[0],
                               ref.dynamics(z[0], v, om, r), rtol=1e-13)
    np.testing.assert_allclose(tire.forces(z, v, 0.0, om, r, 3.0)[0],
                               3.0 * ref.mu(z[0], v, om, r), rtol=1e-13)
    car = HalfCar(rally_gravel(), tire)
    tr = run(car, jnp.linspace(0.0, 2.0, 41), jnp.zeros(3), car.init_state(vx=20.0))
    np.testing.assert_allclose(tr["vx"], 20.0, rtol=1e-8)  # round-off, solver tolerance
    assert tr.states.shape == (41, 16)


def test_braking_pitches_forward_and_moves_load_per_eq55():
    p = CAR.params
    tr = run_car(CAR, jnp.linspace(0.0, 4.0, 41), jnp.array([-800.0, -600.0, 0.0]),
                 CAR.init_state(vx=25.0))
    FzF0, FzR0 = p.static_loads()
    ax, FzF, FzR = tr["ax"][-1], tr["Fz_F"][-1], tr["Fz_R"][-1]
    theta, z = tr["theta"][-1], tr["z"][-1]
    assert ax < -2.0 and theta > 0 and FzF > FzF0 and FzR < FzR0  # nose down, load forward
    np.testing.assert_allclose(FzF + FzR, p.m * p.g, rtol=1e-6)  # eq. 54, heave settled
    # eq. 55 with theta_dd = 0: F_zF - F_zF^o = -(h + z) sum f_x / (L cos theta), sum f_x = m a_x
    sum_fx = tr["Fx_F"][-1] + tr["Fx_R"][-1]
    np.testing.assert_allclose(sum_fx, p.m * ax, rtol=1e-8)
    np.testing.assert_allclose(FzF - FzF0, -(p.h + z) * sum_fx / (p.wheelbase * jnp.cos(theta)),
                               rtol=1e-5)
    # its first-order size: m a_x h / L (z, theta are small corrections)
    np.testing.assert_allclose(FzF - FzF0, -p.m * ax * p.h / p.wheelbase, rtol=2e-3)


def test_steady_cornering_matches_understeer_gradient():
    """Yaw-rate gain r/delta = V / (L + K V^2), K = m (lR C_R - lF C_F) / (L C_F C_R)."""
    p = rally_gravel()
    car = HalfCar(p, LinearTire(c_kappa=10.0, c_alpha=8.0), LinearTire(c_kappa=10.0, c_alpha=10.0))
    V, delta = 20.0, 0.004

    def hold_speed(t, y):  # rear torque holds the speed against the steered wheel's drag
        return jnp.stack([0.0, 3000.0 * (V - y[3]), delta])

    tr = simulate(car, jnp.linspace(0.0, 8.0, 9), hold_speed, car.init_state(vx=V))
    FzF0, FzR0 = p.static_loads()
    CF, CR = 8.0 * FzF0, 10.0 * FzR0
    K = p.m * (p.lR * CR - p.lF * CF) / (p.wheelbase * CF * CR)
    assert K > 0  # understeer
    vx, r = tr["vx"][-1], tr["yaw_rate"][-1]
    np.testing.assert_allclose(r / delta, vx / (p.wheelbase + K * vx**2), rtol=1e-3)
    np.testing.assert_allclose(tr["yaw_rate"][-2], r, rtol=1e-6)  # steady


def test_reduced_by_slips_equals_full_by_recovered_torques():
    p, tire = rally_gravel(), rally_gravel_tire()
    reduced = ReducedHalfCar(p, tire)
    full = HalfCar(p, tire, suspension=False)

    def slips(t):
        return jnp.stack([-0.04 * jnp.sin(2 * t), 0.08 * jnp.sin(1.5 * t) ** 2,
                          0.15 * jnp.sin(1.2 * t)])

    def slips_dot(t):
        return jax.jvp(slips, (t,), (jnp.ones_like(t),))[1]

    ts = jnp.linspace(0.0, 3.0, 31)
    y0 = jnp.array([0.0, 0.0, 0.0, 15.0, 0.0, 0.0])
    tol = dict(rtol=1e-10, atol=1e-10)
    tr = simulate(reduced, ts, lambda t, y: slips(t), y0, dense=True, **tol)

    def torques(t, y):  # open loop: recovered along the reduced trajectory
        u = slips(t)
        _, _, T_F, T_R = reduced.recover_torques(tr.evaluate(t), u, slips_dot(t))
        return jnp.stack([T_F, T_R, u[2]])

    omF, omR, _, _ = reduced.recover_torques(y0, slips(0.0), slips_dot(0.0))
    yf0 = full.init_state(vx=15.0).at[6].set(omF).at[7].set(omR)
    tf = simulate(full, ts, torques, yf0, **tol)
    assert float(jnp.max(jnp.abs(tr["psi"]))) > 1.0  # a real maneuver
    for k in ["x", "y", "psi", "vx", "vy", "yaw_rate", "omega_F", "omega_R"]:
        np.testing.assert_allclose(tf[k], tr[k], atol=1e-7, err_msg=k)
    for k in ["Fz_F", "Fz_R", "Fx_F", "Fy_F", "Fx_R", "Fy_R"]:
        np.testing.assert_allclose(tf[k], tr[k], atol=1e-4, err_msg=k)


def test_vmap_jit_grad():
    ts = jnp.linspace(0.0, 2.0, 41)
    u0 = jnp.array([-300.0, -200.0, 0.05])

    def final(car, u, vx0):
        tr = run_car(car, ts, u, car.init_state(vx=vx0))
        return tr.states[-1]

    # batch == loop over parameters, inputs and initial states
    ms = jnp.array([1200.0, 1450.0, 1700.0])
    us = jnp.stack([u0, 0.5 * u0, -u0])
    vx0s = jnp.array([12.0, 15.0, 18.0])

    def final_m(m, u, vx0):
        return final(eqx.tree_at(lambda c: c.params.m, CAR, m), u, vx0)

    batch = jax.vmap(final_m)(ms, us, vx0s)
    for i in range(3):
        one = final_m(ms[i], us[i], vx0s[i])
        np.testing.assert_allclose(batch[i], one, rtol=1e-9, atol=1e-9)

    # gradients of the final state wrt mass, inertia, tire parameters and inputs
    def objective(x):
        car = eqx.tree_at(lambda c: (c.params.m, c.params.Iz, c.tire.B, c.tire.D), CAR,
                          (x[0], x[1], x[2], x[3]))
        y = final(car, x[4:7], 15.0)
        return y[1] + 3.0 * y[2] + 0.1 * y[3]  # y, psi, vx at t = 2 s

    x0 = jnp.array([1450.0, 2740.0, 7.0, 0.52, -300.0, -200.0, 0.05])
    g = jax.jit(jax.grad(objective))(x0)
    assert np.all(np.isfinite(g)) and np.all(np.abs(g) > 0)
    np.testing.assert_allclose(g, fd_grad(objective, x0, eps=1e-5), rtol=2e-4)


@pytest.mark.parametrize("car", [CAR, ReducedHalfCar(rally_gravel(), rally_gravel_tire())],
                         ids=["half car", "reduced"])
def test_angle_signals_of_a_car_at_rest_have_finite_gradients(car):
    """The sideslip and the axles' slip angles are the angles of velocities that vanish at
    rest: 0 there with zero gradients, not NaN; elsewhere the angles, with their
    derivatives."""
    names = ("sideslip", "alpha_F", "alpha_R")
    u = jnp.zeros(3)

    def angles(state):
        sig = car.signals(state, u)
        return jnp.stack([sig[n] for n in names])

    start = (lambda vx: car.init_state(vx=vx)) if isinstance(car, HalfCar) else (
        lambda vx: jnp.zeros(6).at[3].set(vx))  # the reduced car: (x, y, psi, vx, vy, r)
    rest = start(0.0)
    assert np.all(np.asarray(angles(rest)) == 0.0)
    assert np.all(np.isfinite(np.asarray(jax.jacrev(angles)(rest))))
    assert np.all(np.isfinite(np.asarray(jax.jacfwd(angles)(rest))))
    moving = start(10.0).at[4].set(0.5)  # vy = 0.5 m/s
    np.testing.assert_allclose(float(angles(moving)[0]), np.arctan2(0.5, 10.0), rtol=1e-12)
    J = np.asarray(jax.jacrev(angles)(moving))
    assert abs(J[0, 4] - 10.0 / (10.0**2 + 0.5**2)) < 1e-9  # d sideslip / d vy


def test_a_lifted_axle_neither_grips_nor_pulls_the_body_down():
    """Pitched far nose down (the rear spring extended past its preload, its load negative):
    the rear wheel has left the ground, so the heave and pitch see only the front's load,
    and the rear tire has no force (the spring pulling the body to the ground was a model
    error)."""
    car = CAR
    state = car.init_state(vx=15.0).at[10].set(0.2)  # theta = 0.2 rad, nose down
    FzF, FzR = car._suspension_loads(state[:12])
    assert float(FzR) < 0 < float(FzF)
    p = car.params
    rates = car.f(state, jnp.zeros(3))
    np.testing.assert_allclose(float(rates[9]), float(FzF) / p.m - p.g, rtol=1e-12)
    sig = car.signals(state, jnp.zeros(3))
    assert float(sig["Fx_R"]) == 0.0 and float(sig["Fy_R"]) == 0.0


def test_braked_in_a_turn_to_a_stop_on_dynamic_tires():
    r"""Braking in a turn from 5 m/s until the car stands, dynamic tires, the default
    explicit solver: the solve succeeds through the stop (a static tire's slips are
    singular there), the torque-limited deceleration is the closed form of the wheel
    equations 52-53 with the chassis, $\dot v = -(T_b/r)/(m + (I_F + I_R)/r^2)$ (the brake
    below the grip, 0.03 rad of steer), and the car comes to rest without rolling back."""
    p = rally_gravel()
    car = HalfCar(p, LumpedLuGre2D(lugre2d_bakker1987()))
    ts = jnp.linspace(0.0, 6.0, 61)
    tr = run(car, ts, brake_in_turn(0.03, 1200.0, t_brake=2.0), car.init_state(vx=5.0))
    assert bool(tr.ok)
    v, vx = np.asarray(tr["speed"]), np.asarray(tr["vx"])
    m, r, inertia = float(p.m), float(p.r), float(p.Iw_F + p.Iw_R)
    decel = (v[25] - v[35]) / (ts[35] - ts[25])  # 2.5-3.5 s: full torque, wheels turning
    np.testing.assert_allclose(decel, 1200.0 / r / (m + inertia / r**2), rtol=1e-4)
    assert v[-1] < 1e-6 and vx.min() > -1e-9


def test_input_forms():
    ts = jnp.array([0.0, 1.0, 3.0])
    samples = jnp.array([[0.0, 1.0, 2.0], [10.0, 1.0, 0.0], [30.0, -1.0, 4.0]])
    u, sampled = as_controls(ts, samples, 3)
    assert sampled
    np.testing.assert_allclose(u(2.0, None), [20.0, 0.0, 2.0], rtol=1e-14)  # linear
    u, sampled = as_controls(ts, jnp.array([1.0, 2.0, 3.0]), 3)
    assert not sampled
    np.testing.assert_allclose(u(7.0, None), [1.0, 2.0, 3.0])
    law = lambda t, y: y[:3] * t  # noqa: E731  (feedback is passed through)
    assert as_controls(ts, law, 3) == (law, False)


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="inputs must be a constant of shape"):
        simulate(CAR, jnp.linspace(0.0, 1.0, 5), jnp.zeros((4, 3)), CAR.init_state(vx=1.0))
    with pytest.raises(ValueError, match="HalfCar.tire_R"):
        HalfCar(rally_gravel(), rally_gravel_tire(), IsotropicLumpedLuGre(cdc1999()))
