"""The structured interior-point solver on problems with known answers."""

import re
import types
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim import RESULTS
from vehsim.optimal.ip import (
    AbstractStagewiseNLP,
    IPOptions,
    compile_interior_point,
    interior_point,
)
from vehsim.optimal.ip.block_tridiagonal import KKTMatrix
from vehsim.optimal.ip.riccati import (
    _chol_ok,
    _cholesky,
    _solve_lower,
    riccati_factor,
    riccati_solve,
)
from vehsim.optimal.ip.solver import _least_squares_multipliers, _solve, canonical_options


class RestToRest(AbstractStagewiseNLP):
    """Point mass, friction circle |a| <= amax, from rest at 0 to rest at (L, 0), free t_f.

    Bang-bang optimum t_f = 2 sqrt(L / amax); with an even number of piecewise-constant
    segments the switch falls on a knot and the discrete optimum is exact."""

    num_stages: int = eqx.field(static=True)
    state_size: int = eqx.field(static=True, default=5)
    control_size: int = eqx.field(static=True, default=2)
    L: jax.Array = eqx.field(converter=jnp.asarray, default=10.0)
    amax: jax.Array = eqx.field(converter=jnp.asarray, default=5.0)

    def transition(self, x, u, k):
        h = x[4] / self.num_stages
        p = x[:2] + h * x[2:4] + 0.5 * h**2 * u
        v = x[2:4] + h * u
        return jnp.concatenate([p, v, x[4:]])

    def terminal_cost(self, x):
        return x[4]

    def path_inequality(self, x, u, k):
        return jnp.stack([self.amax**2 - u @ u, x[4] - 0.1])

    def initial_equality(self, x):
        return x[:4]

    def terminal_equality(self, x):
        return jnp.stack([x[0] - self.L, x[1], x[2], x[3]])


def _guess(M, L=10.0):
    xs0 = jnp.zeros((M + 1, 5)).at[:, 0].set(jnp.linspace(0, L, M + 1))
    xs0 = xs0.at[:, 4].set(5.0).at[:, 2].set(2.0)
    return xs0, jnp.zeros((M, 2))


@pytest.fixture(scope="module")
def bang_bang():
    M = 12
    prob = RestToRest(num_stages=M)
    return prob, interior_point(prob, *_guess(M))


def test_bang_bang_min_time_matches_analytic(bang_bang):
    prob, sol = bang_bang
    assert sol.result == RESULTS.successful
    t_exact = 2 * np.sqrt(10.0 / 5.0)
    assert abs(float(sol.xs[-1, 4]) - t_exact) < 1e-6
    # bang-bang: full acceleration, then full braking, along x
    a = np.asarray(sol.us[:, 0])
    np.testing.assert_allclose(a[:6], 5.0, atol=1e-3)
    np.testing.assert_allclose(a[6:], -5.0, atol=1e-3)
    assert float(sol.inf_pr) < 1e-9


def test_batch_by_vmap_and_result(bang_bang):
    prob, _ = bang_bang
    amax = jnp.array([5.0, 2.5])
    xs0, us0 = _guess(prob.num_stages)

    def solve(a):
        p = eqx.tree_at(lambda q: q.amax, prob, a)
        return interior_point(p, xs0, us0, IPOptions(max_iter=60), throw=False)

    sols = jax.vmap(solve)(amax)
    assert np.all(np.asarray(sols.converged))
    np.testing.assert_allclose(sols.xs[:, -1, 4], 2 * np.sqrt(10.0 / amax), atol=1e-6)


def test_ahead_of_time_compiled_solver_is_the_same_program(bang_bang):
    """`compile_interior_point` (compiled from zeros of the right shapes) returns the solution
    of `interior_point` bit for bit, solves other parameter values with the same program
    (t_f = 2 sqrt(L / amax)) and raises like it on failure."""
    prob, sol = bang_bang
    M = prob.num_stages
    solve = compile_interior_point(prob, jnp.zeros((M + 1, 5)), jnp.zeros((M, 2)))
    again = solve(prob, *_guess(M))
    np.testing.assert_array_equal(np.asarray(again.xs), np.asarray(sol.xs))
    assert int(again.iterations) == int(sol.iterations)
    slower = solve(eqx.tree_at(lambda q: q.amax, prob, jnp.asarray(2.5)), *_guess(M))
    assert float(slower.xs[-1, 4]) == pytest.approx(2 * np.sqrt(10.0 / 2.5), abs=1e-6)
    with pytest.raises(RuntimeError, match="inf_pr="):
        solve(prob, *_guess(M), IPOptions(max_iter=3))


def test_verbose_prints_the_iteration_log_and_compiles_the_quiet_program(bang_bang, capsys,
                                                                        caplog):
    """``verbose`` prints one line per logged iteration (the last is the returned iterate's
    residuals) and is not part of the compiled program: the verbose solve is the quiet one,
    bit for bit, with no second compilation."""
    prob, sol = bang_bang
    xs0, us0 = _guess(prob.num_stages)
    with jax.log_compiles():
        loud = interior_point(prob, xs0, us0, IPOptions(verbose=True))
    assert "_solve" not in caplog.text  # jax.log_compiles names every program it compiles
    err = capsys.readouterr().err
    np.testing.assert_array_equal(np.asarray(loud.xs), np.asarray(sol.xs))
    lines = [ln for ln in err.splitlines() if ln.startswith("  ip ")]
    assert len(lines) == int(sol.iterations) + 1
    assert [int(ln.split()[1]) for ln in lines] == list(range(int(sol.iterations) + 1))
    assert f"inf_pr {float(sol.inf_pr):.2e}" in lines[-1]
    assert f"obj {float(sol.objective): .8e}" in lines[-1]


def test_live_log_prints_each_iteration_as_it_runs_the_same_solve(bang_bang, capfd):
    """``live``: the iteration lines come from the running program (a host callback per
    iteration, before the solve returns), the same lines as the log printed after it, and
    the same solve bit for bit."""
    prob, sol = bang_bang
    xs0, us0 = _guess(prob.num_stages)
    after = interior_point(prob, xs0, us0, IPOptions(verbose=True))
    logged = [ln for ln in capfd.readouterr().err.splitlines() if ln.startswith("  ip ")]
    live = interior_point(prob, xs0, us0, IPOptions(live=True))
    jax.effects_barrier()
    lines = [ln for ln in capfd.readouterr().err.splitlines() if ln.startswith("  ip ")]
    np.testing.assert_array_equal(np.asarray(live.xs), np.asarray(after.xs))
    # the live lines are the passes that took a step; the log adds the returned iterate's
    assert len(lines) >= int(sol.iterations) and lines == logged[:len(lines)]


def test_the_solver_program_is_exported_once_and_loaded_after(bang_bang, tmp_path,
                                                              monkeypatch):
    """The solver itself never writes: with the persistent cache on, `interior_point` leaves
    the exported folder empty. The compilation layer's `exported_interior_point` keeps JAX's
    tracing for a problem class from outside vehsim (its static fields might not print in
    full); for a trusted class it exports its program (one file in the cache's exported
    folder) and computes the jit path's solution bit for bit; a process with nothing in
    memory loads the file (nothing is exported again); a static option that changes the
    program is another file; a traced call (vmap) keeps the jit path; an unreadable file is
    exported again."""
    import vehsim._compilation as cc

    prob, _ = bang_bang
    xs0, us0 = _guess(prob.num_stages)
    monkeypatch.setattr(cc, "_exported_folder", lambda: tmp_path)
    monkeypatch.setattr(cc, "_programs", {})
    jitted = _solve(prob, xs0, us0, canonical_options(IPOptions()))
    module = type(prob).__module__.split(".")[0]
    with monkeypatch.context() as m:
        m.setattr(cc, "FAITHFUL_MODULES", (*cc.FAITHFUL_MODULES, module))
        interior_point(prob, xs0, us0)  # the core: a jitted function, nothing written
    assert not list(tmp_path.iterdir()) and not cc._programs
    cc.exported_interior_point(prob, xs0, us0)  # a problem class from outside vehsim
    assert not list(tmp_path.iterdir())
    monkeypatch.setattr(cc, "FAITHFUL_MODULES", (*cc.FAITHFUL_MODULES, module))
    first = cc.exported_interior_point(prob, xs0, us0)
    (path,) = tmp_path.glob("interior_point-*.bin")
    np.testing.assert_array_equal(np.asarray(first.xs), np.asarray(jitted.xs))

    def no_export(*args, **kwargs):
        raise AssertionError("exported again")

    monkeypatch.setattr(cc, "_programs", {})  # as in a new process
    with monkeypatch.context() as m:
        m.setattr(jax.export, "export", no_export)
        again = cc.exported_interior_point(prob, xs0, us0, IPOptions(max_iter=200))  # same
    assert len(cc._programs) == 1 and None not in cc._programs.values()
    np.testing.assert_array_equal(np.asarray(again.xs), np.asarray(first.xs))

    jax.vmap(lambda a: cc.exported_interior_point(eqx.tree_at(lambda q: q.amax, prob, a), xs0,
                                                  us0, throw=False).xs)(jnp.array([5.0, 6.0]))
    assert len(list(tmp_path.glob("*.bin"))) == 1
    tighter = cc.exported_interior_point(prob, xs0, us0, IPOptions(tol=1e-10))
    assert len(list(tmp_path.glob("*.bin"))) == 2
    assert float(tighter.xs[-1, 4]) == pytest.approx(float(first.xs[-1, 4]), abs=1e-6)

    path.write_bytes(b"not a program")
    monkeypatch.setattr(cc, "_programs", {})
    mended = cc.exported_interior_point(prob, xs0, us0)
    np.testing.assert_array_equal(np.asarray(mended.xs), np.asarray(first.xs))
    assert path.stat().st_size > 1000
    with pytest.raises(RuntimeError, match="inf_pr="):  # raises as `interior_point` does
        cc.exported_interior_point(prob, xs0, us0, IPOptions(max_iter=3))


def test_iteration_limit_reports_result_and_residuals(bang_bang):
    prob, _ = bang_bang
    xs0, us0 = _guess(prob.num_stages)
    sol = interior_point(prob, xs0, us0, IPOptions(max_iter=3), throw=False)
    assert sol.result == RESULTS.ip_max_iterations and not sol.converged
    assert int(sol.iterations) == 3
    assert float(sol.inf_pr) > 1e-6 and np.isfinite(float(sol.inf_du))
    with pytest.raises(RuntimeError, match="inf_pr="):
        interior_point(prob, xs0, us0, IPOptions(max_iter=3))


class CappedRestToRest(RestToRest):
    """`RestToRest` with its final time at most ``tmax``: infeasible below the bang-bang
    optimum $2\\sqrt{L/a_{max}}$ (2.83 s)."""

    tmax: jax.Array = eqx.field(converter=jnp.asarray, default=1.0)

    def path_inequality(self, x, u, k):
        return jnp.concatenate([super().path_inequality(x, u, k), (self.tmax - x[4])[None]])


def test_a_solve_stuck_at_a_violation_it_cannot_reduce_says_the_problem_is_infeasible():
    """t_f <= 1 s where the optimum is 2.83 s: the violation stalls near 3.5 by the 30th
    pass, so a solve of 60 passes ends `ip_locally_infeasible` with that violation; one of
    25 (still reducing it) and a feasible solve that cannot meet an unreachable ``tol``
    (violation below ``constr_tol``, or flat at rounding far below the starting one, above
    an unreachable ``constr_tol``) end `ip_max_iterations`; with t_f <= 2.9 s it
    converges."""
    from vehsim.optimal.ip.solver import INFEASIBLE_PASSES

    M = 12
    infeasible = CappedRestToRest(num_stages=M, tmax=1.0)
    sol = interior_point(infeasible, *_guess(M), IPOptions(max_iter=60), throw=False)
    assert sol.result == RESULTS.ip_locally_infeasible and int(sol.iterations) == 60
    assert float(sol.inf_pr) == pytest.approx(3.5, rel=1e-6)
    with pytest.raises(RuntimeError, match="probably infeasible"):
        interior_point(infeasible, *_guess(M), IPOptions(max_iter=60))
    assert f"last {INFEASIBLE_PASSES} passes" in RESULTS[RESULTS.ip_locally_infeasible]
    early = interior_point(infeasible, *_guess(M), IPOptions(max_iter=25), throw=False)
    assert early.result == RESULTS.ip_max_iterations and float(early.inf_pr) > 3.5
    feasible = interior_point(CappedRestToRest(num_stages=M, tmax=2.9), *_guess(M),
                              IPOptions(max_iter=60), throw=False)
    assert feasible.converged
    np.testing.assert_allclose(float(feasible.objective), 2 * np.sqrt(10.0 / 5.0), rtol=1e-6)
    unreachable = interior_point(CappedRestToRest(num_stages=M, tmax=2.9), *_guess(M),
                                 IPOptions(max_iter=60, tol=1e-300), throw=False)
    assert unreachable.result == RESULTS.ip_max_iterations
    assert float(unreachable.inf_pr) <= 1e-9
    # a violation brought down to rounding and flat there, above an unreachable constr_tol:
    # near a feasible point, not infeasible
    near = interior_point(CappedRestToRest(num_stages=M, tmax=2.9), *_guess(M),
                          IPOptions(max_iter=60, tol=1e-300, constr_tol=1e-300), throw=False)
    assert near.result == RESULTS.ip_max_iterations
    assert 0.0 < float(near.inf_pr) < 1e-9


def test_a_violation_falling_slowly_is_progress_and_a_flat_one_is_not():
    """The passes-without-progress count over a log (`passes_without_progress`): a
    violation falling 0.6 % a pass makes 1 % every second pass (the count never passes 1);
    a flat one counts every pass after the first; entries past ``last`` are not read; a log
    shorter than ``last`` gives 0."""
    from vehsim.optimal.ip.solver import passes_without_progress

    slow = jnp.asarray(10.0 * 0.994 ** np.arange(100))
    assert max(int(passes_without_progress(slow, k)) for k in range(100)) == 1
    flat = jnp.full(30, 3.5)
    assert [int(passes_without_progress(flat, k)) for k in range(30)] == list(range(30))
    log = jnp.asarray([3.5, 3.5, 3.5, 1.0, jnp.nan])
    assert int(passes_without_progress(log, 2)) == 2
    assert int(passes_without_progress(log, 3)) == 0
    assert int(passes_without_progress(flat, 30)) == 0


def _random_kkt(rng, M, nx, nu, ne, definite):
    """A random KKT matrix of the stage structure: W symmetric (positive definite with
    graded eigenvalues if `definite`, else indefinite: its control block shifted down by
    1e4, past the equality rows' 1e3 J_e^T J_e, and its state block up by as much, so that
    the control blocks' factors fail and P_0's exists), defects exact (d_lambda = 0, the padded last knot -1),
    boundary equalities at -1e-3 (eigenvalues far above rounding)."""
    ny = nx + nu
    W = rng.normal(size=(M + 1, ny, ny))
    shift = np.diag(np.r_[np.full(nx, 1e4), np.full(nu, -1e4)])  # x-block up, u-block down
    W = W @ W.transpose(0, 2, 1) if definite else W + W.transpose(0, 2, 1) + shift
    W = W + np.diag(np.logspace(-3, 4, ny)) if definite else W
    A = rng.normal(size=(M + 1, nx, ny))
    A[-1] = 0.0
    dl = np.zeros((M + 1, nx))
    dl[-1] = -1.0
    return KKTMatrix(W=jnp.asarray(W), A=jnp.asarray(A), Je=jnp.asarray(rng.normal(size=(
        M + 1, ne, ny))), dl=jnp.asarray(dl), de=jnp.full((M + 1, ne), -1e-3))


@pytest.mark.parametrize("nu", [1, 2, 3, 4])
@pytest.mark.parametrize("definite", [True, False])
def test_riccati_solve_and_inertia_match_the_dense_matrix(definite, nu):
    # the dense matrix from the structured product (unit vectors), solved by LAPACK; the
    # Riccati factor exists exactly when the matrix has one negative eigenvalue per
    # multiplier row and none zero (Sylvester); every closed-form size of the control
    # blocks' inverse and the Cholesky fallback beyond
    nx, ne, M = 3, 2, 4
    nb = 2 * nx + nu + ne
    rng = np.random.default_rng(1)
    K = _random_kkt(rng, M, nx, nu, ne, definite)
    N = (M + 1) * nb
    dense = np.stack([np.asarray(K.matvec(jnp.asarray(e.reshape(M + 1, nb)))).reshape(-1)
                      for e in np.eye(N)], axis=1)
    np.testing.assert_allclose(dense, dense.T, atol=0)  # symmetric
    eig = np.linalg.eigvalsh(dense)
    right_inertia = np.sum(eig < 0) == (M + 1) * (nx + ne) and np.all(eig != 0)
    F = riccati_factor(K)
    assert bool(F.ok) == bool(right_inertia)
    if definite:
        assert right_inertia
        rhs = rng.normal(size=(M + 1, nb))
        sol = np.asarray(riccati_solve(F, K, jnp.asarray(rhs)))
        ref = np.linalg.solve(dense, rhs.reshape(-1))
        np.testing.assert_allclose(sol.reshape(-1), ref, rtol=1e-6, atol=1e-9)
    else:
        assert not right_inertia


def test_checked_solve_refines_an_inaccurate_solve_and_rejects_one_refinement_cannot_mend(
        monkeypatch):
    # checked_solve's three outcomes on one factor of the right inertia: a first solve within
    # the backward-error tolerance is used; one that misses it (made inaccurate on purpose
    # here, a relative error of 1e-4: backward error 3e-8 against the tolerance 1e-10) is
    # mended by one step of iterative refinement (3e-12); a solve still above the tolerance
    # after that step is rejected (ok false), though its factor exists
    from vehsim.optimal.ip import kkt

    nx, nu, ne, M = 3, 2, 2, 4
    nb = 2 * nx + nu + ne
    rng = np.random.default_rng(3)
    K = _random_kkt(rng, M, nx, nu, ne, True)
    rhs = jnp.asarray(rng.normal(size=(M + 1, nb)))
    lay = types.SimpleNamespace()  # checked_solve does not read the layout
    dense = np.stack([np.asarray(K.matvec(jnp.asarray(e.reshape(M + 1, nb)))).reshape(-1)
                      for e in np.eye((M + 1) * nb)], axis=1)
    ref = np.linalg.solve(dense, np.asarray(rhs).reshape(-1))

    sol, ok, F = kkt.checked_solve(lay, K, rhs)
    assert bool(F.ok) and bool(ok)
    np.testing.assert_allclose(np.asarray(sol).reshape(-1), ref, rtol=1e-8, atol=1e-10)

    exact_solve = kkt.riccati_solve
    monkeypatch.setattr(kkt, "riccati_solve", lambda F, K, b: exact_solve(F, K, b) * (1 + 1e-4))
    first = np.asarray(kkt.riccati_solve(F, K, rhs))
    assert not bool(kkt._backward_error_ok(K, jnp.asarray(first), rhs)[0])  # misses the tol
    sol, ok, _ = kkt.checked_solve(lay, K, rhs)
    assert bool(ok)
    err = np.max(np.abs(np.asarray(sol).reshape(-1) - ref))
    assert err < 1e-3 * np.max(np.abs(first.reshape(-1) - ref))  # the refined solution

    # a solver too poor for one refinement to reach the tolerance (relative error 3e-3): the
    # refined solve is accepted where its backward error is below `singular` (IPOPT's
    # residual_ratio_singular, the interior point's default 1e-5), refused above it, and
    # refused by default (`singular` the tolerance itself)
    monkeypatch.setattr(kkt, "riccati_solve", lambda F, K, b: exact_solve(F, K, b) * (1 + 3e-3))
    first = kkt.riccati_solve(F, K, rhs)
    refined = first + kkt.riccati_solve(F, K, rhs - K.matvec(first))
    scale = np.max(np.asarray(K.matvec(refined, absolute=True) + jnp.abs(rhs)))
    backward = np.max(np.abs(np.asarray(rhs - K.matvec(refined)))) / scale
    assert 1e-9 < backward < 1e-5
    for singular, accepted in ((None, False), (backward / 2, False), (2 * backward, True),
                               (kkt.BACKWARD_ERROR_SINGULAR, True)):
        sol, ok, F = kkt.checked_solve(lay, K, rhs, singular)
        assert bool(F.ok) and bool(ok) == accepted, singular
    np.testing.assert_allclose(np.asarray(sol), np.asarray(refined), rtol=1e-12)

    monkeypatch.setattr(kkt, "backward_error_tol", lambda dtype: 0.0)  # none meets it
    sol, ok, F = kkt.checked_solve(lay, K, rhs)
    assert bool(F.ok) and not bool(ok)
    assert np.all(np.isfinite(np.asarray(sol)))


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5])
def test_unrolled_cholesky_and_triangular_solves_match_lapack(n):
    # against numpy and scipy (LAPACK): graded positive definite matrices (diagonal over
    # seven decades), and an indefinite matrix has no factor; n = 5 is LAPACK itself
    import scipy.linalg

    rng = np.random.default_rng(n)
    for _ in range(10):
        B = rng.normal(size=(n, n))
        D = np.diag(np.logspace(-3, 4, n)[rng.permutation(n)])
        Q = D @ B @ B.T @ D + 1e-3 * np.eye(n)
        L = np.asarray(_cholesky(jnp.asarray(Q)))
        np.testing.assert_allclose(L, np.linalg.cholesky(Q), rtol=1e-10, atol=1e-12 * L.max())
        b = rng.normal(size=(n, 4))
        for transposed in (False, True):
            x = np.asarray(_solve_lower(jnp.asarray(L), jnp.asarray(b), transposed))
            ref = scipy.linalg.solve_triangular(L, b, lower=True, trans=int(transposed))
            np.testing.assert_allclose(x, ref, rtol=1e-10)
    S = np.diag(np.r_[np.ones(n - 1), -1.0])
    assert not bool(_chol_ok(_cholesky(jnp.asarray(S))))


def test_riccati_step_compiles_without_lapack_or_blas_calls():
    # the recursion's speed on small blocks rests on every stage being fused arithmetic: no
    # LAPACK (Cholesky, triangular solve) or BLAS call inside the scans; P_0's factor and
    # solve, once per factorisation, are LAPACK's
    K = _random_kkt(np.random.default_rng(0), 4, 3, 3, 2, True)
    rhs = jnp.ones((5, 2 * 3 + 3 + 2))
    hlo = jax.jit(lambda K, b: riccati_solve(riccati_factor(K), K, b)).lower(
        K, rhs).compile().as_text()
    bodies = re.findall(r"^%\S*region\S* \(.*?^\}", hlo, re.M | re.S)
    loops = [b for b in bodies if "dynamic-update-slice" in b]
    assert len(loops) >= 3  # the factor's scan and the solve's two
    for body in loops:
        assert "custom-call" not in body and " dot(" not in body
    assert "lapack" in hlo  # P_0


TRACES = []


class CountedRestToRest(RestToRest):
    """`RestToRest` that records each trace of its dynamics (a compiled program reused
    records nothing)."""

    def transition(self, x, u, k):
        TRACES.append(k)
        return super().transition(x, u, k)


def test_options_built_without_float64_reuse_the_compiled_solver():
    # a default argument `IPOptions()` evaluated at import, before float64 was switched on,
    # holds int32/float32 arrays: the solver must not compile a second program for it
    M = 12
    prob = CountedRestToRest(num_stages=M)
    sol = interior_point(prob, *_guess(M), IPOptions())
    traced = len(TRACES)
    jax.config.update("jax_enable_x64", False)
    try:
        single = IPOptions()
    finally:
        jax.config.update("jax_enable_x64", True)
    assert single.mu0.dtype == jnp.float32 and traced > 0
    again = interior_point(prob, *_guess(M), single)
    assert len(TRACES) == traced
    assert float(again.objective) == pytest.approx(float(sol.objective), rel=1e-9)


def test_second_order_correction_with_the_step_s_own_residuals_is_the_step():
    # the correction reuses the step's factor with new constraint residuals: given the
    # residuals the step was computed for, it must return the step itself
    from vehsim.optimal.ip.derivatives import stage_derivatives
    from vehsim.optimal.ip.kkt import newton_step, second_order_correction
    from vehsim.optimal.ip.problem import stage_layout
    from vehsim.optimal.ip.solver import _initial_state

    M = 12
    prob = RestToRest(num_stages=M)
    lay = stage_layout(prob)
    it = _initial_state(prob, lay, *_guess(M), IPOptions()).iterate
    d = stage_derivatives(prob, lay, it.ys, it.lam, it.nu, it.z)
    step = newton_step(lay, it, d, 0.1, 0.0)
    dy, ds, dlam, dnu = second_order_correction(lay, it, d, 0.1, step, d.c, d.e,
                                                (d.g - it.s) * lay.masks().g)
    for got, want in ((dy, step.dy), (ds, step.ds), (dlam, step.dlam), (dnu, step.dnu)):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-9, atol=1e-11)
    assert float(jnp.max(jnp.abs(step.dy))) > 1e-3  # a real step


def test_least_squares_multipliers_at_the_optimum_are_its_multipliers(bang_bang):
    # at a KKT point the Lagrangian gradient vanishes for the solution's multipliers, so the
    # least-squares estimate (the first pass of a least-squares start) must return them
    from vehsim.optimal.ip.derivatives import stage_derivatives
    from vehsim.optimal.ip.kkt import Iterate, newton_step
    from vehsim.optimal.ip.problem import stage_layout

    prob, sol = bang_bang
    lay = stage_layout(prob)
    ys = lay.join(sol.xs, sol.us)
    it = Iterate(ys=ys, s=jnp.ones_like(sol.z), z=sol.z, lam=jnp.zeros_like(sol.lam),
                 nu=jnp.zeros_like(sol.nu))
    d = stage_derivatives(prob, lay, ys, it.lam, it.nu, it.z)
    step = newton_step(lay, it, d, 0.1, 0.0, least_squares=True)
    mk = lay.masks()
    assert float(jnp.max(jnp.abs(sol.lam))) > 0.1  # nontrivial multipliers
    np.testing.assert_allclose(np.asarray(step.dlam), np.asarray(sol.lam * mk.lam), atol=1e-6)
    np.testing.assert_allclose(np.asarray(step.dnu), np.asarray(sol.nu * mk.eq), atol=1e-6)
    # the primal part is the least-squares residual: zero at a KKT point
    assert float(jnp.max(jnp.abs(step.dy))) < 1e-6
    # the solver's start evaluates it from values and Jacobians only: the same multipliers
    lam, nu = _least_squares_multipliers(prob, lay, it, 0.1)
    np.testing.assert_allclose(np.asarray(lam), np.asarray(sol.lam * mk.lam), atol=1e-6)
    np.testing.assert_allclose(np.asarray(nu), np.asarray(sol.nu * mk.eq), atol=1e-6)


def test_a_capped_solve_reports_the_residuals_of_the_iterate_it_returns(bang_bang):
    # the last pass of a capped solve takes no step and skips the Hessian: its residuals
    # are those of the full derivatives at the returned iterate, and it is logged unstepped
    from vehsim.optimal.ip.derivatives import stage_derivatives
    from vehsim.optimal.ip.kkt import Iterate, kkt_residuals
    from vehsim.optimal.ip.problem import stage_layout

    prob, _ = bang_bang
    lay = stage_layout(prob)
    xs0, us0 = _guess(prob.num_stages)
    sol = interior_point(prob, xs0, us0, IPOptions(max_iter=4), throw=False)
    ys = lay.join(sol.xs, sol.us)
    it = Iterate(ys=ys, s=sol.s, z=sol.z, lam=sol.lam, nu=sol.nu)
    d = stage_derivatives(prob, lay, ys, it.lam, it.nu, it.z)
    res = kkt_residuals(lay, it, d)
    assert int(sol.iterations) == 4 and not sol.converged
    for name in ("inf_pr", "inf_du", "compl"):
        assert float(getattr(sol, name)) == pytest.approx(float(getattr(res, name)),
                                                          rel=1e-12, abs=1e-14)
    assert float(sol.objective) == pytest.approx(float(d.objective), rel=1e-14)
    assert float(sol.log.alpha[3]) == 0.0 and float(sol.log.alpha[2]) > 0.0
    assert np.isnan(float(sol.log.alpha[4]))


def test_best_iterate_returns_the_smallest_kkt_error_the_solve_reached(bang_bang):
    """``best_iterate``: a capped solve returns, of the iterates it passed, the one of the
    smallest scaled KKT error, with its own residuals and objective. The solve capped at
    ``n`` passes returns the iterate after ``n - 1`` steps, so the caps 1..N lay out the
    trajectory, each iterate's error is computed here from its derivatives
    (`kkt_residuals`), and the capped solve with the option must return the caps' argmin.
    The error along this trajectory is not monotone, so the best is not always the last; a
    converged solve is the same with and without the option."""
    from vehsim.optimal.ip.derivatives import stage_derivatives
    from vehsim.optimal.ip.kkt import Iterate, kkt_residuals
    from vehsim.optimal.ip.problem import stage_layout

    prob, converged = bang_bang
    lay = stage_layout(prob)
    xs0, us0 = _guess(prob.num_stages)

    def error(sol):
        ys = lay.join(sol.xs, sol.us)
        it = Iterate(ys=ys, s=sol.s, z=sol.z, lam=sol.lam, nu=sol.nu)
        return float(kkt_residuals(lay, it, stage_derivatives(prob, lay, ys, it.lam, it.nu,
                                                                it.z)).error)

    caps = range(1, 13)
    last = [interior_point(prob, xs0, us0, IPOptions(max_iter=n), throw=False) for n in caps]
    errors = np.array([error(sol) for sol in last])
    print("errors along the trajectory", errors)
    earlier = 0
    for n, sol_last in zip(caps, last):
        best = interior_point(prob, xs0, us0, IPOptions(max_iter=n, best_iterate=True),
                              throw=False)
        j = int(np.argmin(errors[:n]))
        earlier += j < n - 1
        want = last[j]
        # the same iterate (two programs: equal to their rounding)
        for name in ("xs", "us", "z", "lam", "nu", "s", "objective", "inf_pr", "inf_du",
                     "compl"):
            np.testing.assert_allclose(np.asarray(getattr(best, name)),
                                       np.asarray(getattr(want, name)), rtol=1e-9,
                                       atol=1e-12, err_msg=name)
        # the outcome is the solve's: the result, the passes and the log of the last iterate
        assert best.result == sol_last.result and int(best.iterations) == n
        np.testing.assert_allclose(np.asarray(best.log.inf_pr), np.asarray(sol_last.log.inf_pr),
                                   rtol=1e-9)
    assert earlier >= 2  # the option changed what some capped solves return
    again = interior_point(prob, xs0, us0, IPOptions(best_iterate=True))
    assert again.converged and int(again.iterations) == int(converged.iterations)
    for a, b in zip(jax.tree.leaves(again), jax.tree.leaves(converged)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-9, atol=1e-12)


def test_zero_and_least_squares_starts_reach_the_same_optimum(bang_bang):
    prob, sol = bang_bang
    xs0, us0 = _guess(prob.num_stages)
    for opts in (IPOptions(multiplier_init="zero"), IPOptions(bound_multiplier_init="constant")):
        other = interior_point(prob, xs0, us0, opts)
        assert float(other.xs[-1, 4]) == pytest.approx(float(sol.xs[-1, 4]), abs=1e-7)
    with pytest.raises(ValueError, match="IPOptions.multiplier_init must be one of"):
        IPOptions(multiplier_init="ones")


def test_barrier_decreases_several_times_while_the_iterate_allows():
    # IPOPT's fast monotone decrease: mu <- min(0.2 mu, mu^1.5) while E_mu(mu) <= 10 mu
    from vehsim.optimal.ip.solver import _barrier_update

    mu, changed = _barrier_update(lambda m: jnp.asarray(0.05), jnp.asarray(0.1), 1e-8)
    # 0.05 <= 1.0 -> 0.02; 0.05 <= 0.2 -> 0.02**1.5 = 2.83e-3; 0.05 > 2.83e-2: stop
    assert float(mu) == pytest.approx(0.02**1.5, rel=1e-12) and bool(changed)
    mu, changed = _barrier_update(lambda m: jnp.asarray(0.0), jnp.asarray(0.1), 1e-8)
    assert float(mu) == pytest.approx(1e-9) and bool(changed)  # down to tol / 10
    mu, changed = _barrier_update(lambda m: jnp.asarray(2.0), jnp.asarray(0.1), 1e-8)
    assert float(mu) == 0.1 and not bool(changed)


def _random_maneuver_point(M, seed):
    """The corner90 maneuver NLP of ``M`` stages (two RK4 steps each), its layout, and a
    random point ``ys`` with random multipliers ``lam``, ``nu`` and positive ``z``."""
    from vehsim.optimal.ip.problem import stage_layout
    from vehsim.optimal.primitives import rally_gravel_car
    from vehsim.optimal.roads import road
    from vehsim.optimal.shooting import ManeuverOCP

    prob = ManeuverOCP(vehicle=rally_gravel_car(), road=road("corner90"), num_stages=M,
                       steps_per_stage=2)
    lay = stage_layout(prob)
    mk = lay.masks()
    k1, k2, k3, k4 = jax.random.split(jax.random.PRNGKey(seed), 4)
    base = jnp.array([2.0, 5.0, 0.1, 8.0, 0.3, 0.2, 0.05, 0.08, 0.1, 3.5, 0.5, -0.2, 0.3])
    ys = (base[None] + 0.1 * jax.random.normal(k1, (M + 1, lay.ny))) * mk.y
    lam = jax.random.normal(k2, (M + 1, lay.nx)) * mk.lam
    nu = jax.random.normal(k3, (M + 1, lay.ne)) * mk.eq
    z = jnp.abs(jax.random.normal(k4, (M + 1, lay.ng))) * mk.g
    return prob, lay, ys, lam, nu, z


def test_stage_hessians_are_the_blocks_of_the_whole_lagrangian_hessian():
    """Every function of the maneuver NLP depends on one stage, so the Hessian of the whole
    Lagrangian $f + \\lambda \\cdot c + \\nu \\cdot e - z \\cdot g$ (jax.hessian of the
    assembled problem, a dense peer) is block diagonal with the stage blocks of
    `stage_derivatives` (both of its Hessian modes), at a random point and random multipliers, two RK4 steps per stage
    (nodes inside the segment)."""
    from vehsim.optimal.ip.derivatives import stage_derivatives, stage_values

    M = 2
    prob, lay, ys, lam, nu, z = _random_maneuver_point(M, 7)
    mk = lay.masks()

    def lagrangian(y):
        f, c, e, g = stage_values(prob, lay, y)
        return f + jnp.sum(lam * c) + jnp.sum(nu * e) - jnp.sum(z * g * mk.g)

    dense = np.asarray(jax.jit(jax.hessian(lagrangian))(ys))  # (M+1, ny, M+1, ny)
    used = np.asarray(mk.y).astype(bool)
    mask = used[:, :, None, None] & used[None, None, :, :]
    scale = np.max(np.abs(dense))
    assert scale > 1.0  # curvature present
    for hessian in ("forward-over-reverse", "forward-over-forward"):
        d = eqx.filter_jit(stage_derivatives)(prob, lay, ys, lam, nu, z, hessian)
        blocks = np.zeros_like(dense)
        for k in range(M + 1):
            blocks[k, :, k, :] = np.asarray(d.H[k])
        np.testing.assert_allclose(np.where(mask, blocks, 0.0), np.where(mask, dense, 0.0),
                                   rtol=0, atol=1e-8 * scale, err_msg=hessian)


def test_stage_jacobians_are_those_of_the_full_derivatives():
    """`stage_jacobians` (values and Jacobians, no Hessian) gives the values and Jacobians
    of `stage_derivatives` at a random point of the maneuver NLP, and a zero Hessian."""
    from vehsim.optimal.ip.derivatives import stage_derivatives, stage_jacobians

    prob, lay, ys, lam, nu, z = _random_maneuver_point(3, 3)
    full = eqx.filter_jit(stage_derivatives)(prob, lay, ys, lam, nu, z)
    jac = eqx.filter_jit(stage_jacobians)(prob, lay, ys)
    for name in ("objective", "c", "e", "g", "grad_f", "A", "Je", "Jg"):
        want = np.asarray(getattr(full, name))
        assert np.max(np.abs(want)) > 0, name
        np.testing.assert_allclose(np.asarray(getattr(jac, name)), want, rtol=1e-12,
                                   atol=1e-12 * np.max(np.abs(want)), err_msg=name)
    assert np.max(np.abs(np.asarray(full.H))) > 1.0 and not np.any(np.asarray(jac.H))


def test_frozen_hessian_reaches_the_same_optimum_linearly(bang_bang):
    """``hessian_update='first'`` keeps the first pass's Hessian: the fixed point is still
    the KKT point (the analytic bang-bang time), in more passes than Newton's; with
    ``fresh_hessian_steps`` as many as the cap (an array: the same program) it is Newton's
    solve, step for step; it refuses an unknown update."""
    prob, sol = bang_bang
    solve = eqx.filter_jit(lambda steps: interior_point(
        prob, *_guess(prob.num_stages),
        IPOptions(hessian_update="first", max_iter=300, fresh_hessian_steps=steps)))
    frozen = solve(jnp.asarray(1))
    assert float(frozen.xs[-1, 4]) == pytest.approx(2 * np.sqrt(10.0 / 5.0), abs=1e-6)
    assert int(frozen.iterations) > int(sol.iterations)
    newton = solve(jnp.asarray(300))
    assert int(newton.iterations) == int(sol.iterations)
    np.testing.assert_allclose(newton.xs, sol.xs, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="IPOptions.hessian_update must be one of"):
        IPOptions(hessian_update="never")
    with pytest.raises(ValueError, match="IPOptions.fresh_hessian_steps"):
        IPOptions(hessian_update="first", fresh_hessian_steps=0)


def test_kept_jacobians_reach_the_optimum_with_exact_residuals(bang_bang):
    """``jacobian_update='first'`` keeps the Jacobians with the Hessian (after 10 Newton
    steps here) and evaluates the values and the Lagrangian gradient (one reverse pass):
    the solve converges to the KKT point, the analytic bang-bang time, in more passes than
    Newton's, and a capped solve reports the residuals that fresh Jacobians give at its
    iterate (`kkt_residuals`). It refuses to run without a kept Hessian."""
    from vehsim.optimal.ip.derivatives import stage_jacobians
    from vehsim.optimal.ip.kkt import Iterate, kkt_residuals
    from vehsim.optimal.ip.problem import stage_layout

    prob, newton = bang_bang
    lay = stage_layout(prob)
    solve = eqx.filter_jit(lambda o: interior_point(prob, *_guess(prob.num_stages), o,
                                                    throw=False))
    kept = lambda cap: IPOptions(hessian_update="first", jacobian_update="first",
                                 max_iter=cap, fresh_hessian_steps=10)

    def exact(sol):
        ys = lay.join(sol.xs, sol.us)
        it = Iterate(ys=ys, s=sol.s, z=sol.z, lam=sol.lam, nu=sol.nu)
        return kkt_residuals(lay, it, stage_jacobians(prob, lay, ys))

    sol = solve(kept(300))
    assert sol.result == RESULTS.successful
    assert int(newton.iterations) < int(sol.iterations) < 300
    assert float(sol.xs[-1, 4]) == pytest.approx(2 * np.sqrt(10.0 / 5.0), abs=1e-6)
    assert float(exact(sol).inf_du) < 1e-6  # the limit is the KKT point
    capped = solve(kept(14))
    assert capped.result == RESULTS.ip_max_iterations
    for name in ("inf_pr", "inf_du"):
        got, want = float(getattr(capped, name)), float(getattr(exact(capped), name))
        assert want > 1e-9 and got == pytest.approx(want, rel=1e-9), name
    with pytest.raises(ValueError, match="needs hessian_update='first'"):
        IPOptions(jacobian_update="first")
    with pytest.raises(ValueError, match="IPOptions.jacobian_update must be one of"):
        IPOptions(hessian_update="first", jacobian_update="never")


def test_kept_hessian_starts_the_inertia_correction_from_the_last_regularisation():
    """A Newton pass tries $\\delta = 0$ first, then `DELTA_FIRST` growing a hundredfold
    (IPOPT's sequence); a pass that keeps the Hessian of a pass that needed a regularisation
    starts from that one over `DELTA_DECREASE` (the same curvature fails $\\delta = 0$
    again), growing eightfold: its $\\delta$ is $\\delta_{i-1}/3 \\cdot 8^{f_i - 1}$
    after $f_i$ factorisations, one fewer than from 0. On a minimum-time horizon problem
    (a corner, whose Hessian needs a regularisation at every pass)."""
    import vehsim as vs
    from vehsim.drive.horizon import profile_guess
    from vehsim.optimal.ip.kkt import DELTA_DECREASE, DELTA_FIRST, DELTA_GROWTH, DELTA_GROWTH_FIRST

    road = vs.CentrelineRoad.from_segments([("straight", 10.0), ("arc", 15, 90),
                                            ("straight", 20.0)], 4.0)
    table = vs.RoadTable.from_road(road, extension=40.0)
    # (the slip bound 0.2: with the default 0.15 and the end knot at the tire's peak slip
    # this start's first pass needs no regularisation)
    driver = vs.RecedingHorizonDriver(table, horizon=30.0, num_stages=6, slip_limit=0.2)
    x8, D = jnp.array([0.5, 0.05, 12.0, 0.0, 0.0, 0.0, 0.0, 0.0]), jnp.full((6,), 0.52)
    prob = driver.problem(2.0, x8, D)
    sol = interior_point(prob, *profile_guess(table, driver.vehicle, 2.0, x8, D, horizon=30.0),
                         IPOptions(hessian_update="first", max_iter=40, log_size=40, mu0=0.1),
                         throw=False)
    assert int(sol.iterations) == 40 and not bool(sol.converged)  # 39 steps, then the residuals
    f = np.asarray(sol.log.factorisations[:39])
    reg = np.asarray(sol.log.regularisation[:39])
    assert f[0] >= 2  # the first (Newton) pass: 0, then 1e-4, 1e-2, ...
    assert reg[0] == pytest.approx(DELTA_FIRST * DELTA_GROWTH_FIRST ** (f[0] - 2), rel=1e-12)
    assert np.all(reg > 0)
    np.testing.assert_allclose(reg[1:], reg[:-1] / DELTA_DECREASE * DELTA_GROWTH ** (f[1:] - 1),
                               rtol=1e-12)
    assert np.sum(f[1:] == 1) >= 10  # most kept-Hessian passes factor once


def test_one_rk4_step_without_the_loop_is_the_looped_step():
    """A segment of one RK4 step skips the loop over steps: its end state and Jacobian equal
    the first step of a looped two-step segment (to rounding)."""
    from vehsim.optimal.primitives import rally_gravel_car
    from vehsim.optimal.roads import road
    from vehsim.optimal.shooting import ManeuverOCP, _rk4_segment

    prob = ManeuverOCP(vehicle=rally_gravel_car(), road=road("corner90"), num_stages=4)
    x = jnp.array([2.0, 5.0, 0.1, 8.0, 0.3, 0.2, 0.05, -0.08, 0.1, 3.5])
    u = jnp.array([0.5, -0.2, 0.3])
    h = 0.05

    def one(x):
        end, starts = _rk4_segment(prob._rhs, x, u, h, 1)
        return end, starts

    def first_of_two(x):
        _, starts = _rk4_segment(prob._rhs, x, u, h, 2)
        return starts[1]

    end, starts = one(x)
    assert starts.shape == (1, 10) and np.array_equal(np.asarray(starts[0]), np.asarray(x))
    np.testing.assert_allclose(np.asarray(end), np.asarray(first_of_two(x)), rtol=1e-14,
                               atol=1e-14)
    assert not np.allclose(np.asarray(end), np.asarray(x))  # the step moves the state
    np.testing.assert_allclose(np.asarray(jax.jacfwd(lambda y: one(y)[0])(x)),
                               np.asarray(jax.jacfwd(first_of_two)(x)), rtol=1e-12, atol=1e-12)


def test_implicit_derivatives_of_the_optimum_are_the_closed_form(bang_bang):
    """``implicit=True``: d t_f / d(L, amax) of t_f = 2 sqrt(L / amax) by the implicit
    function theorem at the returned optimum, forward mode and reverse mode (which cannot
    run through the iteration loop), against the closed form 1/sqrt(L amax) and
    -sqrt(L) / amax^1.5."""
    prob, _ = bang_bang
    xs0, us0 = _guess(prob.num_stages)

    def t_final(L, amax):
        p = eqx.tree_at(lambda q: (q.L, q.amax), prob, (L, amax))
        return interior_point(p, xs0, us0, implicit=True).xs[-1, 4]

    L, a = jnp.asarray(10.0), jnp.asarray(5.0)
    exact = np.array([1.0 / np.sqrt(10.0 * 5.0), -np.sqrt(10.0) / 5.0**1.5])
    forward = [jax.jvp(t_final, (L, a), t)[1] for t in ((1.0, 0.0), (0.0, 1.0))]
    np.testing.assert_allclose(np.asarray(forward), exact, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(jax.grad(t_final, argnums=(0, 1))(L, a)), exact,
                               rtol=1e-6)

    # through the iterations (implicit=False): forward mode differentiates the loop (here
    # converged, so near the implicit derivative); reverse mode, which JAX cannot run through
    # a while loop, refuses with a message naming implicit=True, jitted or vmapped too
    def t_loop(L):
        p = eqx.tree_at(lambda q: q.L, prob, L)
        return interior_point(p, xs0, us0).xs[-1, 4]

    np.testing.assert_allclose(float(jax.jvp(t_loop, (L,), (1.0,))[1]), exact[0], rtol=1e-4)
    for derivative in (jax.grad(t_loop), jax.jit(jax.grad(t_loop)),
                       lambda L: jax.vmap(jax.grad(t_loop))(L[None])):
        with pytest.raises(TypeError, match="implicit=True"):
            derivative(L)

    # a solve stopped short of the optimum has no implicit derivative: a clear error in both
    # modes (jitted too), neither a NaN nor a number; its values are still returned
    def t_capped(L):
        p = eqx.tree_at(lambda q: q.L, prob, L)
        return interior_point(p, xs0, us0, IPOptions(max_iter=3), throw=False,
                              implicit=True).xs[-1, 4]

    assert np.isfinite(float(t_capped(L)))
    for derivative in (lambda L: jax.jvp(t_capped, (L,), (1.0,))[1], jax.grad(t_capped),
                       jax.jit(jax.grad(t_capped))):
        with pytest.raises(Exception, match="did not converge") as info:
            float(derivative(L))
        assert "max_iter" in str(info.value)


class EffortRestToRest(RestToRest):
    """`RestToRest` with an effort cost rho h |u|^2 per stage: the parameter enters the
    Lagrangian's gradient (no closed form: central differences)."""

    rho: jax.Array = eqx.field(converter=jnp.asarray, default=0.05)

    def stage_cost(self, x, u, k):
        return self.rho * x[4] / self.num_stages * (u @ u)


@pytest.mark.parametrize("output", ["final time", "objective"])
def test_implicit_derivative_of_a_cost_parameter_matches_finite_differences(output):
    """The final time (a state of the solution) and the objective (its total derivative
    along the solution's tangent, which ``implicit=True`` once left at 0)."""
    M = 12
    xs0, us0 = _guess(M)
    opts = IPOptions(tol=1e-11, constr_tol=1e-11)

    def value(rho):
        sol = interior_point(EffortRestToRest(num_stages=M, rho=rho), xs0, us0, opts,
                             implicit=True)
        return sol.xs[-1, 4] if output == "final time" else sol.objective

    rho = jnp.asarray(0.05)
    forward = float(jax.jvp(value, (rho,), (1.0,))[1])
    f = jax.jit(value)
    fd = [float(f(rho + h) - f(rho - h)) / (2 * h) for h in (1e-4, 2.5e-5)]
    assert abs(forward) > 0.1  # the effort slows the optimum down and costs
    assert fd[0] == pytest.approx(fd[1], rel=1e-5)
    assert forward == pytest.approx(fd[1], rel=1e-5)
    assert float(jax.grad(value)(rho)) == pytest.approx(forward, rel=1e-9)


def test_warm_start_of_the_multipliers(bang_bang):
    """From an optimum with its multipliers the solve has nothing left to do; a perturbed
    problem from them converges; z = 0 (no warm start for this problem) is the cold start
    (to rounding: another program)."""
    prob, sol = bang_bang
    duals = (sol.lam, sol.nu, sol.z)
    again = interior_point(prob, sol.xs, sol.us, IPOptions(mu0=1e-9), multipliers=duals)
    assert int(again.iterations) <= 1
    longer = eqx.tree_at(lambda q: q.L, prob, jnp.asarray(10.5))
    warm = interior_point(longer, sol.xs, sol.us, IPOptions(mu0=1e-5), multipliers=duals)
    assert float(warm.xs[-1, 4]) == pytest.approx(2 * np.sqrt(10.5 / 5.0), abs=1e-6)
    xs0, us0 = _guess(prob.num_stages)
    cold = interior_point(prob, xs0, us0, multipliers=(sol.lam, sol.nu, 0.0 * sol.z))
    np.testing.assert_allclose(np.asarray(cold.xs), np.asarray(sol.xs), rtol=0, atol=1e-12)
    assert int(cold.iterations) == int(sol.iterations)


def test_a_step_without_newton_direction_reestimates_the_multipliers(bang_bang, monkeypatch):
    """A pass whose inertia correction needed more than `DELTA_RESET` (forced here: the
    Newton step reports 1e10) leaves the next pass to re-estimate the defect and equality
    multipliers by least squares, with the regularisation restarted, unless
    ``reestimate_multipliers`` is off; an ordinary pass does neither."""
    from vehsim.optimal.ip import solver
    from vehsim.optimal.ip.problem import stage_layout

    prob, _ = bang_bang
    lay = stage_layout(prob)
    opts = IPOptions()
    st = solver._initial_state(prob, lay, *_guess(prob.num_stages), opts)
    st = solver._iteration(prob, lay, opts, st)  # the least-squares setup pass
    assert bool(st.multipliers_ready)
    ordinary = solver._iteration(prob, lay, opts, st)
    assert bool(ordinary.multipliers_ready) and float(ordinary.delta_last) < solver.DELTA_RESET
    newton = solver.newton_step
    monkeypatch.setattr(solver, "newton_step", lambda *a, **k: eqx.tree_at(
        lambda n: n.delta, newton(*a, **k), jnp.asarray(1e10)))
    forced = solver._iteration(prob, lay, opts, st)
    assert not bool(forced.multipliers_ready) and float(forced.delta_last) == 0.0
    again = solver._iteration(prob, lay, opts, forced)  # the setup pass: no step counted
    assert int(again.iteration) == int(forced.iteration)
    # switched off (an array: one program serves both), the same pass leaves the
    # multipliers to the Newton steps
    off = solver._iteration(prob, lay, IPOptions(reestimate_multipliers=jnp.asarray(False)), st)
    assert bool(off.multipliers_ready) and int(off.iteration) == int(st.iteration) + 1


def test_a_step_accepted_on_the_last_trial_is_not_a_failed_search(bang_bang, monkeypatch):
    """The trial count alone does not say whether the search failed: a step accepted on its
    last allowed trial (forced here) leaves the multipliers and the failure count alone."""
    from vehsim.optimal.ip import solver
    from vehsim.optimal.ip.linesearch import MAX_TRIALS
    from vehsim.optimal.ip.problem import stage_layout

    prob, _ = bang_bang
    lay = stage_layout(prob)
    opts = IPOptions()
    st = solver._initial_state(prob, lay, *_guess(prob.num_stages), opts)
    st = solver._iteration(prob, lay, opts, st)  # the least-squares setup pass
    search = solver.filter_line_search

    def on_the_last_trial(*a, **k):
        alpha, _, accepted, filt, direction = search(*a, **k)
        assert bool(accepted)
        return alpha, jnp.asarray(MAX_TRIALS), accepted, filt, direction

    monkeypatch.setattr(solver, "filter_line_search", on_the_last_trial)
    after = solver._iteration(prob, lay, opts, st)
    assert bool(after.multipliers_ready) and int(after.failed_searches) == 0


def test_a_fixed_work_solve_stops_when_its_line_search_stalls(bang_bang, monkeypatch):
    """Without the multipliers' re-estimate (a real-time iteration's fixed work), a pass
    whose line search accepts no trial is retried once (its filter forgotten); a second
    failure in a row ends the solve with `RESULTS.ip_line_search_failed` at the iterate it
    stalled at, instead of repeating the same failed step, with all its trials, until
    ``max_iter``. With the re-estimate the passes go on, and a pass that succeeds in between
    restarts the count."""
    from vehsim.optimal.ip import solver
    from vehsim.optimal.ip.linesearch import MAX_TRIALS

    prob, _ = bang_bang
    search = solver.filter_line_search
    fails = {"on": True}

    def failing(*args):
        alpha, n, accepted, filt, direction = search(*args)
        n = jnp.where(fails["on"], MAX_TRIALS, n)
        alpha = jnp.where(fails["on"], alpha * 2.0**-30, alpha)
        return alpha, n, accepted & (not fails["on"]), filt, direction

    monkeypatch.setattr(solver, "filter_line_search", failing)
    xs0, us0 = _guess(prob.num_stages)
    fixed = IPOptions(max_iter=12, reestimate_multipliers=False, log_size=17)  # its own program
    sol = interior_point(prob, xs0, us0, fixed, throw=False)
    assert sol.result == RESULTS.ip_line_search_failed and not sol.converged
    assert int(sol.iterations) == solver.STALLED_PASSES
    assert int(np.sum(np.asarray(sol.log.trials))) == solver.STALLED_PASSES * MAX_TRIALS
    with pytest.raises(RuntimeError, match="ip_line_search_failed|line search accepted no step"):
        interior_point(prob, xs0, us0, fixed)
    # with the re-estimate every pass is tried up to max_iter
    again = interior_point(prob, xs0, us0, IPOptions(max_iter=12, log_size=17), throw=False)
    assert again.result == RESULTS.ip_max_iterations and int(again.iterations) == 12
    # the rule pass by pass: fail, succeed, fail (not stalled), fail (stalled)
    lay = solver.stage_layout(prob)
    st = solver._initial_state(prob, lay, xs0, us0, fixed)
    done = []
    for on in (True, False, True, True):
        fails["on"] = on
        before = st.iterate.ys
        st = solver._iteration(prob, lay, fixed, st)
        done.append(bool(st.done))
    assert done == [False, False, False, True] and int(st.failed_searches) == 2
    # the stalled pass returns the point it started from (whose residuals it reports)
    np.testing.assert_array_equal(np.asarray(st.iterate.ys), np.asarray(before))
    assert st.result == RESULTS.ip_line_search_failed


class DoubleIntegrator(AbstractStagewiseNLP):
    """x = (position, speed) from (1, 0), acceleration u: quadratic costs; `bound` (None: no
    inequality at all) on |u|; `inverse_cost`: a cost 1/u with 0.5 <= u <= 3 instead, a
    function undefined at the dummy control u_M = 0 of the last knot."""

    num_stages: int = eqx.field(static=True)
    bound: float | None = eqx.field(static=True, default=None)
    inverse_cost: bool = eqx.field(static=True, default=False)
    state_size: int = eqx.field(static=True, default=2)
    control_size: int = eqx.field(static=True, default=1)

    def transition(self, x, u, k):
        return jnp.stack([x[0] + 0.1 * x[1], x[1] + 0.1 * u[0]])

    def stage_cost(self, x, u, k):
        return x @ x + (1.0 / u[0] if self.inverse_cost else 0.1 * u @ u)

    def terminal_cost(self, x):
        return 10.0 * x @ x

    def path_inequality(self, x, u, k):
        if self.inverse_cost:
            return jnp.stack([u[0] - 0.5, 3.0 - u[0]])
        if self.bound is None:
            return jnp.zeros((0,))
        return jnp.stack([self.bound - u[0], self.bound + u[0]])

    def initial_equality(self, x):
        return x - jnp.array([1.0, 0.0])


class Decay(AbstractStagewiseNLP):
    """No control: x_{k+1} = 0.9 x_k, cost sum_k (x_k - 2)^2 over the stages, x_0 free; the
    optimum x_0 = 2 sum a_k / sum a_k^2 with a_k = 0.9^k."""

    num_stages: int = eqx.field(static=True)
    state_size: int = eqx.field(static=True, default=1)
    control_size: int = eqx.field(static=True, default=0)

    def transition(self, x, u, k):
        return 0.9 * x

    def stage_cost(self, x, u, k):
        return (x[0] - 2.0) ** 2

    def path_inequality(self, x, u, k):
        return jnp.stack([x[0] + 5.0])


class SquareRootExit(AbstractStagewiseNLP):
    """From x_0 = 0, u_k in [0, 1]: maximise sqrt(x_M) against the effort, a terminal
    cost undefined (infinite slope) at the fixed first knot."""

    num_stages: int = eqx.field(static=True)
    state_size: int = eqx.field(static=True, default=1)
    control_size: int = eqx.field(static=True, default=1)

    def transition(self, x, u, k):
        return x + 0.1 * u

    def stage_cost(self, x, u, k):
        return u @ u

    def terminal_cost(self, x):
        return -jnp.sqrt(x[0])

    def path_inequality(self, x, u, k):
        return jnp.stack([u[0], 1.0 - u[0]])

    def initial_equality(self, x):
        return x


class LinearBudget(SquareRootExit):
    """A linear program on `SquareRootExit`'s dynamics, bounds and start: x_M >= 0.5,
    minimise sum u_k (optimum 5); every variable declared linear."""

    def stage_cost(self, x, u, k):
        return u[0]

    def terminal_cost(self, x):
        return jnp.zeros(())

    def terminal_inequality(self, x):
        return x - 0.5

    def linear_variables(self):
        return (0, 1)


def test_a_problem_linear_in_every_variable_has_no_hessian_and_solves():
    """`linear_variables` naming every variable (a linear program): the stage derivatives
    take no second-derivative pass (the Hessian zero, the Jacobians those of the full
    computation) and the interior point reaches the optimum, 5; a problem that declares a
    variable it curves along (the double integrator's control, in a quadratic cost) is
    refused by `check_linear_variables`."""
    from vehsim.optimal.ip import derivatives as dv
    from vehsim.optimal.ip.problem import curved_variables, stage_layout

    M = 8
    lp = LinearBudget(num_stages=M)
    lay = stage_layout(lp)
    assert curved_variables(lp, lay) == ()
    ys = jnp.asarray(np.random.default_rng(0).uniform(0.1, 0.9, (M + 1, 2)))
    lam, nu, z = (jnp.ones((M + 1, n)) for n in (lay.nx, lay.ne, lay.ng))
    d = dv.stage_derivatives(lp, lay, ys, lam, nu, z)
    full = dv.stage_derivatives(lp, lay, ys, lam, nu, z, hessian="forward-over-forward")
    assert float(jnp.max(jnp.abs(d.H))) == 0.0 == float(jnp.max(jnp.abs(full.H)))
    for name in ("A", "Je", "Jg", "grad_f", "c", "g"):
        np.testing.assert_array_equal(np.asarray(getattr(d, name)), np.asarray(getattr(full,
                                                                                      name)))
    dv.check_linear_variables(lp, ys)
    sol = interior_point(lp, jnp.zeros((M + 1, 1)), jnp.full((M, 1), 0.5), IPOptions())
    assert float(sol.objective) == pytest.approx(5.0, abs=1e-6)

    class Curved(DoubleIntegrator):
        def linear_variables(self):
            return (2,)  # the control u: its cost 0.1 u^2 curves

    bad = Curved(num_stages=M)
    with pytest.raises(ValueError, match=r"declares y\[2\], but the stage functions curve"):
        dv.check_linear_variables(bad, jnp.ones((M + 1, 3)))


def test_problems_without_inequalities_or_controls_solve():
    M = 10
    free = interior_point(DoubleIntegrator(num_stages=M), jnp.zeros((M + 1, 2)),
                          jnp.zeros((M, 1)))
    loose = interior_point(DoubleIntegrator(num_stages=M, bound=100.0), jnp.zeros((M + 1, 2)),
                           jnp.zeros((M, 1)))  # the same optimum, its bound inactive
    assert free.converged and loose.converged
    np.testing.assert_allclose(np.asarray(free.us), np.asarray(loose.us), atol=1e-7)
    sol = interior_point(Decay(num_stages=5), jnp.zeros((6, 1)), jnp.zeros((5, 0)))
    a = 0.9 ** np.arange(5)
    assert sol.converged
    assert float(sol.xs[0, 0]) == pytest.approx(2.0 * a.sum() / (a @ a), rel=1e-9)


@pytest.mark.parametrize("case", ["inverse stage cost", "square-root terminal cost"])
def test_functions_undefined_where_they_are_masked_keep_the_hessian_finite(case):
    """The stage functions at the last knot (dummy control 0) and the terminal ones at the
    first knot are masked; evaluated there, 1/u and sqrt(x) have infinite slopes, which a
    reverse-mode Hessian multiplied by the mask's zero (NaN). Both Hessian modes solve."""
    M = 10
    if case == "inverse stage cost":
        prob, guess = DoubleIntegrator(num_stages=M, inverse_cost=True), (
            jnp.zeros((M + 1, 2)), jnp.ones((M, 1)))
    else:
        prob, guess = SquareRootExit(num_stages=M), (
            jnp.full((M + 1, 1), 0.5).at[0].set(0.0), jnp.full((M, 1), 0.5))
    sols = [interior_point(prob, *guess, IPOptions(hessian=h), throw=False)
            for h in ("forward-over-reverse", "forward-over-forward")]
    assert all(s.result == RESULTS.successful for s in sols), [s.message for s in sols]
    assert float(sols[0].objective) == pytest.approx(float(sols[1].objective), rel=1e-9)
    assert int(sols[0].iterations) < 30


def test_a_refined_solve_is_accepted_up_to_the_singular_backward_error(monkeypatch):
    """Every Newton solve made inaccurate on purpose (a relative error of 3e-3: one step of
    refinement leaves a backward error near 1e-6): the default acceptance (IPOPT's 1e-5)
    converges to the exact solve's optimum; ``backward_error_singular=1e-10`` with one
    refinement step refuses every factorisation, and with IPOPT's 10 steps (each gains the
    same factor) accepts them."""
    from vehsim.optimal.ip import kkt

    class Inaccurate(DoubleIntegrator):  # a program of its own: the patch is traced into it
        pass

    M = 6
    args = (jnp.zeros((M + 1, 2)), jnp.zeros((M, 1)))
    ref = interior_point(DoubleIntegrator(num_stages=M, bound=1.0), *args)
    exact_solve = kkt.riccati_solve
    monkeypatch.setattr(kkt, "riccati_solve", lambda F, K, b: exact_solve(F, K, b) * (1 + 3e-3))
    sol = interior_point(Inaccurate(num_stages=M, bound=1.0), *args, throw=False)
    assert sol.result == RESULTS.successful
    assert float(sol.objective) == pytest.approx(float(ref.objective), rel=1e-8)
    strict = interior_point(Inaccurate(num_stages=M, bound=1.0), *args,
                            IPOptions(backward_error_singular=1e-10, max_refinement_steps=1),
                            throw=False)
    assert strict.result == RESULTS.ip_newton_system_failed
    refined = interior_point(Inaccurate(num_stages=M, bound=1.0), *args,
                             IPOptions(backward_error_singular=1e-10), throw=False)
    assert refined.result == RESULTS.successful
    assert float(refined.objective) == pytest.approx(float(ref.objective), rel=1e-8)


def test_refinement_recovers_the_row_a_periodic_lap_s_riccati_solve_misses(default_codegen):
    """The KKT system of a periodic lap (the oval of tests/test_optimal_curvilinear.py, 50
    stages, pass 200 of its solve under the command line's code generator; the 9 rows of the
    periodic end are condensed with $-\\delta_c$, and the last stage has 3 controls) is
    ill-conditioned at the regularisation 0.01, where its inertia is right. Under the command
    line's code generator the Riccati solve missed one row of the third stage from the end (a
    backward error of 0.7 on the machine that recorded it, 1e-6 under XLA's default) and one
    refinement step left 7e-5, above IPOPT's 1e-5, so the regularisation grew to 3-30 and
    the solve crept. Refined as IPOPT refines (up to 10 steps), the solve is accepted and
    agrees with a dense LU solve of the same matrix."""
    from vehsim.optimal.ip import kkt

    data = np.load(Path(__file__).parent / "data" / "periodic_oval_kkt_pass_200.npz")
    delta = 0.01
    W = data["W0"] + delta * np.einsum("ki,ij->kij", data["y_mask"], np.eye(data["W0"].shape[1]))
    K = KKTMatrix(W=jnp.asarray(W), A=jnp.asarray(data["A"]), Je=jnp.asarray(data["Je"]),
                  dl=jnp.asarray(data["dl"]), de=jnp.asarray(data["de"]))
    rhs = jnp.asarray(data["rhs"])
    # the dense peer: K assembled column by column from its block products, then LU
    n = rhs.size
    cols = [np.asarray(K.matvec(jnp.asarray(np.eye(n)[j].reshape(rhs.shape)))).ravel()
            for j in range(n)]
    dense = np.linalg.solve(np.stack(cols, 1), np.asarray(rhs).ravel()).reshape(rhs.shape)

    def solves(K, rhs):
        first = riccati_solve(riccati_factor(K), K, rhs)
        one = kkt.checked_solve(None, K, rhs, kkt.BACKWARD_ERROR_SINGULAR, steps=1)
        ten = kkt.checked_solve(None, K, rhs, kkt.BACKWARD_ERROR_SINGULAR,
                                steps=kkt.MAX_REFINEMENT_STEPS)
        return (kkt._backward_error(K, first, rhs)[0], one[0], kkt._backward_error(K, one[0], rhs)[0],
                ten[0], ten[1], kkt._backward_error(K, ten[0], rhs)[0], ten[2].ok)

    # the command line's code generation (the suite's LLVM passes back on)
    program = jax.jit(solves).lower(K, rhs).compile(compiler_options=default_codegen)
    first_error, _, one_error, sol, ok, error, inertia = program(K, rhs)
    assert bool(inertia)
    assert float(first_error) > 1e-8  # ill-conditioned: an accurate solve's is 1e-16
    assert bool(ok) and float(error) <= min(float(one_error), kkt.BACKWARD_ERROR_SINGULAR)
    assert np.max(np.abs(np.asarray(sol) - dense)) <= 1e-6 * np.max(np.abs(dense))


def test_refinement_stops_at_the_floor_and_keeps_its_most_accurate_solution(monkeypatch):
    """`checked_solve`'s refinement loop, its solves made inexact on purpose (each a fraction
    of the exact correction, so each step scales the residual by a known factor), and the
    backward error it measures them by (of x = 0: exactly 1):
    - a solve that returns 0.9 of the exact correction leaves a tenth of the residual per
      step; the loop stops at the first step whose backward error is at the floor
      (`BACKWARD_ERROR_TOL`), not at its step limit;
    - a solve that overshoots once the residual is small (3 times the correction: the
      residual doubles and flips sign) ends the loop there, and the solution returned is the
      step before it, the most accurate one, not the last."""
    from vehsim.optimal.ip import kkt

    # the periodic lap's KKT blocks, its end's equality rows regularised by -1 instead of
    # -1e-9 and its primal ones by 1: well conditioned, a Riccati solve exact to rounding
    data = np.load(Path(__file__).parent / "data" / "periodic_oval_kkt_pass_200.npz")
    W = data["W0"] + np.einsum("ki,ij->kij", data["y_mask"], np.eye(data["W0"].shape[1]))
    K = KKTMatrix(W=jnp.asarray(W), A=jnp.asarray(data["A"]), Je=jnp.asarray(data["Je"]),
                  dl=jnp.asarray(data["dl"]), de=-jnp.ones_like(jnp.asarray(data["de"])))
    rhs = jnp.asarray(data["rhs"])
    exact = kkt.riccati_solve(kkt.riccati_factor(K), K, rhs)
    assert float(kkt._backward_error(K, exact, rhs)[0]) < 1e-13
    # the Oettli-Prager scale |K||x| + |b| counts |b|: x = 0 leaves the residual b, an error
    # of exactly 1 (|K||x| alone would be 0 there)
    assert float(jnp.max(jnp.abs(rhs))) != 1.0
    assert float(kkt._backward_error(K, jnp.zeros_like(rhs), rhs)[0]) == 1.0
    exact_solve = kkt.riccati_solve
    floor = kkt.backward_error_tol(rhs.dtype)

    def refined(fraction):
        monkeypatch.setattr(kkt, "riccati_solve",
                            lambda F, K, b: fraction(b) * exact_solve(F, K, b))
        sol, ok, _ = kkt.checked_solve(None, K, rhs, 1e-5, steps=kkt.MAX_REFINEMENT_STEPS)
        return sol, bool(ok), float(kkt._backward_error(K, sol, rhs)[0])

    first = float(kkt._backward_error(K, 0.9 * exact, rhs)[0])
    steps = int(np.ceil(np.log10(first / floor)))  # a tenth per step: the first at the floor
    assert 1 < steps < kkt.MAX_REFINEMENT_STEPS  # the limit would refine further
    sol, ok, error = refined(lambda b: 0.9)
    # (the backward error's scale |K||x| + |b| grows by a ninth as x nears the solution)
    assert ok and error == pytest.approx(first * 0.1 ** steps, rel=0.15)
    assert 0.1 * floor < error <= floor

    big = float(jnp.max(jnp.abs(rhs)))  # the first solve's residual is 0.1 of it, the next 0.01
    sol, ok, error = refined(lambda b: jnp.where(jnp.max(jnp.abs(b)) > 0.05 * big, 0.9, 3.0))
    assert error == pytest.approx(0.1 * first, rel=0.15)  # one step in: the best
    overshot = float(kkt._backward_error(K, sol + 3.0 * exact_solve(
        kkt.riccati_factor(K), K, rhs - K.matvec(sol)), rhs)[0])
    assert overshot == pytest.approx(2.0 * error, rel=0.15)  # the step after it, not kept
    assert not ok  # 4e-3 or so, above the accepted 1e-5


def test_a_newton_system_no_regularisation_solves_ends_the_solve(monkeypatch):
    """Every factorisation refused (forced: no solve is accurate enough): the solve stops
    on its first pass with `ip_newton_system_failed`, not at its iteration limit."""
    from vehsim.optimal.ip import kkt

    class Refused(DoubleIntegrator):  # a program of its own: the patch is traced into it
        pass

    monkeypatch.setattr(kkt, "backward_error_tol", lambda dtype: 0.0)
    M = 6
    refused = IPOptions(backward_error_singular=1e-300)
    sol = interior_point(Refused(num_stages=M, bound=1.0), jnp.zeros((M + 1, 2)),
                         jnp.zeros((M, 1)), refused, throw=False)
    assert sol.result == RESULTS.ip_newton_system_failed
    assert int(sol.iterations) <= 1
    assert int(sol.log.factorisations[0]) == kkt.MAX_FACTORISATIONS
    with pytest.raises(RuntimeError, match="could not solve its Newton system"):
        interior_point(Refused(num_stages=M, bound=1.0), jnp.zeros((M + 1, 2)),
                       jnp.zeros((M, 1)), refused)


def test_a_float32_solve_accepts_the_backward_error_of_its_precision():
    M = 10
    ref = interior_point(DoubleIntegrator(num_stages=M, bound=1.0), jnp.zeros((M + 1, 2)),
                         jnp.zeros((M, 1)))
    jax.config.update("jax_enable_x64", False)
    try:
        sol = interior_point(DoubleIntegrator(num_stages=M, bound=1.0), jnp.zeros((M + 1, 2)),
                             jnp.zeros((M, 1)), IPOptions(tol=1e-4, constr_tol=1e-4),
                             throw=False)
        assert sol.xs.dtype == jnp.float32
        assert sol.result == RESULTS.successful, sol.message
        assert int(sol.iterations) < 20
        assert float(sol.objective) == pytest.approx(float(ref.objective), rel=1e-4)
    finally:
        jax.config.update("jax_enable_x64", True)
