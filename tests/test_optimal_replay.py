"""Replay of an optimal primitive on the full half-car: torque recovery, open-loop drift,
path tracking. One coarse corner90 min-time primitive (the settings of
tests/test_optimal_primitives.py) serves every test."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from optimal_cache import corner90_min_time

from vehsim.optimal.replay import (
    default_vehicle,
    initial_state,
    matched_lugre_tire,
    replay_open_loop,
    replay_tracking,
)
from vehsim.tire.friction_ellipse import rally_gravel_tire


# one worker for this module and its peer: they share the compiled, solved primitive
pytestmark = pytest.mark.xdist_group("corner90_min_time")


@pytest.fixture(scope="module")
def prim():
    p = corner90_min_time()  # shared with tests/test_optimal_primitives.py
    assert p.solution.converged
    return p


def _check_equilibrium(car, y0, delta):
    """Heave/pitch at rest (eq. 54, 55 with zero accelerations), tire states at rest."""
    u = jnp.array([0.0, 0.0, delta])
    rates = car.f(y0, u)
    np.testing.assert_allclose(rates[jnp.array([9, 11])], 0.0, atol=1e-9)  # z_dd, theta_dd
    np.testing.assert_allclose(rates[12:], 0.0, atol=1e-9)  # friction states at rest
    sig = car.signals(y0, u)
    p = car.params
    np.testing.assert_allclose(sig["Fz_F"] + sig["Fz_R"], p.m * p.g, rtol=1e-9)
    return sig


def test_initial_state_is_the_suspension_equilibrium_with_the_reduced_loads(prim):
    """Static tire: the suspension equilibrium carries the quasi-static loads of the reduced
    model (which neglects z in the pitch arm h + z and cos(theta)), and the wheel speeds
    realise the primitive's initial slips."""
    x0 = prim.solution.xs[0]
    red = prim.problem.vehicle
    FzF_qs, FzR_qs = red.normal_loads(x0[:6], x0[6:9])
    mg = float(red.params.m * red.params.g)
    car = default_vehicle(prim)
    y0 = eqx.filter_jit(initial_state)(car, x0[:6], x0[6:9])
    sig = _check_equilibrium(car, y0, x0[8])
    np.testing.assert_allclose([sig["kappa_F"], sig["kappa_R"]], x0[6:8], atol=1e-12)
    assert abs(float(sig["Fz_F"] - FzF_qs)) < 2e-3 * mg
    assert abs(float(sig["Fz_R"] - FzR_qs)) < 2e-3 * mg


def test_recovered_torques_reproduce_the_primitive_on_the_equivalent_full_model(prim):
    """Closed consistency check: HalfCar without suspension (quasi-static loads) and the
    same static tire, driven by the recovered torques, is the reduced model; it follows the
    continuous-time reference to solver tolerance (measured: < 1e-5 m), and the primitive's
    RK4 nodes to their discretisation error (measured 1.8 mm at 30 segments)."""
    r = replay_open_loop(prim, suspension=False)
    d = r.drift
    assert d["completed"]
    assert d["max_deviation_from_reference"] < 1e-4
    assert d["max_speed_error"] < 1e-4
    assert d["reference_vs_primitive"] < 5e-3
    assert d["final_position_error"] < 5e-3
    assert abs(d["final_heading_error"]) < 1e-3
    # the slips realised by the torques are the primitive's (wheel dynamics, eqs. 52-53)
    np.testing.assert_allclose(r.trajectory["kappa_F"], r.reference["kappa_F"], atol=1e-5)
    np.testing.assert_allclose(r.trajectory["kappa_R"], r.reference["kappa_R"], atol=1e-5)
    # on the road up to the reference's own corner cut between the coarse grid's nodes
    assert d["max_corridor_violation"] <= d["reference_corridor_violation"] + 1e-4


def test_tracking_keeps_the_dynamic_tire_car_on_the_road(prim):
    """Full half-car (suspension, wheel spin, dynamic LuGre tire): open loop the rear wheel,
    braked at the friction peak, locks and the car leaves the road by metres; the tracking
    feedback keeps it within the reference's own corridor violation (+ 2 cm) and ends within
    0.3 m and 0.1 rad of the primitive."""
    tire = matched_lugre_tire()
    ol = replay_open_loop(prim, tire=tire).drift
    run = replay_tracking(prim, tire=tire)
    tr = run.drift
    # both start from the suspension and LuGre steady state at the primitive's slips
    _check_equilibrium(default_vehicle(prim, tire), run.trajectory.states[0],
                       prim.solution.xs[0, 8])
    np.testing.assert_allclose([run.trajectory["kappa_F"][0], run.trajectory["kappa_R"][0]],
                               prim.solution.xs[0, 6:8], atol=1e-12)
    assert ol["max_corridor_violation"] > 1.0  # measured 1.89 m
    assert ol["final_position_error"] > 3.0  # measured 6.7 m
    assert tr["completed"]
    assert tr["max_corridor_violation"] < 0.2 * ol["max_corridor_violation"]
    assert tr["max_corridor_violation"] <= tr["reference_corridor_violation"] + 0.02
    assert tr["final_position_error"] < 0.3  # measured 0.15 m
    assert abs(tr["final_heading_error"]) < 0.1  # measured 0.064 rad
    assert tr["max_deviation_from_reference"] < 0.3


def test_matched_lugre_steady_state_is_close_to_the_friction_ellipse():
    """The documented fit: the tire's own steady state (dynamics = 0, solved by Newton on
    `IsotropicLumpedLuGre.dynamics`) against D sin(C atan(B s)), pure longitudinal slip and
    pure side slip, at rolling speeds 6-10 m/s: max misfit 0.055 in mu (documented)."""
    lugre, fe = matched_lugre_tire(), rally_gravel_tire()
    r = 0.3

    def mu_ss(vx, vy, omega):
        z = jnp.zeros(2)
        for _ in range(3):  # linear in z: one step is exact
            z = z - jnp.linalg.solve(jax.jacfwd(lambda z: lugre.dynamics(z, vx, vy, omega, r,
                                                                          1.0))(z),
                                     lugre.dynamics(z, vx, vy, omega, r, 1.0))
        return lugre.forces(z, vx, vy, omega, r, 1.0)[:2]

    s = jnp.linspace(0.01, 1.0, 60)
    worst = 0.0
    for V in (6.0, 8.0, 10.0):
        omega = V / r
        # braking: wheel rolls at omega r = V, the road passes at V (1 + s): s = (V_x - w r)/(w r)
        f_long = jax.vmap(lambda s: mu_ss(V * (1 + s), 0.0, omega))(s)
        f_lat = jax.vmap(lambda s: mu_ss(V, V * s, omega))(s)
        target = fe.mu_of_s(s)
        np.testing.assert_allclose(f_long[:, 0], -jnp.abs(f_long[:, 0]))  # opposes sliding
        np.testing.assert_allclose(f_lat[:, 1], -jnp.abs(f_lat[:, 1]))
        np.testing.assert_allclose(f_lat[:, 1], f_long[:, 0], rtol=1e-12)  # isotropic
        worst = max(worst, float(jnp.max(jnp.abs(-f_long[:, 0] - target))))
        assert abs(float(s[jnp.argmax(-f_long[:, 0])]) - 0.215) < 0.06  # peak slip
    assert worst < 0.06
