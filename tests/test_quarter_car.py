"""Quarter-car braking simulator: conservation, closed-form locked-wheel and load limits,
gradients against finite differences, input validation."""

import dataclasses

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim._constants import GRAVITY
from vehsim.params import table3
from vehsim.tire.lugre import LumpedLuGre, PointLuGre, stribeck
from vehsim.tire.magic_formula import magic_formula
from vehsim.tire.relaxed_magic_formula import MagicFormulaParams, RelaxedMagicFormula
from vehsim.vehicle.normal_load import ConstantLoad, LoadRelaxation, PrescribedLoad
from vehsim.vehicle.quarter_car import QuarterCar, simulate_quarter_car


TS = jnp.linspace(0.0, 1.0, 101)


@eqx.filter_jit
def _sim(car, torque):
    return simulate_quarter_car(car, TS, torque, 20.0, rtol=1e-8, atol=1e-10)


def _lumped_car(**kw):
    return QuarterCar(LumpedLuGre(table3(), 1.5), mass=400.0, inertia=1.2, radius=0.3,
                      load=LoadRelaxation(0.15, 0.05), **kw)


def test_free_rolling_is_an_equilibrium():
    car = _lumped_car()
    sol = _sim(car, jnp.zeros_like(TS))
    np.testing.assert_allclose(sol.v, 20.0, rtol=1e-12)
    np.testing.assert_allclose(sol.omega * 0.3, 20.0, rtol=1e-12)
    np.testing.assert_allclose(sol.Fx, 0.0, atol=1e-9)
    np.testing.assert_allclose(sol.Fn, 400.0 * GRAVITY, rtol=1e-12)


def test_locked_wheel_matches_stribeck_and_load_transfer():
    # A torque far above the tire's capacity locks the wheel: v_r = -v (up to the
    # creep of the smoothed brake), kappa |w r| ~ 0, so the lumped model's steady state is
    # mu = -(g(v_r) + sigma2 |v_r|) (eqs. 10, 22-23), the deceleration is |F_x|/m, and the
    # load relaxes to Fn_static + gain |F_x|.
    car = _lumped_car()
    sol = _sim(car, jnp.where(TS > 0.05, 6000.0, 6000.0 * TS / 0.05))
    k = -1  # t = 1 s, long after the lock
    p = table3()
    v_r = 0.3 * sol.omega[k] - sol.v[k]
    assert float(sol.omega[k]) * 0.3 < 0.01 * float(sol.v[k])  # locked
    mu_ss = -(stribeck(p, v_r) + p.sigma2 * abs(v_r))
    np.testing.assert_allclose(sol.Fx[k] / sol.Fn[k], mu_ss, rtol=2e-3)
    np.testing.assert_allclose(sol.Fn[k], 400.0 * GRAVITY - 0.15 * sol.Fx[k], rtol=2e-3)
    # momentum balance m dv = F_x dt over the run (trapezoid on the save grid)
    impulse = float(jnp.trapezoid(sol.Fx, TS))
    np.testing.assert_allclose(400.0 * (sol.v[-1] - sol.v[0]), impulse, rtol=2e-3)


def test_default_constant_load_gives_coulomb_sliding():
    """The default load (`ConstantLoad`): F_n = m g throughout. With a point LuGre tire
    without Stribeck effect or viscous friction (mu_s = mu_c, sigma2 = 0) a sliding wheel
    (v_r < 0 throughout, the bristle at its steady deflection) brakes at F_x = -mu_c F_n
    exactly, so v falls linearly at mu_c g (Coulomb), whatever the mass. (A soft brake
    smoothing omega_eps and Tsit5: a non-stiff wheel, compiled in a fraction of Kvaerno5's
    time.)"""
    p = table3()
    coulomb = eqx.tree_at(lambda q: (q.mu_s, q.sigma2), p, (p.mu_c, jnp.asarray(0.0)))
    torque = jnp.where(TS > 0.05, 6000.0, 6000.0 * TS / 0.05)
    sim = eqx.filter_jit(lambda car: simulate_quarter_car(car, TS, torque, 20.0, rtol=1e-8,
                                                          atol=1e-10, solver=dfx.Tsit5()))
    for mass in (400.0, 250.0):
        car = QuarterCar(PointLuGre(coulomb), mass=mass, inertia=1.2, radius=0.3,
                         omega_eps=5.0)
        assert isinstance(car.load, ConstantLoad)
        sol = sim(car)
        np.testing.assert_allclose(sol.Fn, mass * GRAVITY, rtol=1e-15)
        after = TS >= 0.3  # sliding by then (checked), the bristle at its sliding state
        assert np.all(np.asarray(0.3 * sol.omega - sol.v)[after] < -5.0)
        np.testing.assert_allclose(sol.Fx[after], -float(p.mu_c) * mass * GRAVITY, rtol=1e-7)
        np.testing.assert_allclose(sol.v[after], sol.v[after][0] - float(p.mu_c) * GRAVITY
                                   * (TS[after] - 0.3), rtol=1e-7)


def test_magic_formula_locked_wheel_and_prescribed_load():
    Fn = 3000.0 + 500.0 * jnp.sin(3.0 * TS)
    mf = MagicFormulaParams(B=10.0, C=1.9, D=1.0, E=0.97, relaxation_length=0.25)
    car = QuarterCar(RelaxedMagicFormula(mf), mass=400.0, inertia=1.2, radius=0.3,
                     load=PrescribedLoad(TS, Fn))
    sol = _sim(car, jnp.full_like(TS, 5000.0))
    np.testing.assert_allclose(sol.Fn, Fn, rtol=1e-12)
    # locked: transient slip -> (r w - v)/v = -1, mu -> MF(-1)
    s = (0.3 * sol.omega[-1] - sol.v[-1]) / sol.v[-1]
    np.testing.assert_allclose(sol.Fx[-1] / sol.Fn[-1], magic_formula(s, mf.B, mf.C, mf.D, mf.E),
                               rtol=2e-3)
    np.testing.assert_allclose(float(s), -1.0, atol=2e-3)


def test_magic_formula_peak_closed_form():
    # mu(s) peaks at D where C atan(B s - E(B s - atan B s)) = pi/2
    p = MagicFormulaParams(B=10.0, C=1.9, D=1.1, E=0.5)
    s = jnp.linspace(0.0, 1.0, 200_001)
    np.testing.assert_allclose(jnp.max(magic_formula(s, p.B, p.C, p.D, p.E)), 1.1, rtol=1e-9)


def test_speed_gradient_matches_finite_differences():
    # d v(t_end) / d (mu_s, kappa0) through the adaptive diffrax solve in forward mode (the
    # mode the closed-loop fit uses), during partial slip; tight tolerances so that finite
    # differences are not swamped by step-size changes
    ts = TS[:16]
    torque = 1500.0 * ts / 0.15

    def v_end(x):
        car = _lumped_car()
        car = eqx.tree_at(lambda c: (c.tire.params.mu_s, c.tire.kappa0), car, (x[0], x[1]))
        return simulate_quarter_car(car, ts, torque, 20.0, rtol=1e-10, atol=1e-12,
                                    max_steps=4096, adjoint=dfx.ForwardMode()).v[-1]

    x = jnp.array([1.55, 1.5])
    g = np.asarray(jax.jit(jax.jacfwd(v_end))(x))
    f = jax.jit(v_end)
    fd = [(float(f(x.at[i].add(1e-4 * x[i]))) - float(f(x.at[i].add(-1e-4 * x[i]))))
          / (2e-4 * float(x[i])) for i in range(2)]
    assert np.all(np.isfinite(g)) and np.all(np.abs(g) > 0)
    np.testing.assert_allclose(g, fd, rtol=1e-4)


def test_derivatives_from_an_exact_equilibrium_match_central_differences():
    """From a braked standstill and from free rolling without torque the motion is constant
    and its error zero, so the step-size control (which sees the motion, not its
    derivative) would lengthen the steps without bound: the derivative through steps of a
    third of a second is off by 3 % of the largest derivative (free rolling) to 2.8 times
    it (braked standstill). With the default step ceiling, 10 ms, both modes equal central
    differences (to 9e-5 of it)."""
    ts = jnp.linspace(0.0, 1.2, 13)
    car = _lumped_car()

    def run(x, adjoint=None, **unbounded):  # x = (torque [kN m], v0 [m/s])
        sol = simulate_quarter_car(car, ts, 1000.0 * x[0], x[1], adjoint=adjoint, **unbounded)
        return jnp.concatenate([sol.v, sol.omega, sol.Fx / 1000.0])

    f = jax.jit(run)
    fwd = jax.jit(jax.jacfwd(lambda x: run(x, adjoint=dfx.ForwardMode())))
    rev = jax.jit(jax.jacrev(run))
    unbounded = jax.jit(jax.jacfwd(lambda x: run(x, dfx.ForwardMode(), dtmax=None)))
    for x in (jnp.array([1.0, 0.0]), jnp.array([0.0, 20.0])):
        cd = np.stack([(np.asarray(f(x + e)) - np.asarray(f(x - e))) / 2e-6
                       for e in 1e-6 * jnp.eye(2)], axis=-1)
        scale = np.max(np.abs(cd))
        assert scale > 1.0
        for jac in (fwd, rev):
            np.testing.assert_allclose(np.asarray(jac(x)), cd, atol=5e-4 * scale)
        assert np.max(np.abs(np.asarray(unbounded(x)) - cd)) > 0.01 * scale


@pytest.mark.parametrize("field, kwargs", [
    ("mass", dict(mass=-1.0, inertia=1.0, radius=0.3)),
    ("inertia", dict(mass=400.0, inertia=0.0, radius=0.3)),
    ("radius", dict(mass=400.0, inertia=1.0, radius=-0.3)),
])
def test_bad_quarter_car_names_field(field, kwargs):
    with pytest.raises(ValueError, match=f"QuarterCar.{field} must lie in"):
        QuarterCar(LumpedLuGre(table3()), **kwargs)


def test_bad_load_and_magic_formula_name_field():
    with pytest.raises(ValueError, match="LoadRelaxation.tau"):
        LoadRelaxation(0.1, -1.0)
    with pytest.raises(ValueError, match="MagicFormulaParams.E"):
        MagicFormulaParams(E=1.5)


def test_jit_does_not_retrace_for_new_parameter_values():
    car = _lumped_car()
    f = eqx.debug.assert_max_traces(lambda c: simulate_quarter_car(
        c, TS[:11], 500.0, 20.0, rtol=1e-6, atol=1e-8).v[-1], max_traces=1)
    f = eqx.filter_jit(f)
    a = f(car)
    b = f(dataclasses.replace(car, mass=500.0))  # a new car, built as users build one
    assert float(b) != float(a)
    _ = jax.block_until_ready(b)
