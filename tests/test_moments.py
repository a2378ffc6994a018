"""Method of moments (eqs. 39-48) against the fine-grid distributed PDE (eqs. 31-34)."""

import math

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad

from vehsim.params import lugre2d_bakker1987
from vehsim.tire.distributed2d import DistributedLuGre2D, steady_state_mu_2d
from vehsim.tire.load import (
    PolynomialLoad,
    QuarticLoad,
    TabulatedLoad,
    TrapezoidalLoad,
    UniformLoad,
)
from vehsim.tire.lugre2d import decay_rates
from vehsim.tire.moments import (
    MomentLuGre2D,
    decay_integrals,
    moments_step_response,
    piecewise_coefficients,
    simulate_moments_delay,
    simulate_moments_history,
)
from vehsim.tire.transient import simulate_tire


R, FZ, V = 0.3, 4000.0, 20.0
TS = jnp.linspace(0.0, 0.03, 61)  # 3 patch transit times at 20 m/s, L = 0.2 m
# Uniform load padded to degree 4 so that it shares a compiled solve with the quartic.
LOADS = {
    "uniform": PolynomialLoad(jnp.array([1.0, 0.0, 0.0, 0.0, 0.0])),
    "trapezoidal": TrapezoidalLoad(0.25),
    "quartic": QuarticLoad(),
}


# one worker for the module: the transients fixture (PDE at n = 64) is computed once
pytestmark = pytest.mark.xdist_group("moments")

def _inputs(alpha_deg, kappa, ramp=0.0):
    """Slip angle stepped (ramp = 0) or ramped linearly over `ramp` seconds to `alpha_deg`."""
    a = jnp.deg2rad(alpha_deg)
    ramp = jnp.asarray(ramp, dtype=float)

    def angle(t):
        frac = jnp.clip(t / jnp.where(ramp > 0, ramp, 1.0), 0.0, 1.0)
        return a * jnp.where(ramp > 0, frac, 1.0)

    return (lambda t: V * jnp.cos(angle(t)), lambda t: -V * jnp.sin(angle(t)),
            lambda t: V * jnp.cos(angle(t)) * (1.0 + kappa) / R)


@eqx.filter_jit
def _run(model, alpha_deg, kappa, ramp, rtol, exact=False):
    # The online moment right-hand side has kinks where the travelled distance passes a piece
    # edge (cases 1 -> 2 of the boundary closure): a tight tolerance keeps the step control
    # honest.
    vx, vy, om = _inputs(alpha_deg, kappa, ramp)
    options = dict(solver=dfx.Tsit5(), rtol=rtol, atol=1e-2 * rtol)
    if exact:
        return simulate_moments_delay(model, TS, vx, vy, om, R, FZ, **options).forces
    return simulate_tire(model, TS, vx, om, R, vy=vy, Fz=FZ, **options).forces


@pytest.fixture(scope="module")
def transients():
    p = lugre2d_bakker1987()
    out = {}
    for name, load in LOADS.items():
        mom, pde = MomentLuGre2D(p, load), DistributedLuGre2D(p, load, n=64)
        for alpha_deg, kappa, ramp in ((4.0, 0.05, 0.0), (15.0, -0.1, 0.0), (15.0, -0.1, 0.01)):
            args = (jnp.asarray(alpha_deg), jnp.asarray(kappa), jnp.asarray(ramp))
            out[name, alpha_deg, ramp] = (
                np.asarray(_run(mom, *args, 1e-12)) if ramp == 0.0 else None,
                np.asarray(_run(pde, *args, 1e-8)),
                np.asarray(_run(mom, *args, 1e-8, exact=True)),
                tuple(f(0.0) for f in _inputs(alpha_deg, kappa)),
            )
    return p, out


@pytest.mark.parametrize("name", list(LOADS))
def test_moments_match_fine_grid_pde_along_transient(transients, name):
    """Step in slip from an undeflected patch (the transients of Fig. 17): F_x, F_y, M_z agree
    to 1e-3 relative to each signal's peak, at every save time."""
    _, out = transients
    for alpha_deg in (4.0, 15.0):
        mom, pde, exact, _ = out[name, alpha_deg, 0.0]
        for m in (mom, exact):  # both closures are exact for a step
            err = np.max(np.abs(m - pde), axis=0) / np.max(np.abs(pde), axis=0)
            assert np.all(err < 1e-3), (name, alpha_deg, err)
        # The transient is a real transient: forces change by a large fraction after t = 0.
        assert np.all(np.abs(pde[-1] - pde[1]) > 0.05 * np.abs(pde[-1]))


@pytest.mark.parametrize("name", list(LOADS))
def test_exact_moments_match_pde_along_slip_ramp(transients, name):
    """Slip angle ramped over one transit time (10 ms), so the inputs change while tread
    crosses the patch: with the delay-state closure (`simulate_moments_delay`) the moments still
    reproduce the PDE's F_x, F_y, M_z to 1e-3 of each signal's peak at every save time."""
    _, out = transients
    _, pde, exact, _ = out[name, 15.0, 0.01]
    err = np.max(np.abs(exact - pde), axis=0) / np.max(np.abs(pde), axis=0)
    assert np.all(err < 1e-3), (name, err)
    # and the ramp differs from the step: the closure is doing work
    step = out[name, 15.0, 0.0][1]
    assert np.max(np.abs(step - pde)[:, 1]) > 0.1 * np.max(np.abs(pde[:, 1]))


@pytest.mark.parametrize("name", list(LOADS))
def test_moments_reach_closed_form_steady_state(transients, name):
    """After three transit times the step response is exactly steady (characteristics)."""
    p, out = transients
    for alpha_deg in (4.0, 15.0):
        mom, _, _, (vx, vy, om) = out[name, alpha_deg, 0.0]
        v_r = jnp.stack([om * R - vx, -vy])
        ss = np.asarray(jax.jit(steady_state_mu_2d)(p, LOADS[name], v_r, om * R)) * FZ
        ss[2] *= p.L
        np.testing.assert_allclose(mom[-1], ss, rtol=1e-6)


def test_densities_share_the_sliding_steady_state():
    """Report 2.4: the densities reach the same steady state. Precisely: for any load q the
    steady force is the sliding value sigma0 v_r / C0 minus a leading-edge-layer term,
    |F/F_n - sigma0 v_r/C0| = sigma0 |v_r|/C0 int e^{-k xi} q <= sigma0 |v_r|/C0 max(q)/k,
    with k = C0 L / |omega r|; equality of the densities is exact for a locked wheel
    (k = inf) and holds to O(1/k) while rolling (a few per cent at large slip)."""
    p = lugre2d_bakker1987()

    steady = jax.jit(steady_state_mu_2d)

    v_r = jnp.array([-15.0, 4.0])
    locked = [np.asarray(steady(p, load, v_r, jnp.zeros(())))[:2]
              for load in LOADS.values()]
    np.testing.assert_allclose(locked[1], locked[0], rtol=1e-12)
    np.testing.assert_allclose(locked[2], locked[0], rtol=1e-12)
    for v_r, c in ((jnp.array([-2.0, 5.0]), 18.0), (jnp.array([0.5, 1.0]), 20.0)):
        C0 = np.asarray(decay_rates(p, v_r))
        k = C0 * float(p.L) / c
        sliding = np.asarray(p.sigma0 * v_r) / C0
        uniform = np.asarray(steady(p, LOADS["uniform"], v_r, jnp.asarray(c)))[:2]
        np.testing.assert_allclose(uniform, sliding * (1 - (1 - np.exp(-k)) / k), rtol=1e-10)
        for load, qmax in ((LOADS["trapezoidal"], 1 / 0.75), (LOADS["quartic"], 1.25)):
            mu = np.asarray(steady(p, load, v_r, jnp.asarray(c)))[:2]
            assert np.all(np.abs(mu - sliding) <= np.abs(sliding) * qmax / k)
            assert np.all(np.sign(mu) == np.sign(sliding))


def _basis_moments(mom, f, nq=40):
    """Moments of the function f(xi) in `mom.basis` by Gauss quadrature per piece, (P, K)."""
    from numpy.polynomial import legendre as npleg

    gx, gw = npleg.leggauss(nq)
    K = mom.n_moments
    out = []
    for a, b in zip(np.asarray(mom.edges[:-1]), np.asarray(mom.edges[1:])):
        h = b - a
        x, w = 0.5 * (gx + 1), 0.5 * gw
        xi = a + h * x
        if mom.basis == "monomial":
            phi = np.stack([h * xi**k for k in range(K)])
        else:
            phi = np.stack([npleg.legval(2 * x - 1, np.eye(K)[k]) for k in range(K)])
        out.append(phi @ (w * f(xi)))
    return np.stack(out)


@pytest.mark.parametrize("basis", ["monomial", "legendre"])
@pytest.mark.parametrize("load", [QuarticLoad(), TrapezoidalLoad(0.3)])
def test_moments_derivative_matches_pde_moments(basis, load):
    """At an arbitrary smooth state with known edge values, eq. 41 (in either basis) equals
    the moments of the PDE right-hand side (integration by parts done right), and the forces
    and moment of eqs. 46, 48 equal the PDE's quadrature of eqs. 32-33 at that state."""
    p = lugre2d_bakker1987()
    mom = MomentLuGre2D(p, load, basis=basis)
    pde = DistributedLuGre2D(p, load, n=40)
    from vehsim.tire.distributed import interpolation_matrix

    xi = np.asarray(pde.nodes / p.L)
    z = jnp.asarray(np.stack([0.01 * xi * (1 - 0.3 * xi), -0.02 * np.sin(2 * xi)]))
    v_r, c = jnp.array([0.8, -1.2]), jnp.asarray(19.0)
    zdot = pde.derivative(z, v_r, c)

    def interp(values):
        return lambda x: interpolation_matrix(pde.n, x) @ np.asarray(values)

    m = jnp.asarray(np.stack([_basis_moments(mom, interp(z[i])) for i in range(2)]))
    # the edge states carry the PDE's own deflections at the piece edges
    z_edge = jnp.asarray(np.stack([interp(z[i])(np.asarray(mom.edges[1:])) for i in range(2)]))
    state = (m, z_edge, jnp.asarray(5.0))
    m_dot = mom.derivative(state, v_r, c)[0]
    expected = np.stack([_basis_moments(mom, interp(zdot[i])) for i in range(2)])
    scale = np.max(np.abs(expected))
    np.testing.assert_allclose(m_dot, expected, rtol=1e-8, atol=1e-11 * scale)
    # a smooth state (not a polynomial): the n = 40 PDE quadrature is exact to rounding
    np.testing.assert_allclose(mom.mu(state, v_r, c), pde.mu(z, v_r, c), rtol=1e-9)


def test_legendre_and_monomial_bases_agree_along_transient(transients):
    """The same moment system in two bases: a slip step with the report's monomial moments
    and with per-piece Legendre moments gives the same F_x, F_y, M_z to solver tolerance."""
    p, out = transients
    load = LOADS["trapezoidal"]
    mono = np.asarray(_run(MomentLuGre2D(p, load, basis="monomial"), jnp.asarray(15.0),
                           jnp.asarray(-0.1), jnp.asarray(0.0), 1e-12))
    leg = out["trapezoidal", 15.0, 0.0][0]
    np.testing.assert_allclose(leg, mono, rtol=0, atol=1e-6 * np.max(np.abs(mono)))


def test_derivative_slope_in_transport_speed_is_finite_towards_lock():
    """The edge equations' arrival term exp(-C0 L b / c) has a c-derivative that overflows
    below c ~ 1e-154 (NaN in reverse mode); below `TRANSPORT_FLOOR` both modes give the
    slope at c = 1e-20, where the term's contribution has long vanished."""
    p = lugre2d_bakker1987()
    mom = MomentLuGre2D(p, QuarticLoad())
    m, z_edge, _ = mom.init_state(jnp.array([1e-3, -2e-3]))
    state = (m, z_edge, jnp.asarray(0.5))
    v_r = jnp.array([-10.0, 2.0])

    def total(c):
        return sum(jnp.sum(x) for x in jax.tree_util.tree_leaves(mom.derivative(state, v_r, c)))

    peer = jax.jvp(total, (1e-20,), (1.0,))[1]
    assert np.isfinite(peer) and peer != 0.0
    for c in (1e-120, 1e-200):
        np.testing.assert_allclose([jax.grad(total)(c), jax.jvp(total, (c,), (1.0,))[1]],
                                   [peer, peer], rtol=1e-12)


def test_basis_is_checked():
    with pytest.raises(ValueError, match="MomentLuGre2D.basis"):
        MomentLuGre2D(lugre2d_bakker1987(), basis="chebyshev")


def test_piecewise_coefficients_reproduce_loads():
    xi = jnp.linspace(0.0, 1.0, 101)
    for load, degree in ((TrapezoidalLoad(0.3), None), (QuarticLoad(), None),
                         (TabulatedLoad([0.0, 0.2, 0.7, 1.0], [0.0, 1.0, 1.2, 0.0]), 1)):
        edges, coeffs = piecewise_coefficients(load, degree)
        piece = np.clip(np.searchsorted(np.asarray(edges), np.asarray(xi), side="right") - 1,
                        0, coeffs.shape[0] - 1)
        vals = [np.polyval(np.asarray(coeffs[j])[::-1], x) for j, x in zip(piece, np.asarray(xi))]
        np.testing.assert_allclose(vals, load.q(xi), atol=1e-12)
    with pytest.raises(ValueError, match="degree"):
        piecewise_coefficients(TabulatedLoad([0.0, 0.5, 1.0], [1.0, 2.0, 1.0]))


def test_moment_forces_gradient_in_ramp_matches_fd():
    """The trapezoid is differentiable in its ramp through the moment model."""
    from helpers import assert_grad_matches_fd

    p = lugre2d_bakker1987()
    v_r, c = jnp.array([1.0, 1.5]), jnp.asarray(20.0)

    @jax.jit
    def f(ramp):
        mom = MomentLuGre2D(p, TrapezoidalLoad(ramp))
        state = mom.init_state(jnp.array([1e-3, 2e-3]))
        return jnp.sum(mom.mu(state, v_r, c) * jnp.array([1.0, 1.0, 10.0]))

    assert_grad_matches_fd(f, jnp.asarray(0.3), rtol=1e-6)


def test_new_parameter_values_do_not_retrace():
    """Parameters and load are arrays: a new value reuses the compiled vector field."""

    @eqx.filter_jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def rhs(model, state, v_r, c):
        return model.derivative(state, v_r, c)

    p = lugre2d_bakker1987()
    for scale, ramp in ((1.0, 0.25), (1.3, 0.2), (0.7, 0.4)):
        q = eqx.tree_at(lambda t: t.sigma0, p, p.sigma0 * scale)
        model = MomentLuGre2D(q, TrapezoidalLoad(ramp))
        out = rhs(model, model.init_state(jnp.array([1e-3, 1e-3])), jnp.array([1.0, 2.0]),
                  jnp.asarray(20.0))
        assert np.all(np.isfinite(out[0]))


def test_exact_moments_gradient_matches_fd():
    """Gradient of F_y during a slip ramp with respect to the longitudinal slip (which moves
    both v_r and the transport speed, hence the entry times t_e of the exact closure) and to
    a scale on sigma0_y, against central differences."""
    from helpers import assert_grad_matches_fd

    p = lugre2d_bakker1987()
    ts = jnp.linspace(0.0, 0.012, 5)

    @jax.jit
    def fy(x):
        kappa, s0y = x[0], x[1]
        q = eqx.tree_at(lambda t: t.sigma0, p, p.sigma0.at[1].multiply(s0y))
        model = MomentLuGre2D(q, TrapezoidalLoad(0.25))
        sol = simulate_moments_delay(model, ts, *_inputs(6.0, kappa, 0.008), R, FZ, rtol=1e-11,
                               atol=1e-13)
        return sol.forces[-1, 1] / FZ + sol.forces[-1, 2] / FZ

    # eps = 1e-4: below it the adaptive solves' tolerance noise dominates the differences
    assert_grad_matches_fd(fy, jnp.array([0.05, 1.0]), rtol=1e-4, eps=1e-4)


def test_delay_and_history_closures_agree():
    """The two exact closures (`simulate_moments_delay`: entry times as ODE states, and the dense
    input history searched by Newton) are different computations of the same edge values:
    along a slip-angle ramp from a uniformly deflected patch (old tread leaving, which makes
    the edge values jump at the first passage) they give the same F_x, F_y, M_z."""
    p = lugre2d_bakker1987()
    model = MomentLuGre2D(p, TrapezoidalLoad(0.25))
    ts = jnp.linspace(0.0, 0.014, 15)
    z0 = jnp.array([2e-3, -1e-3])

    @eqx.filter_jit
    def run(simulate, z0):
        return simulate(model, ts, *_inputs(8.0, 0.03, 0.008), R, FZ, z0, rtol=1e-9,
                        atol=1e-11).forces

    delay = np.asarray(run(simulate_moments_delay, z0))
    history = np.asarray(run(simulate_moments_history, z0))
    peak = np.max(np.abs(history), axis=0)
    np.testing.assert_allclose(delay, history, rtol=0, atol=1e-6 * np.max(peak))
    # the initial deflection matters: the undeflected start differs by a lot
    undeflected = np.asarray(run(simulate_moments_delay, jnp.zeros(2)))
    assert np.all(np.max(np.abs(undeflected - delay), axis=0) > 0.05 * peak)
    with pytest.raises(TypeError, match="simulate_moments_history needs a MomentLuGre2D"):
        simulate_moments_history(DistributedLuGre2D(p, TrapezoidalLoad(0.25), n=4), ts, 20.0,
                                 0.0, 60.0, R, FZ)


def test_delay_closure_with_input_kink_at_loose_tolerance(transients):
    """Told where the inputs kink (the end of the slip-angle ramp), the delay closure lands
    steps there and where that tread reaches the piece edges, and the quartic (whose M_z
    amplifies edge errors ~1000x) reproduces the PDE to 1e-3 at rtol 1e-5."""
    p, out = transients
    _, pde, _, _ = out["quartic", 15.0, 0.01]
    forces = simulate_moments_delay(MomentLuGre2D(p, LOADS["quartic"]), TS,
                                    *_inputs(15.0, -0.1, 0.01), R, FZ, kinks=0.01, rtol=1e-5,
                                    atol=1e-7).forces
    err = np.max(np.abs(np.asarray(forces) - pde), axis=0) / np.max(np.abs(pde), axis=0)
    assert np.all(err < 1e-3), err


# --- The moment system after a slip step solved exactly (`moments_step_response`): against
# the moment ODE, the fine-grid PDE, the closed-form steady state, the point model of a
# locked wheel, and finite differences.


def _step(alpha_deg, kappa, v=20.0):
    a = np.deg2rad(alpha_deg)
    vx, vy = v * np.cos(a), -v * np.sin(a)
    return vx, vy, vx * (1.0 + kappa) / R


@eqx.filter_jit
def _response(model, vx, vy, omega, z0=None, ts=TS):
    return moments_step_response(model, ts, vx, vy, omega, R, FZ, z0).forces


def test_decay_integrals_match_quadrature():
    """I_j(x) = int_0^1 exp(-x u) u^j / j! du on both sides of the branch point x = 2, at 0
    and far out, for up to 11 terms."""
    xs = np.array([0.0, 1e-9, 0.3, 1.0, 1.999, 2.0, 2.001, 5.0, 40.0, 700.0, 1e4])
    got = np.asarray(jax.jit(decay_integrals, static_argnums=1)(jnp.asarray(xs), 11))
    for x, row in zip(xs, got):
        ref = [quad(lambda u: math.exp(-x * u) * u**j / math.factorial(j), 0, 1,
                    epsabs=0, epsrel=1e-13, limit=200)[0] for j in range(11)]
        np.testing.assert_allclose(row[:7], ref[:7], rtol=1e-12)
        np.testing.assert_allclose(row, ref, rtol=1e-9)  # j = 10 at x = 2: ~5 digits lost


def test_decay_integrals_gradient_matches_fd():
    from helpers import assert_grad_matches_fd

    for x in (0.0, 0.7, 2.0, 3.5, 60.0):
        assert_grad_matches_fd(lambda x: jnp.sum(decay_integrals(x, 7) * jnp.arange(1.0, 8.0)),
                               jnp.asarray(x), rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("name", list(LOADS))
def test_step_response_matches_moment_ode_and_pde(transients, name):
    """The exact solution equals the moment ODE integrated at rtol 1e-12 (online closure,
    exact for steps) to 1e-7 of each signal's peak, and the PDE (n = 64) to 1e-3."""
    p, out = transients
    for alpha_deg, kappa in ((4.0, 0.05), (15.0, -0.1)):
        ode, pde, _, _ = out[name, alpha_deg, 0.0]
        exact = np.asarray(_response(MomentLuGre2D(p, LOADS[name]), *_step(alpha_deg, kappa)))
        peak = np.max(np.abs(ode), axis=0)
        assert np.all(np.max(np.abs(exact - ode), axis=0) < 1e-7 * peak), (name, alpha_deg)
        assert np.all(np.max(np.abs(exact - pde), axis=0) < 1e-3 * peak), (name, alpha_deg)


@pytest.mark.parametrize("name", list(LOADS))
def test_step_response_is_the_steady_state_after_one_transit(name):
    """From t = L/|omega r| on, all tread on the patch entered after the step: the response is
    the closed-form steady state exactly (not asymptotically)."""
    p = lugre2d_bakker1987()
    vx, vy, om = _step(8.0, 0.08)
    transit = float(p.L) / (om * R)
    ts = jnp.linspace(0.0, 3 * transit, 31)
    forces = np.asarray(_response(MomentLuGre2D(p, LOADS[name]), vx, vy, om, ts=ts))
    v_r = jnp.array([om * R - vx, -vy])
    ss = np.asarray(steady_state_mu_2d(p, LOADS[name], v_r, om * R)) * FZ
    ss[2] *= float(p.L)
    after = np.asarray(ts) >= transit * (1 + 1e-12)
    np.testing.assert_allclose(forces[after], np.broadcast_to(ss, forces[after].shape),
                               rtol=1e-10)
    # ... and not before: the transient is still under way at half a transit
    assert np.all(np.abs(forces[np.asarray(ts) < 0.5 * transit][-1] - ss) > 1e-3 * np.abs(ss))


@pytest.mark.parametrize("basis", ["legendre", "monomial"])
def test_the_triangle_is_two_ramps_in_either_basis(basis):
    """The trapezoid of ramp 1/2 is the triangle: the moment model takes it as its two ramps
    (a flat piece of zero width divided the Legendre tables by its width: NaN), and its step
    response is the closed-form steady state after one transit."""
    p = lugre2d_bakker1987()
    model = MomentLuGre2D(p, TrapezoidalLoad(0.5), basis=basis)
    assert model.pieces == 2
    vx, vy, om = _step(8.0, 0.08)
    transit = float(p.L) / (om * R)
    ts = jnp.linspace(0.0, 2 * transit, 11)
    forces = np.asarray(_response(model, vx, vy, om, ts=ts))
    ss = np.asarray(steady_state_mu_2d(p, TrapezoidalLoad(0.5), jnp.array([om * R - vx, -vy]),
                                       om * R)) * FZ
    ss[2] *= float(p.L)
    np.testing.assert_allclose(forces[-1], ss, rtol=1e-10)


def test_step_response_from_deflected_patch_matches_delay_closure():
    """From a uniform initial deflection (old tread leaves over the first transit) the exact
    solution equals `simulate_moments_delay` (rtol 1e-11) to 1e-7 of the peaks, in
    the forces and in the moments themselves (the `state`, computed on the full tables while
    the forces take the load-contracted ones)."""
    p = lugre2d_bakker1987()
    model = MomentLuGre2D(p, TrapezoidalLoad(0.25))
    vx, vy, om = _step(6.0, 0.03)
    z0 = jnp.array([2e-3, -1e-3])
    exact_sol = eqx.filter_jit(moments_step_response)(model, TS, vx, vy, om, R, FZ, z0)
    ode_sol = eqx.filter_jit(simulate_moments_delay)(model, TS, vx, vy, om, R, FZ, z0,
                                                     rtol=1e-11, atol=1e-13)
    exact, ode = np.asarray(exact_sol.forces), np.asarray(ode_sol.forces)
    peak = np.max(np.abs(ode), axis=0)
    np.testing.assert_array_less(np.max(np.abs(exact - ode), axis=0), 1e-7 * peak)
    m_exact, m_ode = np.asarray(exact_sol.state), np.asarray(ode_sol.state)
    assert m_exact.shape == m_ode.shape == (len(TS), 2, model.pieces, model.n_moments)
    m_err = np.max(np.abs(m_exact - m_ode), axis=(0, 2, 3))  # per axis
    m_peak = np.max(np.abs(m_ode), axis=(0, 2, 3))
    np.testing.assert_array_less(m_err, 1e-7 * m_peak)
    assert np.all(np.max(np.abs(exact - np.asarray(_response(model, vx, vy, om))), axis=0)
                  > 0.02 * peak)  # the initial deflection matters


def test_locked_wheel_is_the_point_model():
    """omega = 0: no transport, every bristle obeys the point model (eqs. 26-30),
    z = v_r (1 - exp(-C0 t)) / C0, so F/F_n = sigma0 z + sigma1 dz/dt + sigma2 v_r for any
    load of unit mean; M_z = 0 for the symmetric quartic."""
    p = lugre2d_bakker1987()
    vx, vy = 15.0, -3.0
    v_r = np.array([-vx, -vy])
    C0 = np.asarray(decay_rates(p, jnp.asarray(v_r)))
    t = np.asarray(TS)[:, None]
    z = v_r * (1 - np.exp(-C0 * t)) / C0
    zdot = v_r * np.exp(-C0 * t)
    point = FZ * (np.asarray(p.sigma0) * z + np.asarray(p.sigma1) * zdot
                  + np.asarray(p.sigma2) * v_r)
    for name in ("trapezoidal", "quartic"):
        forces = np.asarray(_response(MomentLuGre2D(p, LOADS[name]), vx, vy, 0.0))
        np.testing.assert_allclose(forces[:, :2], point, rtol=1e-10)
        np.testing.assert_allclose(forces[:, 2], 0.0, atol=1e-9 * np.abs(point).max())


def test_step_response_gradients_match_fd():
    """F_y + M_z/L at t = 6 ms against (kappa, alpha, sigma0_y scale): at a slip step, at zero
    slip (v_r = 0, where C0 = 0 and the norm in C0 has a kink) and at a locked wheel."""
    from helpers import assert_grad_matches_fd

    p = lugre2d_bakker1987()
    ts = jnp.array([0.0, 0.004, 0.006])

    def f(x):
        kappa, alpha, s0y = x[0], x[1], x[2]
        q = eqx.tree_at(lambda t: t.sigma0, p, p.sigma0.at[1].multiply(s0y))
        vx, vy = 20.0 * jnp.cos(alpha), -20.0 * jnp.sin(alpha)
        out = moments_step_response(MomentLuGre2D(q, TrapezoidalLoad(0.25)), ts, vx, vy,
                                    vx * (1.0 + kappa) / R, R, FZ).forces
        return (out[-1, 1] + out[-1, 2] / q.L) / FZ

    for x in ([0.05, 0.1, 1.0], [0.0, 0.0, 1.0], [-1.0, 0.2, 1.2]):
        assert_grad_matches_fd(f, jnp.asarray(x), rtol=1e-5, atol=1e-9, eps=1e-6)


def test_step_response_checks_inputs_and_does_not_retrace():
    p = lugre2d_bakker1987()
    model = MomentLuGre2D(p, UniformLoad())
    with pytest.raises(TypeError, match="vy must be a scalar"):
        moments_step_response(model, TS, 20.0, lambda t: -t, 60.0, R, FZ)
    with pytest.raises(TypeError, match="omega must be a scalar"):
        moments_step_response(model, TS, 20.0, 0.0, jnp.ones(3), R, FZ)
    with pytest.raises(TypeError, match="needs a MomentLuGre2D"):
        moments_step_response(p, TS, 20.0, 0.0, 60.0, R, FZ)

    @eqx.filter_jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def run(model, vx, vy, om):
        return moments_step_response(model, TS, vx, vy, om, R, FZ).forces

    for scale, alpha in ((1.0, 3.0), (1.2, 9.0), (0.8, 0.0)):
        q = eqx.tree_at(lambda t: t.sigma0, p, p.sigma0 * scale)
        vx, vy, om = (jnp.asarray(v) for v in _step(alpha, 0.02))
        run(MomentLuGre2D(q, TrapezoidalLoad(0.2 + 0.01 * scale)), vx, vy, om)
