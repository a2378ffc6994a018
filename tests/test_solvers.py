"""ROS34PW2 (Rosenbrock-W on stiff blocks): order, stiffness, half-car agreement."""

import functools

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from vehsim import (
    RESULTS,
    ROS34PW2,
    HalfCar,
    IsotropicLumpedLuGre,
    rally_gravel,
    rally_gravel_tire,
    simulate,
)
from vehsim.params import cdc1999
from vehsim.solvers import solve_small
from vehsim.vehicle.maneuvers import brake_in_turn


def _vf(t, y, args):  # nonlinear, non-autonomous, y[2] mildly stiff
    return jnp.stack([-y[1] * y[0] + jnp.sin(t), y[0] - 0.5 * y[1] ** 2,
                      -50.0 * (y[2] - jnp.cos(t)) + y[0]])


Y0 = jnp.array([1.0, 0.5, 0.0])


def _fixed(solver, n):
    return dfx.diffeqsolve(dfx.ODETerm(_vf), solver, 0.0, 1.0, 1.0 / n, Y0,
                           max_steps=1000).ys[-1]


@functools.cache
def _reference():
    return dfx.diffeqsolve(dfx.ODETerm(_vf), dfx.Tsit5(), 0.0, 1.0, 1e-3, Y0,
                           stepsize_controller=dfx.PIDController(rtol=1e-13, atol=1e-13),
                           max_steps=100_000).ys[-1]


@pytest.mark.parametrize("blocks", [((0, 1, 2),), ((2,),), ((0,), (2,))])
def test_third_order_for_any_block_jacobian(blocks):
    # a W-method keeps its order whatever part of the Jacobian it uses
    ref = _reference()
    e = [float(jnp.max(jnp.abs(_fixed(ROS34PW2(blocks), n) - ref))) for n in (80, 160)]
    assert 2.7 < np.log2(e[0] / e[1]) < 3.3, e


def test_stiff_linear_block_takes_large_steps_and_matches_expm():
    # eigenvalues -1e4 (block {0, 1}) and -1 (state 2): exact solution expm(A t) y0
    A = jnp.array([[-5000.0, 4999.0, 0.3], [4999.0, -5000.0, 0.0], [0.2, 0.1, -1.0]])
    y0 = jnp.array([1.0, -0.5, 2.0])
    term = dfx.ODETerm(lambda t, y, args: A @ y)
    ctrl = dfx.PIDController(rtol=1e-6, atol=1e-6)
    sol = dfx.diffeqsolve(term, ROS34PW2(((0, 1),)), 0.0, 2.0, None, y0,
                          stepsize_controller=ctrl, saveat=dfx.SaveAt(ts=jnp.array([0.7, 2.0])),
                          max_steps=10_000)
    exact = np.stack([scipy.linalg.expm(np.asarray(A) * t) @ np.asarray(y0) for t in (0.7, 2.0)])
    np.testing.assert_allclose(sol.ys, exact, atol=2e-5)  # 0.7: dense (Hermite) output
    explicit = dfx.diffeqsolve(term, dfx.Tsit5(), 0.0, 2.0, None, y0, stepsize_controller=ctrl,
                               max_steps=100_000)
    assert int(sol.stats["num_steps"]) * 20 < int(explicit.stats["num_steps"])


def test_solve_small_matches_dense_solve():
    rng = np.random.default_rng(0)
    M = np.eye(4)[None] + 0.3 * rng.normal(size=(5, 4, 4))
    b = rng.normal(size=(5, 4))
    x = jax.jit(solve_small)(jnp.asarray(M), jnp.asarray(b))
    np.testing.assert_allclose(x, np.linalg.solve(M, b[..., None])[..., 0], rtol=1e-10,
                               atol=1e-12)


def test_half_car_with_lugre_tires_matches_tsit5():
    car = HalfCar(rally_gravel(), IsotropicLumpedLuGre(cdc1999(), kappa0=1.0))
    assert car.stiff_blocks == ((6, 12, 13), (7, 14, 15))
    u = brake_in_turn(0.04, 1200.0, t_brake=0.3, rise=0.2, t_steer=0.0)
    ts = jnp.linspace(0.0, 1.0, 6)
    kinks = jnp.array([0.2, 0.3, 0.5])
    y0 = car.init_state(vx=18.0)
    tol = lambda x: dict(rtol=jnp.asarray(x), atol=jnp.asarray(x))  # noqa: E731
    run = eqx.filter_jit(simulate)  # the two Tsit5 runs share one compilation
    ref = run(car, ts, u, y0, **tol(1e-11), jump_ts=kinks, max_steps=100_000)
    explicit = run(car, ts, u, y0, **tol(1e-6), jump_ts=kinks, max_steps=100_000)
    tr = run(car, ts, u, y0, solver=ROS34PW2(car.stiff_blocks), **tol(1e-6), jump_ts=kinks,
             max_steps=100_000)
    # each state to 1e-3 of its own peak over the run, in its own units (m, rad, m/s, rad/s,
    # and the friction states, ~7e-3 m: one atol for all would be 15 % of those)
    scale = np.max(np.abs(np.asarray(ref.states)), axis=0)
    for run_ in (tr, explicit):
        np.testing.assert_allclose(np.asarray(run_.states) / scale,
                                   np.asarray(ref.states) / scale, rtol=0, atol=1e-3)
    # not held to the explicit stability limit of the wheel-tire blocks
    assert int(tr.num_steps) * 2 < int(explicit.num_steps), (tr.num_steps, explicit.num_steps)


def test_stage_loop_has_the_unrolled_stages_values_in_a_smaller_program():
    """Stages 2-4 as one loop (the default) against `unroll_stages`: one step of the half car
    with dynamic tires from a braking, cornering state, equal to rounding; the loop's step
    compiles to a program at most 75 % of the unrolled one's (measured 60 %): the vector
    field and its linearisation once, not three times."""
    car = HalfCar(rally_gravel(), IsotropicLumpedLuGre(cdc1999(), kappa0=1.0))
    u = brake_in_turn(0.04, 1200.0, t_brake=0.0, rise=0.2, t_steer=0.0)
    y0 = car.init_state(vx=18.0).at[3].set(0.4).at[5].set(0.3)
    term = dfx.ODETerm(lambda t, y, args: car.f(y, u(t, y)))

    def step(solver, y):
        return solver.step(term, 0.1, 0.102, y, None, None, False)[:2]

    loop, unrolled = ROS34PW2(car.stiff_blocks), ROS34PW2(car.stiff_blocks, unroll_stages=True)
    out = step(loop, y0)
    for a, b in zip(out, step(unrolled, y0)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-15)
    assert float(jnp.max(jnp.abs(out[0] - y0))) > 1e-3  # the step moved the state

    def size(solver):  # XLA's optimised program, the calls inlined
        return len(jax.jit(lambda y: step(solver, y)[0]).lower(y0).compile().as_text())

    small, large = size(loop), size(unrolled)
    print("compiled characters: loop", small, "unrolled", large)
    assert small < 0.75 * large, (small, large)


def test_blocks_must_be_equal_length():
    with pytest.raises(ValueError, match="ROS34PW2.blocks"):
        ROS34PW2(((0, 1), (2,)))


@pytest.mark.slow  # ~35 s CPU: forward mode through the Rosenbrock step compiles slowly
def test_half_car_gradients_through_ros34pw2_match_finite_differences():
    # d(final state)/d(mass, brake torque, steering) through 40 fixed ROS34PW2 steps of
    # 10 ms (h |lambda| ~ 18 on the wheel-tire blocks: an explicit solver is unstable
    # there), forward mode vs central differences of the same discrete map, float64; one
    # compilation: the primal values for the differences come from the same jvp
    car = HalfCar(rally_gravel(), IsotropicLumpedLuGre(cdc1999(), kappa0=1.0))
    ts = jnp.array([0.0, 0.4])

    def final(x):
        m, brake, delta = x
        c = eqx.tree_at(lambda c: c.params.m, car, m)
        u = brake_in_turn(delta, brake, t_brake=0.1, rise=0.1, t_steer=0.0)
        tr = simulate(c, ts, u, c.init_state(vx=15.0), solver=ROS34PW2(car.stiff_blocks),
                      dt0=0.01, stepsize_controller=dfx.ConstantStepSize(), max_steps=64,
                      adjoint=dfx.ForwardMode())
        return tr.states[-1]

    value_and_tangent = jax.jit(lambda x, v: jax.jvp(final, (x,), (v,)))

    x0 = np.array([1450.0, 1200.0, 0.05])
    zero = jnp.zeros(3)
    jac = np.stack([np.asarray(value_and_tangent(jnp.asarray(x0), v)[1])
                    for v in jnp.eye(3)], axis=-1)  # (16, 3)
    eps = 1e-6 * np.abs(x0)
    fd = np.stack([(np.asarray(value_and_tangent(jnp.asarray(x0 + e), zero)[0])
                    - np.asarray(value_and_tangent(jnp.asarray(x0 - e), zero)[0])) / (2 * e[i])
                   for i, e in enumerate(np.diag(eps))], axis=-1)
    assert np.all(np.isfinite(jac))
    assert np.max(np.abs(jac)) > 1e-3  # braking and steering do move the final state
    scale = np.max(np.abs(fd), axis=0)  # per parameter
    np.testing.assert_allclose(jac / scale, fd / scale, atol=1e-6)


def _vf_a(t, y, a):  # _vf with a parameter in every rate (derivatives through args)
    return jnp.stack([-a * y[1] * y[0] + jnp.sin(t), y[0] - 0.5 * a * y[1] ** 2,
                      -50.0 * a * (y[2] - jnp.cos(t)) + y[0]])


def _one_step(frozen, h, blocks=((2,),)):
    solver = ROS34PW2(blocks, frozen_jacobian=frozen)

    def step(x):  # x = (y0, a)
        return solver.step(dfx.ODETerm(_vf_a), 0.1, 0.1 + h, x[:3], x[3], None, False)[0]

    return step


def _w_step(J, stiff, h):
    # the scheme of vehsim.solvers.rosenbrock with a given J (rows of the stiff states S):
    # off S k_i = h f_i, on S (I - gamma h J_SS) k_i = h f_i + h J_S.(g_i + gamma k_i off S)
    from vehsim.solvers.rosenbrock import _A, _B, _C, _G, _GAMMA
    S = np.asarray(stiff)
    N = np.setdiff1d(np.arange(3), S)
    W = jnp.eye(len(S)) - _GAMMA * h * J[np.ix_(S, S)]

    def step(x):
        y0, a, ks = x[:3], x[3], []
        for i in range(4):
            fi = _vf_a(0.1 + _C[i] * h, y0 + sum(_A[i, j] * ks[j] for j in range(i)), a)
            g = sum((_G[i, j] * ks[j] for j in range(i)), start=jnp.zeros(3))
            k = jnp.zeros(3).at[N].set(h * fi[N])
            rhs = h * fi[S] + h * J[S] @ (g + _GAMMA * k)
            ks.append(k.at[S].set(jnp.linalg.solve(W, rhs)))
        return y0 + sum(_B[i] * ks[i] for i in range(4))

    return step


@pytest.mark.parametrize("stiff", [(0, 1, 2), (2,)])
def test_frozen_jacobian_derivative_is_the_w_methods_with_that_jacobian(stiff):
    # an independent W-method step with J = df/dy at the point as a constant matrix: same
    # values, and its derivative is the frozen step's
    x, h = jnp.array([1.0, 0.5, 0.2, 1.3]), 5e-3
    J = np.asarray(jax.jacfwd(lambda y: _vf_a(0.1, y, x[3]))(x[:3]))
    ref = _w_step(jnp.asarray(J), stiff, h)
    frozen = _one_step(True, h, (tuple(stiff),))
    np.testing.assert_allclose(np.asarray(frozen(x)), np.asarray(ref(x)), rtol=1e-14)
    np.testing.assert_allclose(np.asarray(jax.jacrev(frozen)(x)), np.asarray(jax.jacfwd(ref)(x)),
                               rtol=1e-11, atol=1e-14)


def test_frozen_jacobian_same_values_reverse_equals_forward_derivative_within_local_error():
    # holding J constant leaves the step's values as they are (bit for bit); its derivative,
    # forward and reverse alike, is the W-method's with that J, off the exact step's (which
    # central differences reproduce) by the step's sensitivity to its Jacobian, of the order
    # of the local error: h^4 (measured: 2.8e-3, 2.8e-4, 2.3e-5, 1.6e-6 of a derivative of
    # order 1 at h = 1e-2 ... 1.25e-3, the stiff rate 65/s)
    x = jnp.array([1.0, 0.5, 0.2, 1.3])
    gaps = []
    for h in (5e-3, 2.5e-3):
        exact, frozen = _one_step(False, h), _one_step(True, h)
        np.testing.assert_array_equal(np.asarray(jax.jit(frozen)(x)),
                                      np.asarray(jax.jit(exact)(x)))
        fwd = np.asarray(jax.jit(jax.jacfwd(frozen))(x))
        rev = np.asarray(jax.jit(jax.jacrev(frozen))(x))
        np.testing.assert_allclose(rev, fwd, rtol=1e-12, atol=1e-15)
        eps = 1e-6
        fd = np.stack([(np.asarray(exact(x + eps * e)) - np.asarray(exact(x - eps * e))) / (2 * eps)
                       for e in np.eye(4)], axis=-1)
        np.testing.assert_allclose(np.asarray(jax.jacfwd(exact)(x)), fd, atol=1e-8)
        gap = np.max(np.abs(fwd - fd))
        assert 1e-8 < gap < 1e-3 * np.max(np.abs(fd))
        gaps.append(gap)
    assert gaps[0] / gaps[1] > 2.0 ** 3  # of the local error's order


def test_ros34pw2_tableau_meets_the_order_conditions():
    """The coefficients of Rang and Angermann's ROS34PW2 (as PETSc's TSROSWRA34PW2 gives
    them) meet the Rosenbrock order conditions to rounding: order 3 for the solution
    (and order 2 for the embedded one), with beta = alpha + Gamma (the diagonal gamma)."""
    from vehsim.solvers.rosenbrock import _A, _B, _B_HAT, _G, _GAMMA

    beta = _A + _G + _GAMMA * np.eye(4)
    a, bp = _A.sum(axis=1), (_A + _G).sum(axis=1)
    g = _GAMMA
    for b in (_B, _B_HAT):
        assert abs(b.sum() - 1.0) < 1e-15
        assert abs(b @ bp - (0.5 - g)) < 1e-15
    assert abs(_B @ a**2 - 1.0 / 3.0) < 1e-15
    assert abs(_B @ ((beta - g * np.eye(4)) @ bp) - (1.0 / 6.0 - g + g * g)) < 1e-15


def test_jump_times_are_honoured_with_a_given_step_size_controller():
    """A controller passed in is still clipped to the jump times: with a kink in the
    vector field at 0.5013 s, ``PIDController(1e-8, 1e-8)`` given explicitly takes the
    default controller's steps exactly, and fewer rejections than without the jump."""
    from vehsim._integrate import integrate

    tj = 0.5013
    ts = jnp.array([0.0, 2.0])

    def f(t, y, args):
        return -y + jnp.where(t > tj, 3.0, 0.0)

    def run(**kw):
        sol = integrate(f, ts, jnp.array([1.0]), rtol=1e-8, atol=1e-8, **kw)
        return float(sol.ys[-1, 0]), int(sol.stats["num_steps"]), \
            int(sol.stats["num_rejected_steps"])

    jumps = jnp.array([tj])
    default = run(jump_ts=jumps)
    given = run(jump_ts=jumps, stepsize_controller=dfx.PIDController(rtol=1e-8, atol=1e-8))
    blind = run(stepsize_controller=dfx.PIDController(rtol=1e-8, atol=1e-8))
    assert given == default
    assert given[2] < blind[2]
    exact = 3.0 + (np.exp(-tj) - 3.0) * np.exp(-(2.0 - tj))
    assert abs(given[0] - exact) < 1e-7


def test_a_non_finite_start_is_refused_by_name():
    car = HalfCar(rally_gravel(), IsotropicLumpedLuGre(cdc1999(), kappa0=1.0))
    y0 = car.init_state(vx=15.0)
    with pytest.raises(ValueError, match=r"state0 must be finite; non-finite values in vx"):
        simulate(car, jnp.array([0.0, 1.0]), jnp.zeros(3), y0.at[3].set(jnp.nan))
    with pytest.raises(ValueError, match=r"inputs must be finite; non-finite values in T_R"):
        simulate(car, jnp.array([0.0, 1.0]), jnp.array([0.0, jnp.inf, 0.0]), y0)


def test_derivative_from_steady_rolling_with_the_stiff_solver():
    """From straight, nearly free rolling (a nearly steady motion, where an explicit
    adaptive solve's steps would grow past the wheel-tire modes' stability without
    `simulate`'s default ceiling), `ROS34PW2` gives d v_x(1 s)/d brake torque in both modes as central differences do
    (docs/differentiating.md, "Steps on an exactly steady motion")."""
    car = HalfCar(rally_gravel(), IsotropicLumpedLuGre(cdc1999(), kappa0=1.0))
    ts = jnp.array([0.0, 1.0])
    solver = ROS34PW2(car.stiff_blocks)

    @functools.partial(jax.jit, static_argnums=1)
    def final_vx(brake, adjoint=None):
        u = lambda t, y: jnp.stack([-0.6 * brake, -0.4 * brake, 0.0 * brake])
        return simulate(car, ts, u, car.init_state(vx=15.0), solver=solver, rtol=1e-10,
                        atol=1e-10, adjoint=adjoint).states[-1, 3]

    # a light brake of 5 N m, off the kink of |v_r| at exactly zero slip (where the two
    # sides' slopes differ by 0.1 %)
    b0, eps = 5.0, 1e-2
    fd = float((final_vx(b0 + eps) - final_vx(b0 - eps)) / (2 * eps))
    fwd = float(jax.jvp(lambda b: final_vx(b, dfx.ForwardMode()), (b0,), (1.0,))[1])
    rev = float(jax.grad(final_vx)(b0))
    assert -0.0024 < fd < -0.0021  # about -1 / (r m_eff) over the second
    np.testing.assert_allclose([fwd, rev], fd, rtol=1e-3)


@pytest.mark.parametrize("tire", ["lumped LuGre", "static"])
def test_explicit_derivative_from_exact_free_rolling_has_a_default_step_ceiling(tire):
    """From exactly free rolling (zero slip, no torque: the motion's error is zero) an
    explicit solve's steps pass the wheel-tire blocks' stability and its derivative d v_x(1 s)
    /d brake torque is off by orders of magnitude with a successful result (dtmax = 1e9: -76
    with the lumped LuGre tires, -2e8 with the static ones, against -0.0022); `simulate`'s
    default ceiling (0.8 of `Tsit5`'s stability limit on the blocks at the start) gives the
    central differences' (docs/differentiating.md, "Steps on an exactly steady motion")."""
    car = HalfCar(rally_gravel(), IsotropicLumpedLuGre(cdc1999(), kappa0=1.0)
                  if tire == "lumped LuGre" else rally_gravel_tire())
    ts = jnp.array([0.0, 1.0])

    @functools.partial(jax.jit, static_argnums=1)
    def final_vx(brake, dtmax):
        u = lambda t, y: jnp.stack([-0.6 * brake, -0.4 * brake, 0.0 * brake])
        return simulate(car, ts, u, car.init_state(vx=15.0), dtmax=dtmax).states[-1, 3]

    eps = 1e-2
    for dtmax in (None, 1e9):
        fd = float((final_vx(eps, dtmax) - final_vx(-eps, dtmax)) / (2 * eps))
        grad = float(jax.grad(final_vx)(0.0, dtmax))
        assert -0.0024 < fd < -0.0021  # the solve itself is right either way
        if dtmax is None:  # the two sides' slopes at zero slip differ by 0.1 %
            np.testing.assert_allclose(grad, fd, rtol=2e-3)
        else:
            assert not abs(grad - fd) < 10 * abs(fd)


def test_a_static_tire_car_starts_from_rest_without_a_ceiling_as_under_jit():
    """From rest the static tire's slip stiffness asks for steps below `CEILING_FLOOR`, so
    the default sets no ceiling: eagerly (where the ceiling is concrete, and was refused as
    a dtmax of inf, a setting never given) as under `jax.jit` (where it is traced), to the
    same states; the drive torque moves the car forwards."""
    car = HalfCar(rally_gravel(), rally_gravel_tire())
    ts = jnp.linspace(0.0, 1.0, 11)
    u = jnp.array([200.0, 200.0, 0.0])
    eager = simulate(car, ts, u, car.init_state(vx=0.0))
    traced = jax.jit(lambda y0: simulate(car, ts, u, y0).states)(car.init_state(vx=0.0))
    assert eager.result == RESULTS.successful
    np.testing.assert_allclose(eager.states, traced, rtol=1e-9, atol=1e-12)
    assert np.all(np.diff(np.asarray(eager["vx"])) > 0)


def test_stability_boundaries_and_the_spectral_radius_bound_match_their_closed_forms():
    # the real-axis stability boundaries of explicit tableaus: Heun's and the midpoint
    # rule's 2 (1 + z + z^2/2), Bosh3's 2.5127 (1 + z + z^2/2 + z^3/6), Tsit5's 3.51 (its
    # polynomial's root, numpy); the spectral radius bound against LAPACK's eigenvalues on
    # badly scaled blocks (a wheel-tire block's coupling is 1e6 times its diagonal), and
    # zero for a nilpotent block
    from vehsim._simulate import _spectral_radius_bound, stability_boundary

    assert stability_boundary(dfx.Heun()) == pytest.approx(2.0, abs=1e-4)
    assert stability_boundary(dfx.Midpoint()) == pytest.approx(2.0, abs=1e-4)
    third = [r.real for r in np.roots([1 / 6, 1 / 2, 1, 2]) if abs(r.imag) < 1e-12]
    assert stability_boundary(dfx.Bosh3()) == pytest.approx(-third[0], abs=1e-4)
    assert 3.50 < stability_boundary(dfx.Tsit5()) < 3.51
    rng = np.random.default_rng(0)
    J = rng.normal(size=(4, 3, 3)) * np.array([1.0, 1e6, 1.0])[:, None]
    rho = np.max(np.abs(np.linalg.eigvals(J)))
    bound = float(_spectral_radius_bound(jnp.asarray(J)))
    assert rho <= bound < 1.06 * rho
    assert float(_spectral_radius_bound(jnp.asarray(np.triu(J, 1)))) == 0.0


def test_forward_mode_through_the_default_adjoint_says_which_adjoint_to_pass():
    """The default adjoint differentiates in reverse mode only; a forward-mode derivative
    raises naming `diffrax.ForwardMode()`, with which it agrees with reverse mode."""
    from vehsim import PointLuGre, preset
    from vehsim.tire.transient import simulate_tire

    def mu_end(x, adjoint=None):
        return simulate_tire(PointLuGre(preset("table3")), jnp.linspace(0.0, 0.05, 3), x[0],
                             x[1], 0.25, adjoint=adjoint).mu[-1]

    x = jnp.array([20.0, 70.0])
    with pytest.raises(TypeError, match=r"adjoint=diffrax.ForwardMode\(\)"):
        jax.jacfwd(mu_end)(x)
    fwd = jax.jacfwd(functools.partial(mu_end, adjoint=dfx.ForwardMode()))(x)
    np.testing.assert_allclose(fwd, jax.grad(mu_end)(x), rtol=1e-9)
