"""The braking limit of any tire: the computed steady state (Newton on the tire's own
dynamics) against the closed forms where both exist, the limit of speed-independent curves
against the point mass's closed form, the peak's derivative through the computed route
against the hand-differentiated peak of Burckhardt's curve, and the other-shape tires' peaks
against their formulas."""

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim._constants import GRAVITY
from vehsim._results import RESULTS
from vehsim.control.controllers.braking import (
    DUMP,
    LockedWheel,
    PeakSlipTracking,
    RuleBasedABS,
    SlipTracking,
)
from vehsim.control.controllers.traction import TractionControl, traction_scenario
from vehsim.control.experiments.half_car_abs import rear_abs, simulate_turn, turn_scenario
from vehsim.control.experiments.metrics import available_friction
from vehsim.control.experiments.scenarios import braking_scenario
from vehsim.control.experiments.tires import OTHER_TIRES, other_tire
from vehsim.control.experiments.tuning import (
    _distance_ratio,
    tune_gains,
    value_and_forward_grad,
)
from vehsim.control.loop import STOP_SPEED, closed_loop_grid, stack
from vehsim.control.plant.hardware import realistic_hardware
from vehsim.control.road.bound import actuated_limit, physical_limit, traction_limit
from vehsim.control.road.peak import peak_braking
from vehsim.control.road.surfaces import SURFACES, surface
from vehsim.tire.burckhardt import BURCKHARDT, BurckhardtParams, RelaxedBurckhardt
from vehsim.tire.distributed import DistributedLuGre
from vehsim.tire.load import QuarticLoad
from vehsim.tire.lugre import AbstractLongitudinalTire, LumpedLuGre, solve_steady_state
from vehsim.tire.mf6 import MFLongitudinalTire, MFParams, mf_evaluate
from vehsim.tire.params import table3
from vehsim.tire.relaxed_magic_formula import MagicFormulaParams, RelaxedMagicFormula
from vehsim.tire.steady_state import steady_state_mu
from vehsim.tire.tir import read_tir, shipped_tires
from vehsim.tire.uniform_lumped import UniformLumpedLuGre


R = 0.3
SLIPS = jnp.asarray([-1.0, -0.7, -0.3, -0.19, -0.1, -0.02, -1e-4, 0.0])


def _computed(tire, s, v):
    """mu at rest at braking slip s by Newton on the tire's dynamics (the generic route)."""
    omega = (1.0 + s) * v / R
    return tire.mu(solve_steady_state(tire, v, omega, R), v, omega, R)


CLOSED_FORMS = {
    "eq. 19 (UniformLumpedLuGre)": UniformLumpedLuGre(surface("wet_asphalt").params),
    "lumped, kappa0 (LumpedLuGre)": LumpedLuGre(table3(), kappa0=1.5),
    "Magic Formula (RelaxedMagicFormula)": RelaxedMagicFormula(MagicFormulaParams()),
    "distributed, linear solve": DistributedLuGre(surface("dry_asphalt").params, QuarticLoad(),
                                                  n=9),
}


@pytest.mark.parametrize("name", CLOSED_FORMS)
def test_closed_form_and_computed_steady_state_agree(name):
    # value, slope and curvature in s (the peak's implicit derivative uses all three), at
    # two speeds, from the locked wheel to free rolling
    tire = CLOSED_FORMS[name]

    @jax.jit
    def both(s, v):
        closed = lambda x: tire.braking_mu(x, v, R)  # noqa: E731
        computed = lambda x: _computed(tire, x, v)  # noqa: E731
        state = lambda x: tire.steady_state_mu(v, (1.0 + x) * v / R, R)  # noqa: E731
        return [(f(s), jax.grad(f)(s), jax.grad(jax.grad(f))(s)) for f in (closed, computed)
                ] + [state(s)]

    for v in (30.0, 8.0):
        (a, da, dda), (b, db, ddb), c = jax.vmap(lambda s: both(s, v))(SLIPS)
        np.testing.assert_allclose(b, a, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(c, a, rtol=1e-10, atol=1e-12)  # the model's own rest state
        inner = slice(1, -2)  # the kinks of |v_r| at s = 0 and of |omega r| at s = -1 aside
        np.testing.assert_allclose(db[inner], da[inner], rtol=1e-8)
        np.testing.assert_allclose(ddb[inner], dda[inner], rtol=1e-6, atol=1e-8)


def test_distributed_steady_state_is_eq_17_and_the_quartic_tire_peaks_as_stated():
    # 10 nodes: the discrete steady state within 2e-4 of eq. 17's quadrature
    tire = other_tire("distributed_quartic")
    p = tire.params
    s = jnp.linspace(-1.0, 0.0, 21)
    exact = jax.vmap(lambda x: steady_state_mu(p, QuarticLoad(), 30.0, (1 + x) * 30.0 / R, R))(s)
    np.testing.assert_allclose(jax.vmap(lambda x: tire.braking_mu(x, 30.0, R))(s), exact,
                               atol=2e-4)


def _burckhardt_peak(c1, c2, c3):
    lam = math.log(c1 * c2 / c3) / c2  # d/dlam [c1 (1 - exp(-c2 lam)) - c3 lam] = 0
    return lam, c1 - c3 / c2 - c3 * lam


def _mf_peak_slip(B, C, E):
    # C arctan(B x - E (B x - arctan B x)) = pi/2, solved by bisection in x
    target = math.tan(math.pi / (2 * C))
    lo, hi = 0.0, 1.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        u = B * mid
        lo, hi = (mid, hi) if u - E * (u - math.atan(u)) < target else (lo, mid)
    return 0.5 * (lo + hi)


def test_other_tires_peak_where_their_formulas_do():
    b = other_tire("burckhardt_dry")
    assert type(b).steady_state is AbstractLongitudinalTire.steady_state  # computed route
    lam, mu = _burckhardt_peak(*BURCKHARDT["dry_asphalt"])
    for v in (30.0, 12.0):
        s, m = peak_braking(b, v, R)
        assert float(s) == pytest.approx(-lam, rel=1e-6)
        assert float(m) == pytest.approx(mu, rel=1e-10)
    for name in ("mf_sharp", "mf_low_flat"):
        p = other_tire(name).params
        s, m = peak_braking(other_tire(name), 30.0, R)
        assert float(s) == pytest.approx(-_mf_peak_slip(float(p.B), float(p.C), float(p.E)),
                                         rel=1e-6)
        assert float(m) == pytest.approx(float(p.D), rel=1e-12)
    # the shapes the docstring promises against dry asphalt's LuGre peak (-0.194, 1.098)
    peaks = {n: [float(x) for x in peak_braking(other_tire(n), 30.0, R)] for n in OTHER_TIRES}
    assert -0.13 < peaks["mf_sharp"][0] < -0.1 and peaks["mf_sharp"][1] == pytest.approx(1.1)
    assert -0.3 < peaks["mf_low_flat"][0] < -0.2 and peaks["mf_low_flat"][1] < 0.5
    assert peaks["lumped_table3"][0] < -0.3
    with pytest.raises(ValueError, match="unknown tire 'slick'; known: mf_sharp"):
        other_tire("slick")


def test_peak_slip_derivative_through_the_computed_route_is_burckhardt_s():
    # d lam*/d c2 = (1 - ln(c1 c2 / c3)) / c2^2 and d mu*/d c1 = 1 - c3/(c1 c2): the implicit
    # derivative of the peak needs the curve's second derivatives through the Newton steps
    c1, c2, c3 = BURCKHARDT["dry_asphalt"]

    def peak(c):
        tire = RelaxedBurckhardt(BurckhardtParams(c1=c[0], c2=c[1], c3=c3))
        return jnp.stack(peak_braking(tire, 25.0, R))

    J = jax.jacfwd(peak)(jnp.asarray([c1, c2]))
    assert float(-J[0, 1]) == pytest.approx((1 - math.log(c1 * c2 / c3)) / c2**2, rel=1e-6)
    assert float(J[1, 0]) == pytest.approx(1 - c3 / (c1 * c2), rel=1e-6)
    assert np.all(np.isfinite(J))


def test_limit_of_a_speed_independent_curve_is_the_point_mass_s():
    # x = (v0^2 - v_stop^2) / (2 mu* g), t = (v0 - v_stop) / (mu* g) with F_n = m g: exact for
    # the quadrature (the integrand is linear in the speed); Burckhardt's curve (computed
    # steady state, mu* by hand) and a Magic Formula (closed form, mu* = D)
    v0 = 30.0
    lam, mu_b = _burckhardt_peak(*BURCKHARDT["dry_asphalt"])
    for name, mu in (("burckhardt_dry", mu_b), ("mf_sharp", 1.1)):
        sc, _ = braking_scenario("dry_asphalt", v0, tire=other_tire(name))
        x, t = (float(a) for a in physical_limit(sc))
        assert x == pytest.approx((v0**2 - STOP_SPEED**2) / (2 * mu * GRAVITY), rel=1e-9)
        assert t == pytest.approx((v0 - STOP_SPEED) / (mu * GRAVITY), rel=1e-9)


def test_peak_of_the_tyre_property_file_s_magic_formula():
    # MFLongitudinalTire has no closed form here: its peak from the computed steady state
    # against the largest -F_x / F_z on a dense slip grid of the file's own formula
    tire = MFLongitudinalTire(MFParams.from_tir(read_tir(shipped_tires()["sample_185_80R14_mf61"])))
    kappa = jnp.linspace(-0.4, 0.0, 40001)
    out = mf_evaluate(tire.params, kappa, 0.0, tire.params.FNOMIN, 0.0, None, 30.0, limits=True)
    i = int(jnp.argmax(-out.Fx))
    s, mu = jax.jit(lambda t: peak_braking(t, 30.0, R))(tire)
    assert float(mu) == pytest.approx(float(-out.Fx[i] / tire.params.FNOMIN), rel=1e-8)
    assert float(s) == pytest.approx(float(kappa[i]), abs=2e-5)


# The closed loop on every named surface: one compiled grid (below) serves the rest of the
# module. From 30 m/s, 2.7 s of braking (dry asphalt stops, the others slow down), the
# controllers regulating down to 0.5 m/s; on the first surfaces the estimate-based ABS
# also with its target slip 10 % short and 10 % long, and dry asphalt again with the
# observer started from a prior far from the road; two traction runs from 2 m/s ride along
# (the braking controllers there, and traction control on the brakings, are not looked at).
N_STEPS = 540
CONTROLLERS = ("locked", "rule", "fixed", "estimate", "estimate x0.9", "estimate x1.1",
               "traction")
OFF_PRIOR = 2.5  # the observer's prior theta on dry asphalt (0.81): a road 3 times as slippery
TRACTION = ("dry_asphalt", "snow")


@functools.cache
def _cases():
    pairs = [braking_scenario(s, 30.0) for s in SURFACES]
    sc, ob = braking_scenario("dry_asphalt", 30.0)
    pairs.append((sc, eqx.tree_at(lambda o: o.model.tire.params, ob,
                                  surface("dry_asphalt").with_theta(OFF_PRIOR))))
    pairs += [traction_scenario(s, 2.0) for s in TRACTION]
    return pairs


@functools.cache
def _grid(observer_gain=True):
    pairs = _cases()
    scenarios, observers = stack([p[0] for p in pairs]), stack([p[1] for p in pairs])
    if not observer_gain:  # the observer's covariance, hence its gain, held at nothing
        tiny = jnp.full(len(pairs), 1e-300)
        observers = eqx.tree_at(lambda o: (o.initial_covariance, o.max_covariance), observers,
                                (tiny, tiny))
    controllers = [LockedWheel(), RuleBasedABS(), SlipTracking(), PeakSlipTracking(),
                   PeakSlipTracking(slip_scale=0.9), PeakSlipTracking(slip_scale=1.1),
                   TractionControl()]
    keys = jax.random.split(jax.random.PRNGKey(0), len(pairs))
    runs = eqx.filter_jit(closed_loop_grid)(scenarios, controllers, observers,
                                            realistic_hardware(), keys, N_STEPS, save=True,
                                            handback_speed=0.5)
    return jax.tree_util.tree_map(np.asarray, runs)


def _distance_to(v, x, v_end):
    """Distance at which the speed first falls below `v_end` (linear in the sample)."""
    k = int(np.argmax(v < v_end))
    w = (v[k - 1] - v_end) / (v[k - 1] - v[k])
    return x[k - 1] + w * (x[k] - x[k - 1])


@functools.cache
def _ratios(observer_gain=True):
    """``{case: (v_end, {controller: distance to v_end over the actuated limit to v_end})}``
    for the braking cases, `v_end` the speed every braking controller reached."""
    runs, pairs, hw = _grid(observer_gain), _cases(), realistic_hardware()
    v, x = runs.signals["v"], runs.signals["x"]
    out = {}
    for j in range(len(SURFACES) + 1):
        v_end = max(float(np.max(v[:6, j, -1])) + 0.01, STOP_SPEED)
        bound = float(actuated_limit(pairs[j][0], hw, jnp.asarray(v_end))[0])
        out[j] = v_end, {c: _distance_to(v[i, j], x[i, j], v_end) / bound
                         for i, c in enumerate(CONTROLLERS[:6])}
    return out


def test_every_named_surface_respects_the_limit_on_the_hardware():
    # distance to the speed every braking controller reached in 2.7 s, over the actuated
    # limit to that speed. Measured: on the Burckhardt family every controller 1.005-1.61
    # (estimate-based 1.005-1.053, the most on snow, where its observer starts from dry
    # asphalt's theta); on the CDC 1999 set (sigma1 = 4.95 s/m) the curve rises to the
    # locked wheel, and the bristle damping's transient at lock-up, which the steady-state
    # limit does not count, lets a locked wheel beat it by 3-5 % (locking is the best
    # braking there: the estimate-based ABS, aiming at s* near -0.9, comes closest, 0.99-1.0)
    ratios = _ratios()
    for j, name in enumerate(SURFACES):
        _, r = ratios[j]
        if name.startswith("cdc1999"):
            assert all(0.94 < x for x in r.values()), (name, r)
            assert r["locked"] < 0.98 and r["locked"] == min(r.values()), (name, r)
            assert r["estimate"] < 1.005, (name, r)
        else:
            assert all(x > 1.0 for x in r.values()), (name, r)
            assert r["estimate"] < 1.06, (name, r)
            assert r["estimate"] < r["rule"] < r["locked"], (name, r)
            assert r["locked"] > 1.15, (name, r)
    runs = _grid()
    assert np.all(runs.result == RESULTS.successful)


def test_estimate_based_abs_from_a_far_prior_within_3_percent_of_the_actuated_limit():
    # dry asphalt, the observer started 3 times too slippery: it must learn the road from the
    # wheel speed to aim at the true peak (an observer ignoring its measurements aims at a
    # slip a third of the peak's and does not stop in 2.7 s). The whole stop (to 1 m/s)
    # against the limit on this hardware; measured 1.021 (1.008 with the prior on the road)
    runs, (sc, _) = _grid(), _cases()[len(SURFACES)]
    bound = float(actuated_limit(sc, realistic_hardware())[0])
    assert 1.0 < runs.stopping_distance[3, len(SURFACES)] / bound <= 1.03


@functools.cache
def _slip_over_peak():
    """Median true slip over the true surface's peak slip at the current speed, of the
    estimate-based ABS (x1, x0.9, x1.1) on dry asphalt from the far prior, from 0.3 s on and
    above 5 m/s."""
    runs, (sc, _) = _grid(), _cases()[len(SURFACES)]
    out = []
    for i in (3, 4, 5):
        s = {k: a[i, len(SURFACES)] for k, a in runs.signals.items()}
        peak_slip, _ = available_friction(sc, s)
        steady = (s["ts"] > 0.3) & (s["v"] > 5.0)
        out.append(float(np.median(s["slip"][steady] / peak_slip[steady])))
    return out


def test_estimate_based_abs_holds_the_wheel_at_the_true_peak_slip():
    # the distance cannot tell a target 10 % off: dry asphalt's peak is flat (x0.9 and x1.1
    # cost 0.04-0.14 % of distance), so the slip itself is checked: measured 1.009, and
    # 0.907 and 1.109 with the target scaled by 0.9 and 1.1
    exact, short, long = _slip_over_peak()
    assert abs(exact - 1.0) < 0.04
    assert abs(short - 0.9) < 0.04 and abs(long - 1.1) < 0.04  # it tracks what it aims at


def test_traction_control_gains_speed_near_the_traction_limit():
    # speed gained in 2.7 s from 2 m/s over what a point mass at the driving peak gains
    # (traction_limit); measured 0.966 on dry asphalt, 0.951 on snow
    runs, pairs = _grid(), _cases()
    for k, name in enumerate(TRACTION):
        j = len(SURFACES) + 1 + k
        limit = float(traction_limit(pairs[j][0], N_STEPS * 0.005))
        gain = (runs.final_speed[6, j] - 2.0) / (limit - 2.0)
        assert 0.93 < gain < 1.0, (name, gain)


@functools.cache
def _turns():
    """Braking in a turn on dry asphalt from 25 m/s (steered 0.02 rad, braked from 0.5 s for
    2 s): ABS on both axles, the front wheels locked, the rear wheels locked (a locked axle:
    the rule-based cycle that never dumps, the same compiled program)."""
    sc = turn_scenario("dry_asphalt", 25.0, 0.02, brake_time=0.5)
    lock = RuleBasedABS(decel_threshold=1e9, slip_threshold=1.0, lock_slip=1.0)
    cases = {"abs": (RuleBasedABS(), rear_abs()), "front locked": (lock, rear_abs()),
             "rear locked": (RuleBasedABS(), lock)}
    out = {}
    for name, (front, rear) in cases.items():
        run = simulate_turn(sc, front, rear, duration=2.5)
        s = {k: np.asarray(v) for k, v in run.signals.items()} | {"ts": np.asarray(run.ts)}
        assert run.result == RESULTS.successful
        out[name] = s
    p = sc.car.params
    return out, float(sc.delta) / float(p.lF + p.lR)


def test_abs_keeps_steering_in_a_turn_and_a_locked_axle_does_not():
    # heading change over the braking against a kinematic car's, sum(v delta / l) dt:
    # measured 0.20 rad with ABS, 0.02 with the front wheels locked (the car ploughs on),
    # 2.2 with the rear locked (it spins: peak sideslip 2 rad, against 0.06 with ABS)
    runs, curvature = _turns()
    turned, sideslip = {}, {}
    for name, s in runs.items():
        braking = s["ts"] >= 0.5
        turned[name] = s["psi"][-1] - s["psi"][braking][0]
        sideslip[name] = np.max(np.abs(s["sideslip"][braking]))
    s = runs["abs"]
    braking = s["ts"] >= 0.5
    kinematic = np.sum(s["speed"][braking] * curvature * 0.005)
    assert 0.5 * kinematic < turned["abs"] < 1.5 * kinematic
    assert abs(turned["front locked"]) < 0.2 * kinematic
    assert sideslip["abs"] < 0.1 and sideslip["rear locked"] > 1.0
    assert turned["rear locked"] > 3 * kinematic
    # the rear controller knows its brakes' capacity (0.4 of the front's): each dump lowers
    # the applied torque within 6 samples (told the front's, its torque wound up past the
    # capacity and a dump held the capped torque for 160 ms)
    phase, torque = s["phase"][:, 1], s["torque"][:, 1]
    dumps = np.flatnonzero((phase[1:] == DUMP) & (phase[:-1] != DUMP)) + 1
    dumps = dumps[dumps + 6 < len(torque)]
    assert len(dumps) >= 3
    for k in dumps:
        assert torque[k + 6] < np.max(torque[k - 1:k + 6]) - 20.0, k


@pytest.mark.slow  # two compiles of the closed loop in forward mode (BFGS; J)
def test_gain_tuning_lowers_the_objective():
    # a tiny problem: one braking on dry asphalt from 8 m/s (stopped in 0.9 s), fixed-slip
    # tracking started from gains 5 times too small; J at the start is the objective's own
    # evaluation (the program tune_gains compiled for it)
    sc, ob = braking_scenario("dry_asphalt", 8.0)
    hw = realistic_hardware(encoder=False)
    problem = (stack([sc]), stack([ob]), jax.random.PRNGKey(3)[None],
               jnp.asarray([float(physical_limit(sc)[0])]), hw, 180)
    start = SlipTracking(kp=12.0, ki=120.0)
    tuned, j0, j1, steps, result = tune_gains(start, *problem, max_steps=3)
    assert float(j1) < float(j0) and int(steps) >= 1
    g = jnp.log(jnp.asarray([12.0, 120.0]))
    assert float(_distance_ratio(g, start, *problem)) == pytest.approx(float(j0), rel=1e-12)
    assert (float(tuned.kp), float(tuned.ki)) != (12.0, 120.0)


def test_forward_mode_value_and_gradient_of_the_tuning_is_the_gradient():
    # the tuning's gradient (one forward-mode pass per gain) on a function with a known
    # gradient; through the closed loop, forward mode against finite differences is
    # tests/test_control_gradients.py's
    def fn(g):
        return jnp.sin(g[0]) * jnp.exp(0.5 * g[1]) + g[0] ** 2

    g = jnp.asarray([0.3, -0.7])
    value, grad = value_and_forward_grad(fn, g)
    assert float(value) == pytest.approx(float(fn(g)), rel=1e-15)
    expected = [np.cos(0.3) * np.exp(-0.35) + 0.6, 0.5 * np.sin(0.3) * np.exp(-0.35)]
    np.testing.assert_allclose(np.asarray(grad), expected, rtol=1e-14)
