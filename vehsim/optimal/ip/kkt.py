r"""The primal-dual iterate, the KKT residuals and the Newton step on the condensed KKT system.

Inequalities get slacks, $g(y) - s = 0$, $s > 0$, and the barrier problem's primal-dual
equations $S z = \mu e$. Eliminating $(\Delta s, \Delta z)$ condenses them into the stage
blocks: with $\Sigma = S^{-1} Z$ the primal block is $W = H + J_g^T \Sigma J_g$ and

$$\begin{pmatrix} W + \delta I & -A^T & J_e^T \\ -A & 0 & 0 \\ J_e & 0 &
-\delta_c I \end{pmatrix}
\begin{pmatrix} \Delta y \\ \Delta\lambda \\ \Delta\nu \end{pmatrix} = -
\begin{pmatrix} \nabla_y \mathcal{L}_\mu \\ c \\ e \end{pmatrix}$$

per stage, coupled to the next stage by the defects (`block_tridiagonal`), and factored by
the Riccati recursion (`riccati`); then
$\Delta s = J_g \Delta y + g - s$ and $\Delta z = \mu S^{-1} e - z - \Sigma \Delta s$.
The defects need no dual regularisation (the recursion eliminates them exactly); the
boundary equalities get $\delta_c$. The inertia correction is IPOPT's (Wächter and Biegler
2006): $\delta$ grows until the matrix has exactly one negative eigenvalue per multiplier row
(padded rows included; the recursion's Cholesky factors all exist) and the solve is
accurate.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ._carry import strong
from .block_tridiagonal import KKTMatrix
from .derivatives import StageDerivatives
from .problem import StageLayout
from .riccati import RiccatiFactor, riccati_factor, riccati_solve


S_MAX = 100.0
"""Scaling threshold of the multipliers in the scaled KKT error (IPOPT's $s_{max}$)."""
DELTA_C = 1e-9
"""Regularisation of the boundary-equality rows ($-\\delta_c I$)."""
DELTA_FIRST = 1e-4
"""First primal regularisation tried when none was needed before."""
DELTA_MIN = 1e-20
"""Smallest first regularisation tried (the last one, divided by `DELTA_DECREASE`)."""
DELTA_DECREASE = 3.0
DELTA_GROWTH_FIRST = 100.0
"""Growth factor of the regularisation while no regularisation was needed before."""
DELTA_GROWTH = 8.0
MAX_FACTORISATIONS = 40
MULTIPLIER_INIT_MAX = 1e3
"""Largest accepted least-squares initial multiplier (IPOPT's ``constr_mult_init_max``)."""
BACKWARD_ERROR_TOL = 1e-10
"""Componentwise backward error (Oettli-Prager) below which a first solve is not refined,
in float64; in a lower precision, 1000 times its machine epsilon where that is larger
(IPOPT's ``residual_ratio_max``)."""
BACKWARD_ERROR_SINGULAR = 1e-5
"""Largest componentwise backward error of a refined solve that is accepted (IPOPT's
``residual_ratio_singular``, the default of `IPOptions.backward_error_singular`): above it
the factor counts as singular and the regularisation grows."""
MAX_REFINEMENT_STEPS = 10
"""Most steps of iterative refinement of a Newton solve (IPOPT's ``max_refinement_steps``,
the default of `IPOptions.max_refinement_steps`)."""
REFINEMENT_IMPROVEMENT = 0.999999999
"""Refinement stops at a step that does not bring the backward error below this fraction
of the last one (IPOPT's ``residual_improvement_factor``)."""


class Iterate(eqx.Module):
    """A primal-dual point: unknowns ``ys`` $(x_k, u_k)$, slacks ``s``, inequality multipliers
    ``z``, defect multipliers ``lam`` and equality multipliers ``nu``, per knot."""

    ys: Float[Array, "M+1 ny"]
    s: Float[Array, "M+1 ng"]
    z: Float[Array, "M+1 ng"]
    lam: Float[Array, "M+1 nx"]
    nu: Float[Array, "M+1 ne"]


class Residuals(eqx.Module):
    r"""Optimality measures of an iterate: ``inf_pr`` max constraint violation, ``inf_du`` max
    Lagrangian-gradient entry, ``compl`` max complementarity $|s z|$, ``error`` the scaled KKT
    error (convergence test), and its parts that do not depend on the complementarity (the
    barrier problem's error follows from them, `barrier_error`): ``optimality``
    $\max(\text{inf\_du}/s_d, \text{inf\_pr})$ and the complementarity scale ``s_c``."""

    inf_pr: Float[Array, ""]
    inf_du: Float[Array, ""]
    compl: Float[Array, ""]
    error: Float[Array, ""]
    optimality: Float[Array, ""]
    s_c: Float[Array, ""]


def barrier_error(lay: StageLayout, it: Iterate, res: Residuals, mu) -> Float[Array, ""]:
    r"""The scaled KKT error $E_\mu$ of the barrier problem for another ``mu`` at the same
    iterate (the complementarity part alone depends on $\mu$)."""
    mg = lay.masks().g
    compl_mu = jnp.max(jnp.abs((it.s * it.z - mu) * mg), initial=0.0)
    return jnp.maximum(res.optimality, compl_mu / res.s_c)


class NewtonStep(eqx.Module):
    """A primal-dual Newton direction, the primal regularisation ``delta`` it took, the
    number of ``factorisations`` the inertia correction tried, and the accepted ``matrix``
    with its ``factor`` (for the second-order correction); ``solved`` is false where no
    regularisation up to the last (`MAX_FACTORISATIONS`) was accepted (the direction is
    then zero)."""

    dy: Float[Array, "M+1 ny"]
    dlam: Float[Array, "M+1 nx"]
    dnu: Float[Array, "M+1 ne"]
    ds: Float[Array, "M+1 ng"]
    dz: Float[Array, "M+1 ng"]
    delta: Float[Array, ""]
    factorisations: Int[Array, ""]
    factor: RiccatiFactor
    matrix: KKTMatrix
    solved: Bool[Array, ""]


class InertiaCorrection(eqx.Module):
    """Loop state of the inertia correction (`_regularised_solve`): the regularisation
    ``delta`` tried last, the KKT ``solution`` it gave, whether that was accepted (``ok``),
    the number of ``factorisations`` so far, and the last ``factor`` and ``matrix``."""

    delta: Float[Array, ""]
    solution: Float[Array, "M+1 nb"]
    ok: Bool[Array, ""]
    factorisations: Int[Array, ""]
    factor: RiccatiFactor
    matrix: KKTMatrix


def kkt_residuals(lay: StageLayout, it: Iterate, d: StageDerivatives) -> Residuals:
    """Residuals and the scaled KKT error $E_0$ (IPOPT's, Wächter and Biegler 2006): dual
    infeasibility scaled by $s_d$, complementarity by $s_c$ (`barrier_error` gives
    $E_\\mu$ from them)."""
    mk = lay.masks()
    M, nx, ne = lay.M, lay.nx, lay.ne
    lam, nu, z, s = it.lam, it.nu, it.z, it.s
    # Lagrangian gradient per stage: grad f + Je' nu - A' lam - Jg' z + [lam_{k-1} on x_k]
    rd = (
        d.grad_f
        + jnp.einsum("kij,ki->kj", d.Je, nu * mk.eq)
        - jnp.einsum("kij,ki->kj", d.A, lam * mk.lam)
        - jnp.einsum("kij,ki->kj", d.Jg, z * mk.g)
    )
    rd = rd.at[1:, :nx].add(lam[:-1] * mk.lam[:-1])
    rd = rd * mk.y
    inf_du = jnp.max(jnp.abs(rd))
    inf_pr = jnp.maximum(
        jnp.maximum(jnp.max(jnp.abs(d.c)), jnp.max(jnp.abs(d.e), initial=0.0)),
        jnp.max(jnp.abs((d.g - s) * mk.g), initial=0.0),
    )
    compl0 = jnp.max(jnp.abs((s * z) * mk.g), initial=0.0)
    n_mult = (M + 1) * (nx + ne) + jnp.sum(mk.g)
    s_d = jnp.maximum(
        S_MAX,
        (jnp.sum(jnp.abs(lam)) + jnp.sum(jnp.abs(nu)) + jnp.sum(jnp.abs(z * mk.g))) / n_mult,
    ) / S_MAX
    s_c = jnp.maximum(S_MAX, jnp.sum(jnp.abs(z * mk.g)) / jnp.maximum(jnp.sum(mk.g), 1.0)) / S_MAX
    base = jnp.maximum(inf_du / s_d, inf_pr)
    return Residuals(inf_pr=inf_pr, inf_du=inf_du, compl=compl0,
                     error=jnp.maximum(base, compl0 / s_c), optimality=base, s_c=s_c)


def _condensed_rhs(lay: StageLayout, it: Iterate, d: StageDerivatives, mu, c, e, gs):
    """Right-hand side of the condensed system for the constraint residuals `c` (defects),
    `e` (equalities) and `gs` ($g - s$)."""
    mk = lay.masks()
    nx, mg, um = lay.nx, mk.g, mk.y
    sg = jnp.where(mg > 0, it.s, 1.0)
    Sigma = jnp.where(mg > 0, it.z / sg, 0.0)
    rhs_y = -(
        d.grad_f
        + jnp.einsum("kij,ki->kj", d.Je, it.nu)
        - jnp.einsum("kij,ki->kj", d.A, it.lam * mk.lam)
    )
    rhs_y = rhs_y.at[1:, :nx].add(-it.lam[:-1] * mk.lam[:-1])
    rhs_y = rhs_y + jnp.einsum("kij,ki->kj", d.Jg, (mu / sg - Sigma * gs) * mg)
    rhs_y = rhs_y * um
    return jnp.concatenate([rhs_y, -c, -e], axis=1)


def _condensed_system(lay: StageLayout, it: Iterate, d: StageDerivatives, mu):
    """Right-hand side and primal blocks $W = H + J_g^T \\Sigma J_g$ of the condensed system
    (rows and columns of unused controls set to the identity)."""
    mk = lay.masks()
    mg, um = mk.g, mk.y
    Sigma = jnp.where(mg > 0, it.z / jnp.where(mg > 0, it.s, 1.0), 0.0)
    rhs = _condensed_rhs(lay, it, d, mu, d.c, d.e, d.g - it.s)
    W0 = d.H + jnp.einsum("kij,ki,kil->kjl", d.Jg, Sigma, d.Jg)
    W0 = W0 * um[:, :, None] * um[:, None, :] + jax.vmap(jnp.diag)(1.0 - um)
    return rhs, W0


def kkt_matrix(lay: StageLayout, W0, d: StageDerivatives, delta) -> KKTMatrix:
    """The KKT matrix with primal regularisation ``delta``: the defects exactly (no dual
    regularisation, their Jacobian has full row rank), the boundary equalities with
    $-\\delta_c$, and $-1$ on the diagonal of unused multiplier rows."""
    mk = lay.masks()
    Wd = W0 + delta * jax.vmap(jnp.diag)(mk.y)
    dl = jnp.where(mk.lam > 0, 0.0, -1.0)
    de = jnp.where(mk.eq > 0, -DELTA_C, -1.0)
    return KKTMatrix(W=Wd, A=d.A, Je=d.Je, dl=dl, de=de)


def _least_squares_system(lay: StageLayout, d: StageDerivatives, z):
    r"""Right-hand side and primal blocks ($W = I$) of the KKT system whose multiplier part
    is IPOPT's least-squares estimate: the $(\lambda, \nu)$ that minimise the Lagrangian
    gradient $\|\nabla f + J_e^T\nu - A^T\lambda + E^T\lambda_{-} - J_g^T z\|$ for the
    inequality multipliers ``z`` (Wächter and Biegler 2006, sec. 3.6)."""
    mk = lay.masks()
    ry = -(d.grad_f - jnp.einsum("kij,ki->kj", d.Jg, z * mk.g)) * mk.y
    rhs = jnp.concatenate([ry, jnp.zeros((lay.M + 1, lay.nx + lay.ne))], axis=1)
    return rhs, jnp.broadcast_to(jnp.eye(lay.ny), d.H.shape)


def capped_multipliers(lam, nu):
    """Least-squares multipliers, or zero where an entry exceeds `MULTIPLIER_INIT_MAX` (an
    unreliable estimate)."""
    use = jnp.maximum(jnp.max(jnp.abs(lam)), jnp.max(jnp.abs(nu))) <= MULTIPLIER_INIT_MAX
    return jnp.where(use, lam, 0.0), jnp.where(use, nu, 0.0)


def _refined_solve(F: RiccatiFactor, K: KKTMatrix, rhs):
    """$K^{-1}$ ``rhs`` by the factor ``F``, with one step of iterative refinement."""
    sol = riccati_solve(F, K, rhs)
    return sol + riccati_solve(F, K, rhs - K.matvec(sol))


def _split_step(lay: StageLayout, d: StageDerivatives, sol, g, s):
    """``(dy, ds, dlam, dnu)`` of a KKT solution, $\\Delta s = J_g\\Delta y + g - s$ with
    the inequality residual $g - s$ it was solved for."""
    mk = lay.masks()
    ny, nx = lay.ny, lay.nx
    dy = sol[:, :ny] * mk.y
    ds = (jnp.einsum("kij,kj->ki", d.Jg, dy) + g - s) * mk.g
    return dy, ds, sol[:, ny : ny + nx] * mk.lam, sol[:, ny + nx :] * mk.eq


def _backward_error_ok(K: KKTMatrix, sol, rhs, tol: float | None = None):
    """Whether the componentwise backward error (Oettli-Prager) of ``sol`` is below ``tol``
    (default `BACKWARD_ERROR_TOL` for the residual's precision; never below it); also the
    residual."""
    res, largest, scale = _residual_and_scale(K, sol, rhs)
    floor = backward_error_tol(res.dtype)
    tol = floor if tol is None else max(tol, floor)
    return largest <= tol * scale, res


def backward_error_tol(dtype) -> float:
    """`BACKWARD_ERROR_TOL`, or 1000 machine epsilons of ``dtype`` where that is larger (a
    float32 solve cannot reach 1e-10)."""
    return max(BACKWARD_ERROR_TOL, 1e3 * float(jnp.finfo(dtype).eps))


def _residual_and_scale(K: KKTMatrix, sol, rhs):
    """The residual $r = b - K\\,x$ of ``sol``, $\\max|r|$ and the largest entry of the
    Oettli-Prager scale $|K||x| + |b|$ (the componentwise backward error is their ratio)."""
    res = rhs - K.matvec(sol)
    return res, jnp.max(jnp.abs(res)), jnp.max(K.matvec(sol, absolute=True) + jnp.abs(rhs))


def _backward_error(K: KKTMatrix, sol, rhs):
    """The componentwise backward error (Oettli-Prager) of ``sol`` and its residual."""
    res, largest, scale = _residual_and_scale(K, sol, rhs)
    return largest / jnp.where(scale > 0, scale, 1.0), res


def checked_solve(lay: StageLayout, K: KKTMatrix, rhs, singular: float | None = None,
                  steps: int = 1):
    """Factor and solve; ``ok`` when the inertia is the expected one (every Cholesky factor
    of the Riccati recursion exists) and the solve is accurate: a first solve whose
    componentwise backward error (Oettli-Prager) is below `BACKWARD_ERROR_TOL`, or else up
    to ``steps`` steps of iterative refinement, as IPOPT refines: until that error is below
    `BACKWARD_ERROR_TOL` or a step no longer reduces it (`REFINEMENT_IMPROVEMENT`), the
    most accurate solution kept and accepted where its error is below ``singular`` (default
    `BACKWARD_ERROR_TOL` too). A factor of the wrong inertia is not used for a solve.

    One step suffices where the factor is accurate. A terminal equality of more rows than the
    last stage has controls (a periodic lap's end, condensed with $-\\delta_c$) makes the
    Riccati recursion's last stages ill-conditioned: the first solve can then miss a row
    entirely, and each step gains a few digits."""
    F = riccati_factor(K)

    def refine(sol, res):
        if steps == 1:
            sol = sol + riccati_solve(F, K, res)
            return sol, _backward_error_ok(K, sol, rhs, singular)[0]
        floor = backward_error_tol(res.dtype)

        def more(c):
            _, _, error, last, n, _, _ = c
            return (n < steps) & (error > floor) & (error < REFINEMENT_IMPROVEMENT * last)

        def step(c):
            sol, res, error, _, n, best, best_error = c
            sol = sol + riccati_solve(F, K, res)
            new_error, res = _backward_error(K, sol, rhs)
            better = new_error < best_error
            return (sol, res, new_error, error, n + 1, jnp.where(better, sol, best),
                    jnp.where(better, new_error, best_error))

        error, _ = _backward_error(K, sol, rhs)
        inf = jnp.asarray(jnp.inf, error.dtype)
        c = jax.lax.while_loop(more, step, (sol, res, error, inf, 0, sol, error))
        best, best_error = c[5], c[6]
        tol = floor if singular is None else max(singular, floor)
        return best, best_error <= tol

    def solve():
        sol = riccati_solve(F, K, rhs)
        accurate, res = _backward_error_ok(K, sol, rhs)
        return jax.lax.cond(accurate, lambda: (sol, accurate), lambda: refine(sol, res))

    sol, accurate = jax.lax.cond(
        F.ok, solve, lambda: (jnp.zeros_like(rhs), jnp.asarray(False)))
    ok = F.ok & accurate & jnp.all(jnp.isfinite(sol))
    return sol, ok, F


def _regularised_solve(lay: StageLayout, W0, d: StageDerivatives, rhs,
                       delta_last, try_zero=True, singular=None,
                       refinement_steps: int = 1) -> InertiaCorrection:
    """Inertia correction: $\\delta = 0$ first (unless ``try_zero`` is false), then
    `DELTA_FIRST` (or the last $\\delta$ over `DELTA_DECREASE`), growing until
    `checked_solve` accepts (at most `MAX_FACTORISATIONS`; ``singular``: its refined solve's
    largest backward error, after at most ``refinement_steps`` steps); the final loop state."""
    d_first = jnp.where(
        delta_last == 0.0, DELTA_FIRST, jnp.maximum(DELTA_MIN, delta_last / DELTA_DECREASE)
    )
    growth = jnp.where(delta_last == 0.0, DELTA_GROWTH_FIRST, DELTA_GROWTH)

    def cond(st: InertiaCorrection):
        return (~st.ok) & (st.factorisations < MAX_FACTORISATIONS)

    def body(st: InertiaCorrection) -> InertiaCorrection:
        n = st.factorisations
        i = n + jnp.where(try_zero, 0, 1)  # the place in the sequence 0, d_first, ...
        delta = jnp.where(i == 0, 0.0, jnp.where(i == 1, d_first, st.delta * growth))
        K = kkt_matrix(lay, W0, d, delta)
        sol, ok, F = checked_solve(lay, K, rhs, singular, refinement_steps)
        return InertiaCorrection(delta=delta, solution=sol, ok=ok, factorisations=n + 1,
                                 factor=F, matrix=K)

    K0 = kkt_matrix(lay, W0, d, 0.0)
    shapes = jax.eval_shape(riccati_factor, K0)
    F0 = jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), shapes)
    delta0, sol0, ok0, n0 = strong((0.0, jnp.zeros((lay.M + 1, lay.nb)), False, 0))
    init = InertiaCorrection(delta=delta0, solution=sol0, ok=ok0, factorisations=n0,
                             factor=F0, matrix=K0)
    return jax.lax.while_loop(cond, body, init)


def newton_step(lay: StageLayout, it: Iterate, d: StageDerivatives, mu, delta_last,
                least_squares=False, try_zero=True, singular=None,
                refinement_steps: int = 1) -> NewtonStep:
    """The primal-dual Newton direction at ``it`` for barrier ``mu``, with the smallest
    regularisation that gives the right inertia (``delta_last``: the previous one;
    ``try_zero``: a traced flag, false to start from ``delta_last`` over `DELTA_DECREASE`
    where $\\delta = 0$ is known to fail; ``singular``: the largest backward error of a
    refined solve, after at most ``refinement_steps`` steps, `checked_solve`).

    Where ``least_squares`` (a traced flag), the same factorisation solves the system of
    `_least_squares_system` instead: ``dlam``, ``dnu`` are then the least-squares
    multipliers themselves (one compiled solver for both)."""
    mg = lay.masks().g
    rhs, W0 = _condensed_system(lay, it, d, mu)
    rhs_ls, W_ls = _least_squares_system(lay, d, it.z)
    rhs = jnp.where(least_squares, rhs_ls, rhs)
    W0 = jnp.where(least_squares, W_ls, W0)
    delta_last = jnp.where(least_squares, 0.0, delta_last)
    corrected = _regularised_solve(lay, W0, d, rhs, delta_last, try_zero | least_squares,
                                   singular, refinement_steps)
    dy, ds, dlam, dnu = _split_step(lay, d, corrected.solution, d.g, it.s)
    sg = jnp.where(mg > 0, it.s, 1.0)
    Sigma = jnp.where(mg > 0, it.z / sg, 0.0)
    dz = (mu / sg - it.z - Sigma * ds) * mg
    return NewtonStep(dy=dy, dlam=dlam, dnu=dnu, ds=ds, dz=dz, delta=corrected.delta,
                      factorisations=corrected.factorisations, factor=corrected.factor,
                      matrix=corrected.matrix, solved=corrected.ok)


def second_order_correction(lay: StageLayout, it: Iterate, d: StageDerivatives, mu,
                            step: NewtonStep, c, e, gs):
    """The primal step and multipliers of the KKT system of `step` (its factor reused) with
    the constraint residuals replaced by the corrected ones `c`, `e`, `gs` ($g - s$):
    ``(dy, ds, dlam, dnu)`` (Wächter and Biegler 2006, the second-order correction)."""
    rhs = _condensed_rhs(lay, it, d, mu, c, e, gs)
    return _split_step(lay, d, _refined_solve(step.factor, step.matrix, rhs), gs, 0.0)
