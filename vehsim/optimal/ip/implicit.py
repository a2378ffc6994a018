r"""Derivatives of a solution by the implicit function theorem.

At the returned iterate $w = (y, s, z, \lambda, \nu)$ the barrier problem's KKT residual
$R(w, \theta) = (\nabla_y\mathcal L,\ c,\ e,\ g - s,\ Sz - \mu e)$ vanishes (to the
solver's tolerance), so for a problem whose parameters $\theta$ (the array fields of the
`AbstractStagewiseNLP`) move by $\dot\theta$ the solution moves by
$\dot w = -(\partial_w R)^{-1}\,\partial_\theta R\,\dot\theta$. $\partial_w R$ is the
matrix of the solver's Newton step at that iterate; eliminating $(\dot s, \dot z)$ as the
step does ($\dot s = J_g\dot y + \dot g$, $\dot z = -\Sigma\dot s$) leaves the condensed
system of `kkt` with the right-hand side

$$-\big(\partial_\theta\nabla_y\mathcal L\,\dot\theta + J_g^T\Sigma\,\partial_\theta g\,
\dot\theta,\ \ \partial_\theta c\,\dot\theta,\ \ \partial_\theta e\,\dot\theta\big),$$

factored by the same Riccati recursion (with the inertia correction's regularisation, none
at a regular solution). The parameter derivatives are one forward-mode pass over the stage
functions and the vector-Jacobian product of the stage Lagrangian. The solve is a
`lax.custom_linear_solve` of the symmetric KKT matrix, so the tangent is linear and
transposable: reverse mode runs too. The guess (and warm-start multipliers) get no
derivative: a converged solution does not depend on them. The objective's tangent is its
total derivative along the solution's; the residuals and the log get none. Where the solve
did not converge the theorem does not apply (near a solution, with the barrier not yet
small, it gave derivatives far from the finite differences): differentiating such a solve,
in either mode, raises `UNCONVERGED_DERIVATIVE_MESSAGE` when the program runs, rather than
return a NaN or a wrong number.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from ..._results import RESULTS
from .derivatives import stage_derivatives, stage_values
from .kkt import Iterate, _condensed_system, _refined_solve, _regularised_solve, _split_step
from .problem import stage_function, stage_layout


UNCONVERGED_DERIVATIVE_MESSAGE = (
    "interior_point(implicit=True): a derivative (jax.jvp, jax.grad) was asked of a solve "
    "that did not converge (its IPSolution.result is not 'successful'). The implicit "
    "function theorem gives derivatives only at a solution; at an iterate short of one it "
    "gives numbers far from the finite differences, so none is returned. Solve to "
    "convergence first (a larger IPOptions.max_iter, a closer guess, or a looser "
    "IPOptions.tol) and check `result`; a receding-horizon drive in mode='converged' "
    "needs every plan of the drive converged (its `converged` diagnostics)")


def _stage_lagrangian(prob, lay, ys, w):
    """Per stage: the gradient in $y_k$ of $w_k\\cdot v_k(y_k)$ and the stage vector $v_k$."""
    vec = stage_function(prob, lay, ys)

    def one(y, k, wk):
        v, pullback = jax.vjp(lambda yy: vec(yy, k), y)
        return pullback(wk)[0], v

    return jax.vmap(one)(ys, jnp.arange(lay.M + 1), w)


def solution_tangent(prob, tprob, it: Iterate, hessian: str = "forward-over-reverse"):
    r"""The tangent $(\dot y, \dot s, \dot z, \dot\lambda, \dot\nu)$ (an `Iterate`) of the
    solution ``it`` of ``prob`` for the problem's tangent ``tprob`` (its inexact-array
    leaves, None where zero), by the implicit function theorem (module docstring)."""
    lay = stage_layout(prob)
    mk = lay.masks()
    it = jax.lax.stop_gradient(it)
    d = stage_derivatives(prob, lay, it.ys, it.lam, it.nu, it.z, hessian)
    d = jax.lax.stop_gradient(d)
    w = jnp.concatenate([jnp.ones((lay.M + 1, 1)), -it.lam * mk.lam, it.nu * mk.eq,
                         -it.z * mk.g], 1)
    dyn, static, tdyn = _problem_tangent(prob, tprob)
    _, (dgrad, dv) = jax.jvp(
        lambda p: _stage_lagrangian(eqx.combine(p, static), lay, it.ys, w), (dyn,), (tdyn,))
    _, dF, de, dg = lay.split(dv)
    dc = jnp.concatenate([-dF[:-1], jnp.zeros((1, lay.nx))], 0)
    de, dg = de * mk.eq, dg * mk.g
    sg = jnp.where(mk.g > 0, it.s, 1.0)
    Sigma = jnp.where(mk.g > 0, it.z / sg, 0.0)
    ry = -(dgrad + jnp.einsum("kij,ki->kj", d.Jg, Sigma * dg)) * mk.y
    rhs = jnp.concatenate([ry, -dc, -de], axis=1)
    # the matrix of the solver's step at this iterate (its inertia correction, on values)
    _, W0 = _condensed_system(lay, it, d, 0.0)
    corr = _regularised_solve(lay, W0, d, jnp.zeros_like(rhs), jnp.asarray(0.0))
    K, F = corr.matrix, corr.factor
    sol = jax.lax.custom_linear_solve(
        K.matvec, rhs, lambda _, b: _refined_solve(F, K, b), symmetric=True)
    dy, ds, dlam, dnu = _split_step(lay, d, sol, dg, 0.0)
    dz = -Sigma * ds * mk.g
    return Iterate(ys=dy, s=ds, z=dz, lam=dlam, nu=dnu)


def _problem_tangent(prob, tprob):
    """``(dyn, static, tdyn)``: the problem's inexact arrays, the rest, and their tangents
    (zeros where ``tprob`` has None)."""
    dyn, static = eqx.partition(prob, eqx.is_inexact_array)
    tdyn = jax.tree.map(
        lambda p, t: None if p is None else jnp.zeros_like(p) if t is None
        else jnp.asarray(t, p.dtype), dyn, tprob, is_leaf=lambda x: x is None)
    return dyn, static, tdyn


def objective_tangent(prob, tprob, ys, dys):
    r"""The objective's tangent at the solution: $\partial_	heta f\,\dot	heta + 
abla_y f
    \cdot\dot y$ (its total derivative along the solution's tangent ``dys``)."""
    dyn, static, tdyn = _problem_tangent(prob, tprob)
    lay = stage_layout(prob)
    return jax.jvp(lambda p, y: stage_values(eqx.combine(p, static), lay, y)[0],
                   (dyn, jax.lax.stop_gradient(ys)), (tdyn, dys))[1]


@eqx.filter_custom_jvp
def implicit_solve(prob, guess, *, solve):
    """``solve(prob, *guess)`` (an `IPSolution`), differentiated in ``prob`` by
    `solution_tangent` at the solution returned and not at all in ``guess``."""
    return solve(prob, *guess)


@implicit_solve.def_jvp
def _implicit_solve_jvp(primals, tangents, *, solve):
    prob, guess = primals
    tprob, _ = tangents
    sol = implicit_solve(prob, guess, solve=solve)
    if tprob is None or not jax.tree.leaves(tprob):
        return sol, None
    lay = stage_layout(prob)
    it = Iterate(ys=lay.join(sol.xs, sol.us), s=sol.s, z=sol.z, lam=sol.lam, nu=sol.nu)
    t = solution_tangent(prob, tprob, it)
    # at an iterate that did not converge the theorem does not apply: an error, not a wrong
    # number; checked on a primal factor of the tangent, so that reverse mode raises in its
    # forward pass and the check is not pruned from either program
    one = eqx.error_if(jnp.ones(()), sol.result != RESULTS.successful,
                       UNCONVERGED_DERIVATIVE_MESSAGE)
    t = jax.tree.map(lambda a: a * one, t)
    tsol = jax.tree.map(lambda _: None, sol)
    tsol = eqx.tree_at(lambda q: (q.xs, q.us, q.lam, q.nu, q.z, q.s, q.objective), tsol,
                       (t.ys[:, : lay.nx], t.ys[:-1, lay.nx:], t.lam, t.nu, t.z, t.s,
                        objective_tangent(prob, tprob, it.ys, t.ys)),
                       is_leaf=lambda x: x is None)
    return sol, tsol

