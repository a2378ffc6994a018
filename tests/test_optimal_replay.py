"""Replay of an optimal primitive on the full half-car: torque recovery, open-loop drift,
path tracking. One coarse corner90 min-time primitive (the settings of
tests/test_optimal_primitives.py) serves every test."""

import dataclasses
import math

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


@eqx.filter_jit
def _rk4_nodes(problem, x0, us):
    """The knots of ``problem``'s RK4 shooting from ``x0`` under the rates ``us``."""

    def stage(x, k_u):
        x = problem.transition(x, k_u[1], k_u[0])
        return x, x

    _, xs = jax.lax.scan(stage, x0, (jnp.arange(us.shape[0]), us))
    return jnp.concatenate([x0[None], xs])


def test_recovered_torques_reproduce_the_primitive_on_the_equivalent_full_model(prim):
    """Closed consistency check: HalfCar without suspension (quasi-static loads) and the
    same static tire, driven by the recovered torques, is the reduced model; it follows the
    continuous-time reference to solver tolerance, and the primitive's RK4 knots differ from
    it by their discretisation error, computed independently here: the same inputs
    integrated by 8 RK4 steps per segment (error 8^-4 of one step's)."""
    r = replay_open_loop(prim, suspension=False)
    d = r.drift
    assert d["completed"]
    assert d["max_deviation_from_reference"] < 1e-4
    assert d["max_speed_error"] < 1e-4
    knots = np.asarray(prim.solution.xs)
    fine = np.asarray(_rk4_nodes(dataclasses.replace(prim.problem, steps_per_stage=8),
                                 prim.solution.xs[0], prim.solution.us))
    rk4_error = np.hypot(*(knots[:, :2] - fine[:, :2]).T)
    assert rk4_error.max() > 1e-4  # a discretisation error worth checking (1.8 mm)
    np.testing.assert_allclose(d["reference_vs_primitive"], rk4_error.max(), rtol=0, atol=1e-5)
    np.testing.assert_allclose(d["final_position_error"], rk4_error[-1], rtol=0, atol=1e-5)
    np.testing.assert_allclose(d["final_heading_error"], fine[-1, 2] - knots[-1, 2], atol=1e-6)
    # the slips realised by the torques are the primitive's (wheel dynamics, eqs. 52-53)
    np.testing.assert_allclose(r.trajectory["kappa_F"], r.reference["kappa_F"], atol=1e-5)
    np.testing.assert_allclose(r.trajectory["kappa_R"], r.reference["kappa_R"], atol=1e-5)
    # on the road up to the reference's own corner cut between the coarse grid's nodes
    assert d["max_corridor_violation"] <= d["reference_corridor_violation"] + 1e-4


def test_tracking_keeps_the_dynamic_tire_car_on_the_road(prim):
    """Full half-car (suspension, wheel spin, dynamic LuGre tire), against the road's own
    sizes (2 m wide): open loop the rear wheel, braked at the friction peak, locks, and the
    car leaves the road by more than half its width and ends more than a road width from the
    primitive's end; with the tracking feedback it leaves the road by less than a tenth of
    half its width (measured 6.8 cm; the reference, whose corner clearance keeps it on the road
    between the nodes, by 1 mm), stays within half a road width of the reference, and ends
    within half a road
    width of the primitive's end, pointing down the exit leg (over one wheelbase its heading
    error moves it less than half the road width)."""
    tire = matched_lugre_tire()
    ol = replay_open_loop(prim, tire=tire).drift
    run = replay_tracking(prim, tire=tire)
    tr = run.drift
    exit_leg = prim.problem.road.legs[-1]
    half_width = 0.5 * min(exit_leg.xmax - exit_leg.xmin, exit_leg.ymax - exit_leg.ymin)
    assert half_width == 1.0
    p = prim.problem.vehicle.params
    # both start from the suspension and LuGre steady state at the primitive's slips
    _check_equilibrium(default_vehicle(prim, tire), run.trajectory.states[0],
                       prim.solution.xs[0, 8])
    np.testing.assert_allclose([run.trajectory["kappa_F"][0], run.trajectory["kappa_R"][0]],
                               prim.solution.xs[0, 6:8], atol=1e-12)
    assert ol["max_corridor_violation"] > half_width  # measured 1.9 m
    assert ol["final_position_error"] > 2 * half_width  # measured 6.7 m
    assert tr["completed"]
    assert tr["max_corridor_violation"] < 0.1 * half_width
    assert tr["max_deviation_from_reference"] < half_width  # measured 0.15 m
    assert tr["final_position_error"] < half_width  # measured 0.15 m
    assert abs(tr["final_heading_error"]) < math.atan(half_width / float(p.lF + p.lR))


def test_matched_lugre_steady_state_is_close_to_the_friction_ellipse():
    """The documented fit: the tire's own steady state (dynamics = 0, solved by Newton on
    `IsotropicLumpedLuGre.dynamics`) is the closed form of its docstring,
    |mu| = sigma0 s / (theta sigma0 s / g(s V) + kappa0 / L) (sigma2 = 0), and lies within
    0.06 (documented max misfit 0.055) of D sin(C atan(B s)), pure longitudinal slip and pure
    side slip, at rolling speeds 6-10 m/s. The friction ellipse peaks at D exactly at
    s* = tan(pi/(2C))/B; the closed form's own peak lies where the friction ellipse is within
    1 % of D (a band from the closed form: |C atan(B s) - pi/2| <= arccos(0.99))."""
    from scipy.optimize import minimize_scalar

    lugre, fe = matched_lugre_tire(), rally_gravel_tire()
    r = 0.3
    p = lugre.params
    q = {n: float(getattr(p, n)) for n in ("sigma0", "mu_c", "mu_s", "v_s", "alpha", "theta",
                                            "L")}
    B, C, D = float(fe.B), float(fe.C), float(fe.D)

    def closed_form(s, V):
        g = q["mu_c"] + (q["mu_s"] - q["mu_c"]) * np.exp(-np.abs(s * V / q["v_s"]) ** q["alpha"])
        return q["sigma0"] * s / (q["theta"] * q["sigma0"] * s / g + float(lugre.kappa0) / q["L"])

    def mu_ss(vx, vy, omega):
        z = jnp.zeros(2)
        for _ in range(3):  # linear in z: one step is exact
            z = z - jnp.linalg.solve(jax.jacfwd(lambda z: lugre.dynamics(z, vx, vy, omega, r,
                                                                          1.0))(z),
                                     lugre.dynamics(z, vx, vy, omega, r, 1.0))
        return lugre.forces(z, vx, vy, omega, r, 1.0)[:2]

    s_star = np.tan(np.pi / (2 * C)) / B
    np.testing.assert_allclose(fe.mu_of_s(s_star), D, rtol=1e-14)
    band = [np.tan((np.pi / 2 + sign * np.arccos(0.99)) / C) / B for sign in (-1, 1)]
    s = jnp.linspace(0.01, 1.0, 60)
    worst = 0.0

    @jax.jit
    def pure_slip(V):
        # braking: wheel rolls at omega r = V, the road passes at V (1 + s): s = (V_x - w r)/(w r)
        return (jax.vmap(lambda s: mu_ss(V * (1 + s), 0.0, V / r))(s),
                jax.vmap(lambda s: mu_ss(V, V * s, V / r))(s))

    for V in (6.0, 8.0, 10.0):
        f_long, f_lat = pure_slip(V)
        np.testing.assert_allclose(-f_long[:, 0], closed_form(np.asarray(s), V), rtol=1e-12)
        np.testing.assert_allclose(f_lat[:, 1], f_long[:, 0], rtol=1e-12)  # isotropic
        worst = max(worst, float(jnp.max(jnp.abs(-f_long[:, 0] - fe.mu_of_s(s)))))
        peak = minimize_scalar(lambda x: -closed_form(x, V), bounds=(0.01, 1.0),
                               method="bounded", options=dict(xatol=1e-9)).x
        assert band[0] < peak < band[1], (V, peak, band)
        assert abs(float(s[jnp.argmax(-f_long[:, 0])]) - peak) <= float(s[1] - s[0])
    assert worst < 0.06
