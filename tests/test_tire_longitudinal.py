"""Longitudinal LuGre: point (eqs. 8-10), distributed (11-14), steady state (15-19), lumped (22-25)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import assert_grad_matches_fd, fd_grad, module_grad_matches_fd, one_sided_slopes

import vehsim as vs


R = 0.3
PARAM_FIELDS = ["sigma0", "sigma1", "sigma2", "mu_c", "mu_s", "v_s", "alpha", "theta", "L"]


@pytest.fixture
def p():
    return vs.params.table3()


# --- steady state: closed forms ----------------------------------------------------------


def test_braking_and_driving_closed_forms_match_quadrature_of_eq17(p):
    load = vs.UniformLoad()
    for v in [5.0, 20.0, 35.0]:
        for s in [-0.999, -0.6, -0.1, -1e-3, 0.0]:
            om = v * (1 + s) / R
            assert np.isclose(vs.braking_mu_uniform(p, s, v),
                              vs.steady_state_mu(p, load, v, om, R), rtol=1e-12, atol=1e-14)
    om = 50.0
    for s in [1e-4, 0.05, 0.4, 0.95]:
        v = R * om * (1 - s)
        assert np.isclose(vs.driving_mu_uniform(p, s, om, R),
                          vs.steady_state_mu(p, load, v, om, R), rtol=1e-12)


@pytest.mark.parametrize("gap", [1e-6, 1e-9, 1e-12, 1e-14])
def test_braking_closed_form_slope_towards_lock_is_the_quadratures(p, gap):
    """d/ds of eq. 19 at s = -1 + gap, in both modes, equals the slope of eq. 17's
    quadrature (regrouped towards lock) through omega = v (1 + s) / r: the closed form's
    s / |1 + s| times a small psi cancelled, and its derivative was 100 % off at 1e-14."""
    v = 20.0
    s = -1.0 + gap
    rev = jax.grad(lambda s: vs.braking_mu_uniform(p, s, v))(s)
    fwd = jax.jvp(lambda s: vs.braking_mu_uniform(p, s, v), (s,), (1.0,))[1]
    peer = jax.grad(lambda om: vs.steady_state_mu(p, vs.UniformLoad(), v, om, R))(
        v * gap / R) * v / R
    np.testing.assert_allclose([rev, fwd], [peer, peer], rtol=1e-8)


@pytest.mark.parametrize("wr", [1e-120, 1e-200, 1e-300])
def test_slopes_below_the_transport_floor_are_the_limits(p, wr):
    """Between lock and |omega r| ~ 1e-154 the rate k ~ 1/|omega r| has a derivative that
    overflows (NaN times a saturated exponential, in both the steady states and the uniform
    lumped model's decay). Below `TRANSPORT_FLOOR` the slopes in omega, in both modes, are
    the ones at |omega r| = 1e-14 (which no floor touches), and the values are unchanged."""
    v = 20.0
    t = vs.UniformLumpedLuGre(p)
    z0 = t.steady_state(v, 1.0, R)
    for f in (lambda om: vs.steady_state_mu(p, vs.QuarticLoad(), v, om, R),
              lambda om: vs.z_ss(p, 0.1, v, om, R),
              lambda om: t.steady_state(v, om, R),
              lambda om: t.dynamics(z0, v, om, R)):
        peer = jax.grad(f)(1e-14 / R)
        rev = jax.grad(f)(wr / R)
        fwd = jax.jvp(f, (wr / R,), (1.0,))[1]
        np.testing.assert_allclose([rev, fwd], [peer, peer], rtol=1e-8)
        np.testing.assert_allclose(f(wr / R), f(1e-14 / R), rtol=1e-12)


def test_slope_at_exact_lock_is_the_mean_of_the_one_sided_slopes(p):
    """|1 + s| (eq. 19) and |omega r| (eq. 17) have a kink at lock: the derivative there, in
    both modes, is the mean of the slopes just either side (as |x|'s derivative is 0 at 0)."""
    v = 20.0
    for f, x0, h in ((lambda s: vs.braking_mu_uniform(p, s, v), -1.0, 1e-9),
                     (lambda om: vs.steady_state_mu(p, vs.UniformLoad(), v, om, R), 0.0, 1e-9)):
        sides = [jax.grad(f)(x0 - h), jax.grad(f)(x0 + h)]
        assert abs(sides[0] - sides[1]) > 0.1 * abs(sides[0])
        np.testing.assert_allclose([jax.grad(f)(x0), jax.jvp(f, (x0,), (1.0,))[1]],
                                   [np.mean(sides)] * 2, rtol=1e-6)


def test_locked_wheel_steady_state_is_point_model(p):
    v = 15.0
    mu_point = -vs.stribeck(p, -v) / p.theta - p.sigma2 * v
    assert np.isclose(vs.braking_mu_uniform(p, -1.0, v), mu_point, rtol=1e-14)
    assert np.isclose(vs.steady_state_mu(p, vs.QuarticLoad(), v, 0.0, R), mu_point, rtol=1e-14)


def test_z_ss_solves_the_steady_pde(p):
    # |r w| dz/dzeta = v_r - theta sigma0 |v_r| / g z  (eq. 14 with dz/dt = 0)
    v, om = 20.0, 0.8 * 20.0 / R
    zeta = jnp.linspace(0.0, p.L, 7)
    dz = jax.vmap(jax.grad(lambda x: vs.z_ss(p, x, v, om, R)))(zeta)
    v_r = R * om - v
    rhs = v_r - vs.decay_rate(p, v_r) * vs.z_ss(p, zeta, v, om, R)
    np.testing.assert_allclose(abs(R * om) * dz, rhs, rtol=1e-10, atol=1e-12)
    assert vs.z_ss(p, 0.0, v, om, R) == 0.0


def test_road_condition_scales_saturated_friction(p):
    # at a locked wheel the force is exactly g / theta (docs/parameters.md: "scales roughly as g/theta")
    for theta in [1.0, 1.25, 2.5]:
        q = eqx.tree_at(lambda m: m.theta, p, jnp.asarray(theta))
        assert np.isclose(vs.braking_mu_uniform(q, -1.0, 20.0) + q.sigma2 * 20.0,
                          -vs.stribeck(q, -20.0) / theta, rtol=1e-14)


# --- distributed PDE -------------------------------------------------------------------


@pytest.mark.parametrize("load", [vs.UniformLoad(), vs.QuarticLoad(), vs.TrapezoidalLoad()],
                         ids=["uniform", "quartic", "trapezoidal"])
def test_pde_run_to_steady_state_matches_eqs_15_to_19(p, load):
    """Time-integrate eq. 14 from rest at constant inputs; compare profile and force."""
    model = vs.DistributedLuGre(p, load, n=32)
    # braking at three speeds, driving at two
    cases = [(10.0, -0.05), (20.0, -0.2), (30.0, -0.5), (20.0, 0.1), (5.0, 0.4)]
    vv = jnp.array([v if s < 0 else v * (1 - s) for v, s in cases])
    om = jnp.array([v * (1 + s) / R if s < 0 else v / R for v, s in cases])

    @jax.jit
    @jax.vmap
    def run(v, w):
        sol = vs.simulate_tire(model, jnp.array([0.0, 0.4]), v, w, R, rtol=1e-10, atol=1e-12)
        return sol.state[-1], sol.mu[-1]

    z_end, mu_end = run(vv, om)
    for i, (v, s) in enumerate(cases):
        prof = vs.z_ss(p, model.nodes, vv[i], om[i], R)
        np.testing.assert_allclose(z_end[i], prof, rtol=1e-4, atol=1e-4 * float(jnp.max(abs(prof))))
        mu_cf = vs.steady_state_mu(p, load, vv[i], om[i], R)
        assert abs(mu_end[i] / mu_cf - 1) < 1e-4, (v, s, mu_end[i], mu_cf)
        if isinstance(load, vs.AbstractPolynomialLoad) and load.coefficients.shape[0] == 1:
            cf = vs.braking_mu_uniform(p, s, v) if s < 0 else vs.driving_mu_uniform(p, s, om[i], R)
            assert abs(mu_end[i] / cf - 1) < 1e-4


def test_locked_wheel_distributed_collapses_to_point_model(p):
    """omega = 0: no transport, every bristle obeys eq. 8, and F equals the point model's."""
    ts = jnp.linspace(0.0, 0.3, 31)
    v = 20.0 - 30.0 * ts  # decelerating through v = 0 with the wheel locked
    dist = vs.simulate_tire(vs.DistributedLuGre(p, vs.QuarticLoad(), n=16), ts, v, 0.0, R)
    point = vs.simulate_tire(vs.PointLuGre(p), ts, v, 0.0, R)
    np.testing.assert_allclose(dist.mu, point.mu, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(dist.state, np.repeat(np.asarray(point.state)[:, None], 17, axis=1),
                               rtol=1e-7, atol=1e-12)


# --- lumped model ------------------------------------------------------------------------


def test_lumped_with_exact_kappa_reproduces_distributed_transient(p):
    """Eq. 22 with kappa(t) from eq. 24 evaluated on the PDE state is the PDE's own average."""
    import diffrax as dfx

    dist = vs.DistributedLuGre(p, vs.QuarticLoad(), n=32)
    lumped = vs.LumpedLuGre(p)
    v_fn = lambda t: 25.0 - 5.0 * t
    om_fn = lambda t: (25.0 - 5.0 * t) * (1.0 - 0.3 * jnp.clip(t / 0.5, 0.0, 1.0)) / R  # ramp brake

    def field(t, y, args):
        z, zbar = y
        v, w = v_fn(t), om_fn(t)
        return dist.dynamics(z, v, w, R), lumped.dynamics(zbar, v, w, R, kappa=dist.kappa(z))

    ts = jnp.linspace(0.0, 1.0, 101)
    sol = dfx.diffeqsolve(dfx.ODETerm(field), dfx.Kvaerno5(), 0.0, 1.0, None,
                          (dist.init_state(), jnp.zeros(())), saveat=dfx.SaveAt(ts=ts),
                          stepsize_controller=dfx.PIDController(rtol=1e-10, atol=1e-12))
    z, zbar = sol.ys
    mu_d = jax.vmap(lambda zz, t: dist.mu(zz, v_fn(t), om_fn(t), R))(z, ts)
    mu_l = jax.vmap(lambda zb, zz, t: lumped.mu(zb, v_fn(t), om_fn(t), R, kappa=dist.kappa(zz)))(
        zbar, z, ts)
    np.testing.assert_allclose(zbar, jax.vmap(dist.mean_deflection)(z), rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(mu_l, mu_d, rtol=1e-6, atol=1e-6)
    assert float(jnp.max(jnp.abs(mu_d))) > 0.5  # the transient is a real one


def test_constant_kappa0_matching_steady_state_lies_in_report_range(p):
    """kappa0* making eq. 22's steady state equal eq. 17's, uniform load: 2 at small slip, 1 at
    large (report eq. 25: kappa0 in [1, 2])."""
    v = 20.0
    vals = []
    for s in [-1e-4, -0.01, -0.1, -0.5, -0.95]:
        om = v * (1 + s) / R
        mu_ss = vs.steady_state_mu(p, vs.UniformLoad(), v, om, R)
        v_r = R * om - v
        zbar = (mu_ss - p.sigma2 * v_r) / p.sigma0
        kappa0 = p.L * (v_r / zbar - vs.decay_rate(p, v_r)) / abs(R * om)
        mu_l = vs.LumpedLuGre(p, kappa0=kappa0).steady_state_mu(v, om, R)
        assert np.isclose(mu_l, mu_ss, rtol=1e-10)
        vals.append(float(kappa0))
    assert abs(vals[0] - 2.0) < 1e-3 and 1.0 < vals[-1] < 1.1
    assert all(a >= b for a, b in zip(vals, vals[1:]))  # monotone from 2 down to 1


# --- gradients ----------------------------------------------------------------------------


SINGULAR_POINTS = {
    "standstill": (0.0, 0.0),
    "locked": (20.0, 0.0),
    "zero_slip": (R * 64.0, 64.0),  # v_r = r omega - v is exactly 0, fused multiply-add or not
    "slip_plus_one": (0.0, 10.0),  # spinning on the spot, s_d = 1
    "braking_minus_one": (12.0, 0.0),
}
# Where |v_r| (v_r = r omega - v) or the transport speed |r omega| of eqs. 14, 22 passes
# through 0, the one-sided slopes differ: (point, coordinate) -> models with a kink there.
TRANSIENT_KINKS = {
    ("standstill", "v"): {"point", "lumped", "distributed"},
    ("standstill", "omega"): {"point", "lumped", "distributed"},
    ("zero_slip", "v"): {"point", "lumped", "distributed"},
    ("zero_slip", "omega"): {"point", "lumped", "distributed"},
    ("locked", "omega"): {"lumped", "distributed"},
    ("braking_minus_one", "omega"): {"lumped", "distributed"},
}


def _transient_models(p):
    return {"point": vs.PointLuGre(p), "lumped": vs.LumpedLuGre(p, kappa0=1.5),
            "distributed": vs.DistributedLuGre(p, vs.QuarticLoad(), n=8)}


@pytest.mark.parametrize("name", ["point", "lumped", "distributed"])
def test_gradients_at_singular_points_are_the_one_sided_slopes(p, name):
    """d/d(v, omega, parameters) of sum(dz/dt) + F/F_n at standstill, lock, zero slip and
    spin. In (v, omega): where the model is differentiable the gradient equals the
    one-sided slopes (which agree); at a kink of |v_r| or |r omega| it is their mean (the
    double-where convention sgn(0) = 0), and the slopes differ. In the parameters
    (smooth there): central differences."""
    model = _transient_models(p)[name]
    z = model.init_state() + 1e-3

    @jax.jit
    def f(y):  # y = (v, omega, the LuGre parameters)
        m = eqx.tree_at(lambda mm: [getattr(mm.params, n) for n in PARAM_FIELDS], model,
                        list(y[2:]))
        return jnp.sum(m.dynamics(z, y[0], y[1], R)) + m.mu(z, y[0], y[1], R)

    grad = jax.jit(jax.grad(f))
    q = np.array([float(getattr(p, n)) for n in PARAM_FIELDS])
    for point, (v0, om0) in SINGULAR_POINTS.items():
        y = np.concatenate([[v0, om0], q])
        g = np.asarray(grad(jnp.asarray(y)))
        for i, coord in enumerate(("v", "omega")):
            left, right = one_sided_slopes(f, y, np.eye(y.size)[i])
            kink = name in TRANSIENT_KINKS.get((point, coord), ())
            where = (name, point, coord)
            assert (abs(left - right) > 1e-3 * abs(left + right)) == kink, (where, left, right)
            np.testing.assert_allclose(g[i], (left + right) / 2, rtol=1e-6, err_msg=str(where))
        np.testing.assert_allclose(g[2:], fd_grad(lambda qq, v0=v0, om0=om0: f(
            jnp.concatenate([jnp.array([v0, om0]), qq])), q), rtol=1e-5, atol=1e-9,
            err_msg=f"{name} at {point}: parameter gradient")


def test_uniform_lumped_derivatives_near_lock_tend_to_the_locked_ones(p):
    """As the wheel nears lock, k = theta sigma0 |v_r| L/(g |omega r|) grows without bound
    and the uniform-load lumped tire's decay rate tends to the point model's: its
    derivatives in (v, omega) settle to their limit (evaluated as the sliding rate plus a
    bounded excess; as the quotient |omega r|/(L psi(k)), d/d omega was 3.4 at 1e-15 m/s
    and -2.7e15 at 1e-30 m/s, against 0.94)."""
    from vehsim.tire.uniform_lumped import UniformLumpedLuGre

    tire = UniformLumpedLuGre(p)
    grad = jax.jit(jax.grad(lambda v, om: tire.dynamics(0.01, v, om, R), argnums=(0, 1)))
    near = np.asarray(grad(20.0, 1e-6 / R))
    for c in (1e-9, 1e-12, 1e-15, 1e-30, 1e-100):
        np.testing.assert_allclose(np.asarray(grad(20.0, c / R)), near, rtol=1e-5,
                                   err_msg=f"|omega r| = {c} m/s")


def test_steady_state_derivatives_near_lock_tend_to_the_locked_ones(p):
    """eq. 17 for any load and the profile of eq. 15 towards lock: v_r L/c grows without
    bound while the profile's factor falls as 1/k; regrouped for k > 1, the derivatives in
    (v, omega) settle to the locked wheel's (the product lost its digits below about 1e-12
    m/s of rolling speed)."""
    from vehsim.tire.steady_state import steady_state_mu, z_ss

    load = vs.QuarticLoad()
    fs = {"mu": lambda v, om: steady_state_mu(p, load, v, om, R),
          "z": lambda v, om: z_ss(p, 0.3 * p.L, v, om, R)}
    for name, f in fs.items():
        grad = jax.jit(jax.grad(f, argnums=(0, 1)))
        near = np.asarray(grad(20.0, 1e-6 / R))
        assert np.all(np.abs(near) > 0)
        for c in (1e-9, 1e-12, 1e-15, 1e-30, 1e-100):
            np.testing.assert_allclose(np.asarray(grad(20.0, c / R)), near, rtol=1e-4,
                                       err_msg=f"{name} at |omega r| = {c} m/s")
        # the two groupings meet at k = 1 without a jump (both exact there)
        from vehsim.tire.steady_state import _rolling_terms

        lo, hi = 1.0 / R, 20.0 / R  # k > 1 at lo, < 1 at hi (a braking wheel at 20 m/s)
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if float(_rolling_terms(p, 20.0, mid, R)[4]) > 1.0 else (lo, mid)
        assert abs(float(f(20.0, lo)) - float(f(20.0, hi))) < 1e-12 * abs(float(f(20.0, lo)))


def test_steady_state_gradients_at_singular_points_are_the_one_sided_slopes(p):
    """eq. 17 (quartic load) and the profile z_ss of eq. 15 at the singular points: the
    gradient is the mean of the one-sided slopes (they differ only at the locked wheel's
    kink of |omega|); eq. 19 at s = -1 (kink) and s = 0, driving at s = 0 and 1 the same.
    At standstill the steady state has no limit (it depends on the slip of the approach),
    and the gradient is the viscous term's alone."""
    forms = {
        "steady_state_mu": jax.jit(lambda x: vs.steady_state_mu(p, vs.QuarticLoad(), x[0],
                                                                x[1], R)),
        "z_ss": jax.jit(lambda x: vs.z_ss(p, 0.1, x[0], x[1], R)),
    }
    for name, f in forms.items():
        grad = jax.jit(jax.grad(f))
        for point, x in SINGULAR_POINTS.items():
            g = np.asarray(grad(jnp.asarray(x)))
            if point == "standstill":
                # locked (omega = 0) and free-rolling (r omega = v) approaches differ by O(1)
                assert abs(float(f(jnp.array([1e-9, 0.0])) - f(jnp.array([1e-9, 1e-9 / R])))
                           ) > 1e-3 * (name == "z_ss") + 0.5 * (name != "z_ss")
                viscous = [-p.sigma2, p.sigma2 * R] if name == "steady_state_mu" else [0, 0]
                np.testing.assert_allclose(g, viscous, rtol=1e-12, atol=0)
                continue
            for i in range(2):
                left, right = one_sided_slopes(f, x, np.eye(2)[i])
                np.testing.assert_allclose(g[i], (left + right) / 2, rtol=1e-5,
                                           err_msg=f"{name} at {point}, coordinate {i}")
    braking = jax.jit(lambda s: vs.braking_mu_uniform(p, s, 20.0))
    driving = jax.jit(lambda s: vs.driving_mu_uniform(p, s, 30.0, R))
    for fn, s, kink in [(braking, -1.0, True), (braking, 0.0, False), (driving, 0.0, False),
                        (driving, 1.0, False)]:
        left, right = one_sided_slopes(fn, s, 1.0)
        assert (abs(left - right) > 1e-3 * abs(left + right)) == kink, (s, left, right)
        np.testing.assert_allclose(jax.jit(jax.grad(fn))(s), (left + right) / 2, rtol=1e-6)


def test_gradient_at_zero_slip_is_the_true_slope(p):
    # d mu_ss / d s at s = 0 (uniform, braking) = sigma0 L / 2 + sigma2 v (linearise eq. 19)
    v = 20.0
    g = jax.grad(lambda s: vs.braking_mu_uniform(p, s, v))(0.0)
    assert np.isclose(g, p.sigma0 * p.L / 2 + p.sigma2 * v, rtol=1e-10)
    g2 = jax.grad(lambda w: vs.steady_state_mu(p, vs.UniformLoad(), v, w, R))(v / R)
    assert np.isclose(g2, (p.sigma0 * p.L / 2 + p.sigma2 * v) * R / v, rtol=1e-8)


def test_transient_derivative_from_zero_slip_matches_central_differences(p):
    """A lumped tire rolling at zero slip stays undeflected: the motion's error is zero and
    the step-size control alone would take steps of the whole span, through which the
    derivative (which excites the bristles) is 15 % off. With the default step ceiling both
    modes equal central differences."""
    import diffrax as dfx

    tire, ts = vs.LumpedLuGre(p), jnp.linspace(0.0, 0.2, 11)

    def mu(x, adjoint=None, **unbounded):  # x = (vx, omega r, sigma0 scale)
        t = eqx.tree_at(lambda t: t.params.sigma0, tire, tire.params.sigma0 * x[2])
        return vs.simulate_tire(t, ts, x[0], x[1] / R, R, adjoint=adjoint, **unbounded).mu

    x = jnp.array([20.0, 20.0, 1.0])
    f = jax.jit(mu)
    cd = np.stack([(np.asarray(f(x + e)) - np.asarray(f(x - e))) / 2e-6
                   for e in 1e-6 * jnp.eye(3)], axis=-1)
    scale = np.max(np.abs(cd))
    assert scale > 1.0
    for jac in (jax.jacfwd(lambda x: mu(x, adjoint=dfx.ForwardMode())), jax.jacrev(mu)):
        np.testing.assert_allclose(np.asarray(jax.jit(jac)(x)), cd, atol=1e-4 * scale)
    unbounded = jax.jit(jax.jacfwd(lambda x: mu(x, dfx.ForwardMode(), dtmax=None)))(x)
    assert np.max(np.abs(np.asarray(unbounded) - cd)) > 0.05 * scale


def test_parameter_gradients_match_finite_differences(p):
    v, om = 18.0, 0.85 * 18.0 / R
    point = vs.PointLuGre(p)
    module_grad_matches_fd(lambda q: vs.PointLuGre(q).mu(jnp.asarray(2e-3), v, om, R), p,
                           [f for f in PARAM_FIELDS if f != "L"])
    module_grad_matches_fd(lambda q: vs.LumpedLuGre(q, 1.3).mu(jnp.asarray(2e-3), v, om, R), p,
                           PARAM_FIELDS)
    module_grad_matches_fd(lambda q: vs.steady_state_mu(q, vs.QuarticLoad(), v, om, R), p,
                           PARAM_FIELDS)
    module_grad_matches_fd(lambda q: vs.braking_mu_uniform(q, -0.3, v), p, PARAM_FIELDS)
    ts = jnp.linspace(0.0, 0.2, 5)
    module_grad_matches_fd(
        lambda q: vs.simulate_tire(eqx.tree_at(lambda m: m.params, point, q), ts, v, om, R,
                                   rtol=1e-11, atol=1e-13).mu[-1],
        p, ["sigma0", "sigma1", "mu_s", "v_s"], rtol=1e-4)
    assert_grad_matches_fd(lambda k: vs.LumpedLuGre(p, k).steady_state_mu(v, om, R),
                           jnp.asarray(1.4))


# --- batching, recompiles, validation --------------------------------------------------


def test_vmap_over_parameter_sets_equals_loop(p):
    batch = jax.tree_util.tree_map(lambda x: x * jnp.linspace(0.9, 1.1, 4), p)
    batch = eqx.tree_at(lambda q: q.mu_s, batch, batch.mu_c + 0.5)
    ts = jnp.linspace(0.0, 0.5, 6)

    def run(q):
        return vs.simulate_tire(vs.LumpedLuGre(q, 1.5), ts, 20.0, 0.8 * 20.0 / R, R).mu

    batched = jax.jit(jax.vmap(run))(batch)
    run_one = jax.jit(run)
    for i in range(4):
        qi = jax.tree_util.tree_map(lambda x: x[i], batch)
        np.testing.assert_allclose(batched[i], run_one(qi), rtol=1e-12)
    ss = jax.vmap(lambda q: vs.steady_state_mu(q, vs.QuarticLoad(), 20.0, 50.0, R))(batch)
    for i in range(4):
        qi = jax.tree_util.tree_map(lambda x: x[i], batch)
        assert np.isclose(ss[i], vs.steady_state_mu(qi, vs.QuarticLoad(), 20.0, 50.0, R),
                          rtol=1e-14)


def test_new_parameter_values_do_not_recompile(p):
    @jax.jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def force(model, z, v, om):
        return model.mu(z, v, om, R) + jnp.sum(model.dynamics(z, v, om, R))

    for scale in [1.0, 1.1, 1.2]:
        q = jax.tree_util.tree_map(lambda x: x * scale, p)
        model = vs.DistributedLuGre(q, vs.QuarticLoad(), n=8)
        force(model, model.init_state() + 1e-3, 20.0 * scale, 60.0)


@pytest.mark.parametrize(
    "field,value,match",
    [("mu_s", 0.5, "mu_c <= mu_s"), ("L", 0.0, "L"), ("L", -0.1, "L"), ("sigma0", 0.0, "sigma0"),
     ("sigma0", jnp.nan, "sigma0"), ("v_s", -1.0, "v_s"), ("sigma1", -0.1, "sigma1"),
     ("theta", jnp.inf, "theta")],
)
def test_bad_parameters_raise_naming_the_field(p, field, value, match):
    kw = {f: getattr(p, f) for f in PARAM_FIELDS}
    kw[field] = value
    with pytest.raises(ValueError, match=match):
        vs.LuGreParams(**kw)


def test_bad_model_arguments_raise():
    with pytest.raises(ValueError, match="kappa0"):
        vs.LumpedLuGre(vs.params.table3(), kappa0=-1.0)
    with pytest.raises(ValueError, match="n"):
        vs.DistributedLuGre(vs.params.table3(), n=2)
    with pytest.raises(ValueError, match="unknown preset"):
        vs.preset("nope")


def test_presets_carry_published_values():
    t3 = vs.preset("table3")
    assert (float(t3.sigma0), float(t3.sigma2), float(t3.mu_c), float(t3.mu_s), float(t3.v_s),
            float(t3.L), float(t3.alpha)) == (181.54, 0.0018, 0.8, 1.55, 6.57, 0.2, 0.5)
    c = vs.preset("cdc1999")
    assert (float(c.sigma0), float(c.sigma1), float(c.mu_c), float(c.mu_s), float(c.v_s),
            float(c.L)) == (40.0, 4.9487, 0.5, 0.9, 12.5, 0.25)
