"""One solve helper and one solution base: every simulation integrates through
`vehsim._integrate.integrate` with its documented defaults, says how the solve went in a
`vehsim.RESULTS` item (``throw=True`` raises with the case's message, ``throw=False`` leaves it
in ``.result``), and returns an `AbstractSolution` with save times, named signals and step
counts. Tiny problems: the point is the plumbing, the models have their own tests."""

import inspect

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vehsim as vs
from vehsim import _integrate
from vehsim._integrate import ATOL, DEFLECTION_ATOL, MAX_STEPS, RTOL, integrate
from vehsim.control.experiments.half_car_abs import rear_abs, simulate_turn, turn_scenario
from vehsim.params import cdc1999, lugre2d_bakker1987
from vehsim.tire.moments import (
    HISTORY_MAX_STEPS,
    moments_step_response,
    simulate_moments_delay,
    simulate_moments_history,
)


R, FZ = 0.3, 4000.0
TS = jnp.linspace(0.0, 0.02, 5)
MAX_STEPS_MESSAGE = "The maximum number of solver steps was reached"


def _ramp(t):
    """A slip angle ramped to 6 deg over 8 ms."""
    return jnp.deg2rad(6.0) * jnp.clip(t / 0.008, 0.0, 1.0)


# vx, vy, omega of a wheel at 20 m/s, slip ratio 0.03, slip angle `_ramp`
RAMP = (lambda t: 20.0 * jnp.cos(_ramp(t)), lambda t: -20.0 * jnp.sin(_ramp(t)),
        lambda t: 20.0 * jnp.cos(_ramp(t)) * 1.03 / R)


def _decay(t, y, args):
    return -50.0 * y + jnp.sin(t)


def test_documented_defaults():
    assert (RTOL, ATOL, DEFLECTION_ATOL, MAX_STEPS) == (1e-8, 1e-8, 1e-10, 100_000)
    assert HISTORY_MAX_STEPS == 4096
    for name in ("`RTOL` = `ATOL` = 1e-8", "`MAX_STEPS` = 100 000", "**solver** `Tsit5`",
                 "**adjoint** `RecursiveCheckpointAdjoint`"):
        assert name in _integrate.__doc__, name
    # every simulation's defaults are the helper's (tire states: the deflection tolerance)
    for fn, atol in ((vs.simulate, ATOL), (vs.simulate_tire, DEFLECTION_ATOL),
                     (vs.simulate_quarter_car, DEFLECTION_ATOL),
                     (simulate_moments_delay, DEFLECTION_ATOL),
                     (simulate_moments_history, DEFLECTION_ATOL)):
        p = inspect.signature(fn).parameters
        assert p["rtol"].default == RTOL, fn.__name__
        assert p["atol"].default == atol, fn.__name__
        assert p["max_steps"].default == MAX_STEPS, fn.__name__
        assert p["throw"].default is True, fn.__name__


def test_integrate_is_diffeqsolve_with_the_defaults():
    """Tsit5, PID control at rtol = atol = 1e-8, saving on the grid: the same numbers as
    diffrax called with them, and the result promoted to `vehsim.RESULTS`."""
    ts = jnp.linspace(0.0, 1.0, 11)
    sol = integrate(_decay, ts, jnp.array([1.0, -2.0]))
    ref = dfx.diffeqsolve(dfx.ODETerm(_decay), dfx.Tsit5(), 0.0, 1.0, None,
                          jnp.array([1.0, -2.0]), saveat=dfx.SaveAt(ts=ts),
                          stepsize_controller=dfx.PIDController(rtol=1e-8, atol=1e-8),
                          max_steps=100_000)
    np.testing.assert_array_equal(np.asarray(sol.ys), np.asarray(ref.ys))
    assert int(sol.stats["num_steps"]) == int(ref.stats["num_steps"])
    assert isinstance(sol.result, vs.RESULTS)
    assert sol.result == vs.RESULTS.successful


def test_throw_raises_with_the_message_and_no_throw_returns_the_result():
    ts = jnp.linspace(0.0, 1.0, 3)
    with pytest.raises(Exception, match=MAX_STEPS_MESSAGE):
        integrate(_decay, ts, jnp.ones(2), max_steps=4)
    sol = integrate(_decay, ts, jnp.ones(2), max_steps=4, throw=False)
    assert sol.result == vs.RESULTS.max_steps_reached
    # under jit the same, through every simulation
    car = vs.HalfCar(vs.rally_gravel(), vs.rally_gravel_tire())
    lumped = vs.LumpedLuGre(cdc1999(), 1.5)
    quarter = vs.QuarterCar(lumped, mass=400.0, inertia=1.2, radius=R)
    moments = vs.MomentLuGre2D(lugre2d_bakker1987(), vs.TrapezoidalLoad(0.25))
    runs = {
        "simulate": lambda **kw: vs.simulate(car, jnp.linspace(0.0, 1.0, 3), jnp.zeros(3),
                                             car.init_state(vx=20.0), **kw),
        "simulate_tire": lambda **kw: vs.simulate_tire(lumped, TS, 20.0, 50.0, R, **kw),
        "simulate_quarter_car": lambda **kw: vs.simulate_quarter_car(quarter, TS, 800.0, 20.0,
                                                                     **kw),
        "simulate_moments_delay": lambda **kw: simulate_moments_delay(
            moments, TS, *RAMP, R, FZ, **kw),
        "simulate_moments_history": lambda **kw: simulate_moments_history(
            moments, TS, *RAMP, R, FZ, **kw),
    }
    for name, run in runs.items():
        sol = eqx.filter_jit(lambda: run(max_steps=2, throw=False))()
        assert vs.result_name(sol.result) == "max_steps_reached", name
        assert not bool(sol.ok), name
        with pytest.raises(Exception, match=MAX_STEPS_MESSAGE):
            jax.block_until_ready(eqx.filter_jit(lambda: run(max_steps=2))())


def _nan_after(t, y, args):
    """A decay whose vector field is NaN after t = 0.35."""
    return jnp.where(t > 0.35, jnp.nan, -y)


COLLAPSED_MESSAGE = "The adaptive step size was rejected down to its floor"


def test_a_vector_field_that_turns_nan_stops_at_the_step_floor():
    """Past t = 0.35 every step is rejected: the default control's floor (`DTMIN_FRACTION` of
    the span) ends the solve within a few dozen steps as `step_size_collapsed`, with the
    states saved before it finite and those after it inf, where without the floor it would
    spend the whole budget and say `max_steps_reached`. A controller of the caller's own
    keeps diffrax's behaviour."""
    ts = jnp.linspace(0.0, 1.0, 11)
    sol = integrate(_nan_after, ts, jnp.ones(2), throw=False)
    assert vs.result_name(sol.result) == "step_size_collapsed"
    assert int(sol.stats["num_steps"]) < 200
    ys = np.asarray(sol.ys)
    np.testing.assert_allclose(ys[:4], np.exp(-np.asarray(ts[:4]))[:, None] * np.ones(2),
                               rtol=1e-7)
    assert np.all(np.isinf(ys[4:]))
    with pytest.raises(Exception, match=COLLAPSED_MESSAGE):
        integrate(_nan_after, ts, jnp.ones(2))
    own = integrate(_nan_after, ts, jnp.ones(2), max_steps=500, throw=False,
                    stepsize_controller=dfx.PIDController(rtol=RTOL, atol=ATOL))
    assert vs.result_name(own.result) == "max_steps_reached"
    # through a simulation: a feedback whose steering turns NaN after 0.07 s
    car = vs.HalfCar(vs.rally_gravel(), vs.rally_gravel_tire())
    tr = vs.simulate(car, jnp.linspace(0.0, 0.2, 5),
                     lambda t, y: jnp.where(t > 0.07, jnp.nan, 0.0) * jnp.ones(3),
                     car.init_state(vx=20.0), throw=False)
    assert vs.result_name(tr.result) == "step_size_collapsed"
    assert int(tr.stats["num_steps"]) < 1000
    assert np.all(np.isfinite(np.asarray(tr.states[:2]))) and np.all(np.isinf(tr.states[2:]))


def test_history_budget_is_its_own():
    """The history solve of `simulate_moments_history` has its own step budget: too small,
    it fails whatever the moment solve's budget."""
    model = vs.MomentLuGre2D(lugre2d_bakker1987(), vs.TrapezoidalLoad(0.25))
    sol = simulate_moments_history(model, TS, *RAMP, R, FZ, history_max_steps=2, throw=False)
    assert vs.result_name(sol.result) == "max_steps_reached"
    ok = simulate_moments_history(model, TS, *RAMP, R, FZ)
    assert bool(ok.ok)
    # its stats count the steps of both solves
    delay = simulate_moments_delay(model, TS, *RAMP, R, FZ)
    assert int(ok.num_steps) > int(delay.num_steps) > 0


def _solutions():
    car = vs.HalfCar(vs.rally_gravel(), vs.rally_gravel_tire())
    lumped = vs.LumpedLuGre(cdc1999(), 1.5)
    moments = vs.MomentLuGre2D(lugre2d_bakker1987(), vs.TrapezoidalLoad(0.25))
    sc, observer = vs.braking_scenario("wet_asphalt", 10.0)
    turn = turn_scenario("dry_asphalt", 15.0, 0.02, brake_time=0.05)
    return {
        "Trajectory": (vs.simulate(car, jnp.linspace(0.0, 0.5, 6), jnp.zeros(3),
                                   car.init_state(vx=20.0)), "speed"),
        "TireSolution": (vs.simulate_tire(lumped, TS, 20.0, 50.0, R), "Fx"),
        "TireSolution (moments)": (simulate_moments_delay(moments, TS, *RAMP, R, FZ), "Mz"),
        "TireSolution (step)": (moments_step_response(moments, TS, 20.0, -1.0, 70.0, R, FZ),
                                "Fy"),
        "QuarterCarSolution": (vs.simulate_quarter_car(
            vs.QuarterCar(lumped, mass=400.0, inertia=1.2, radius=R), TS, 800.0, 20.0), "v"),
        "BrakingRun": (vs.simulate_braking(sc, vs.RuleBasedABS(), observer, duration=0.05),
                       "torque"),
        "TurnRun": (simulate_turn(turn, vs.RuleBasedABS(), rear_abs(), duration=0.1),
                    "yaw_rate"),
    }


def test_every_simulation_returns_the_solution_base():
    for name, (sol, signal) in _solutions().items():
        assert isinstance(sol, vs.AbstractSolution), name
        T = sol.ts.shape[0]
        assert sol[signal].shape[0] == T, name
        assert sol.signals[signal] is sol[signal] or np.array_equal(sol.signals[signal],
                                                                    sol[signal]), name
        assert sol.result == vs.RESULTS.successful and bool(sol.ok), name
        assert "num_steps" in sol.stats and int(sol.num_steps) >= 0, name
        # the step counts are the integration's own
        if name == "TireSolution (step)":
            assert int(sol.num_steps) == 0
        else:
            assert int(sol.num_steps) > 0, name


def test_turn_reports_a_failed_integration():
    """The turn's result is the integrator's: a car started at a non-finite speed gives
    `nonfinite`, a normal one `successful`."""
    good = turn_scenario("dry_asphalt", 15.0, 0.02, brake_time=0.05)
    bad = eqx.tree_at(lambda s: s.speed, good, jnp.asarray(jnp.nan))
    run = simulate_turn(bad, vs.RuleBasedABS(), rear_abs(), duration=0.1)
    assert vs.result_name(run.result) == "nonfinite"
    assert vs.result_name(simulate_turn(good, vs.RuleBasedABS(), rear_abs(),
                                        duration=0.1).result) == "successful"


def test_simulate_tire_takes_either_tire_family():
    """One function for both families: the isotropic lumped 2D tire in pure longitudinal slip
    (vy = 0) at a load F_z gives F_z times the longitudinal lumped tire's mu."""
    lugre = cdc1999()
    v = lambda t: 20.0 - 10.0 * t  # noqa: E731
    omega = lambda t: 0.9 * v(t) / R  # noqa: E731
    one = vs.simulate_tire(vs.LumpedLuGre(lugre, 1.2), TS, v, omega, R)
    two = vs.simulate_tire(vs.IsotropicLumpedLuGre(lugre, kappa0=1.2), TS, v, omega, R, vy=0.0,
                           Fz=3000.0)
    # two solves of different states (the 2D tire carries a lateral one): tolerance level
    np.testing.assert_allclose(two.forces[:, 0], 3000.0 * one.mu, rtol=1e-5)
    np.testing.assert_allclose(two.mu, one.mu, rtol=1e-5)
    np.testing.assert_array_equal(one.forces[:, 1:], 0.0)
    np.testing.assert_array_equal(one["Fz"], 1.0)
    assert abs(float(one.mu[-1])) > 0.1  # a real braking force
    with pytest.raises(ValueError, match="vy must be None"):
        vs.simulate_tire(vs.LumpedLuGre(lugre, 1.2), TS, v, omega, R, vy=0.0)
    # sampled inputs land steps on their samples (the kinks of the interpolation), constants
    # and callables do not
    ts = jnp.linspace(0.0, 0.2, 201)
    tire = vs.LumpedLuGre(lugre, 1.2)
    sampled = vs.simulate_tire(tire, ts, jnp.full(201, 20.0), jnp.full(201, 60.0), R)
    constant = vs.simulate_tire(tire, ts, 20.0, 60.0, R)
    np.testing.assert_allclose(sampled.mu, constant.mu, rtol=1e-5)  # solver tolerance
    assert int(sampled.num_steps) >= 200 > 2 * int(constant.num_steps)
    with pytest.raises(TypeError, match="needs a tire model"):
        vs.simulate_tire(vs.HalfCar(vs.rally_gravel(), vs.rally_gravel_tire()), TS, v, omega, R)
