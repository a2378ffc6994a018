r"""Stage values and derivatives: every function of the NLP depends on one stage only, so its
values, Jacobians and the Hessian of the Lagrangian are taken per stage, under one `vmap`.

With the stage vector $v_k(y_k) = (\ell_k, F_k, e_k, g_k)$ of `stage_function` and the
weights $w_k = (1, -\lambda_k, \nu_k, -z_k)$ (masked), the Hessian of stage $k$ is
$\nabla^2 (w_k \cdot v_k)$; the defect $x_{k+1} - F_k$ contributes its $-F_k$ through
$-\lambda_k$ and its $x_{k+1}$ linearly (no curvature).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .problem import (
    AbstractStagewiseNLP,
    StageLayout,
    curved_variables,
    stage_function,
    stage_layout,
)


class StageDerivatives(eqx.Module):
    """Values and first and second derivatives of every stage, at one iterate.

    ``objective`` $\\sum_k \\ell_k + \\phi$; ``c`` defects $x_{k+1} - F_k$ (last row 0);
    ``e``, ``g`` equalities and inequalities (``e`` masked); ``grad_f`` the cost gradient;
    ``A`` $= \\partial F_k/\\partial y_k$, ``Je``, ``Jg`` (masked); ``H`` the symmetrised
    Hessian of the stage Lagrangian."""

    objective: Float[Array, ""]
    c: Float[Array, "M+1 nx"]
    e: Float[Array, "M+1 ne"]
    g: Float[Array, "M+1 ng"]
    grad_f: Float[Array, "M+1 ny"]
    A: Float[Array, "M+1 nx ny"]
    Je: Float[Array, "M+1 ne ny"]
    Jg: Float[Array, "M+1 ng ny"]
    H: Float[Array, "M+1 ny ny"]


def _defects(lay: StageLayout, ys, F):
    return jnp.concatenate([ys[1:, : lay.nx] - F[:-1], jnp.zeros((1, lay.nx))], 0)


def stage_values(prob: AbstractStagewiseNLP, lay: StageLayout, ys: Float[Array, "M+1 ny"]):
    """Objective, defects, (masked) equalities and inequalities at ``ys``, no derivatives."""
    masks = lay.masks()
    vec = stage_function(prob, lay, ys)
    f, F, e, g = lay.split(jax.vmap(vec)(ys, jnp.arange(lay.M + 1)))
    return jnp.sum(f), _defects(lay, ys, F), e * masks.eq, g


def _forward_over_forward(vec, y, k):
    """Value, Jacobian and per-output Hessians of the stage vector in one forward-over-forward
    pass (batched tangents, no transposes: compact to compile)."""

    def f1(yy):
        v = vec(yy, k)
        return v, v

    def f2(yy):
        J, v = jax.jacfwd(f1, has_aux=True)(yy)
        return J, (J, v)

    T, (J, v) = jax.jacfwd(f2, has_aux=True)(y)
    return v, J, T


def _forward_over_reverse(vec, y, k, w, curved=None):
    """Value, Jacobian and the Hessian of $w \\cdot v$ in one forward pass over the reverse
    pass: the tangents of the gradient of the weighted stage Lagrangian are its Hessian,
    those of the primal outputs the Jacobian (one traced derivative instead of two).

    ``curved`` (indices, or None for all): the directions the forward-over-reverse pass
    takes; along the others (`linear_variables`) the Hessian's columns are zero and the
    Jacobian's columns come from a forward pass of the values alone."""

    def grad_and_value(yy):
        v, pullback = jax.vjp(lambda z: vec(z, k), yy)
        return (pullback(w)[0], v), v

    if curved is None:
        (H, J), V = jax.jacfwd(grad_and_value, has_aux=True)(y)
        return V, J, H
    n = y.shape[0]

    def value_twice(z):  # the value as the aux output: one evaluation
        v = vec(z, k)
        return v, v

    if not curved:  # affine in every variable: no curvature at all
        J, V = jax.jacfwd(value_twice, has_aux=True)(y)
        return V, J, jnp.zeros((n, n), J.dtype)
    straight = [i for i in range(n) if i not in curved]
    curved, straight = jnp.asarray(curved), jnp.asarray(straight)
    basis = jnp.eye(n, dtype=y.dtype)
    # as `jax.jacfwd`: the tangents batched, their axis last
    _, (H_c, J_c), V = jax.vmap(lambda t: jax.jvp(grad_and_value, (y,), (t,), has_aux=True),
                                out_axes=(None, -1, None))(basis[curved])
    J_s = jax.vmap(lambda t: jax.jvp(lambda z: vec(z, k), (y,), (t,))[1],
                   out_axes=-1)(basis[straight])
    H = jnp.zeros((n, n), H_c.dtype).at[:, curved].set(H_c)
    J = jnp.zeros((V.shape[0], n), J_c.dtype).at[:, curved].set(J_c).at[:, straight].set(J_s)
    return V, J, H


def stage_jacobians(
    prob: AbstractStagewiseNLP, lay: StageLayout, ys: Float[Array, "M+1 ny"]
) -> StageDerivatives:
    """Values and Jacobians of every stage, no Hessian (``H`` zero): one forward pass with
    $n_y$ tangents per stage, about a fifth of `stage_derivatives`. Enough for the KKT
    residuals and the least-squares multipliers, which do not involve the Hessian."""
    masks = lay.masks()
    vec = stage_function(prob, lay, ys)

    def one(y, k):
        def value_twice(yy):  # the value as the aux output: one evaluation
            v = vec(yy, k)
            return v, v

        return jax.jacfwd(value_twice, has_aux=True)(y)

    J, V = jax.vmap(one)(ys, jnp.arange(lay.M + 1))
    return _assemble(lay, masks, ys, V, J, jnp.zeros((lay.M + 1, lay.ny, lay.ny)))


def _assemble(lay: StageLayout, masks, ys, V, J, H) -> StageDerivatives:
    f, F, e, g = lay.split(V)
    _, J_F, J_e, J_g = lay.split(J)
    return StageDerivatives(
        objective=jnp.sum(f), c=_defects(lay, ys, F), e=e * masks.eq, g=g, grad_f=J[:, 0],
        A=J_F * masks.lam[:, :, None], Je=J_e * masks.eq[:, :, None],
        Jg=J_g * masks.g[:, :, None], H=H,
    )


def _lagrangian_weights(lay: StageLayout, masks, lam, nu, z):
    """The weights $w_k = (1, -\\lambda_k, \\nu_k, -z_k)$ (masked) of the stage vector in the
    stage Lagrangian $w_k \\cdot v_k$."""
    return jnp.concatenate([jnp.ones((lay.M + 1, 1)), -lam * masks.lam, nu * masks.eq,
                            -z * masks.g], 1)


def stage_values_and_lagrangian_gradient(
    prob: AbstractStagewiseNLP,
    lay: StageLayout,
    ys: Float[Array, "M+1 ny"],
    lam: Float[Array, "M+1 nx"],
    nu: Float[Array, "M+1 ne"],
    z: Float[Array, "M+1 ng"],
):
    r"""Objective, defects, equalities, inequalities (as `stage_values`) and the gradient of
    each stage's Lagrangian $\nabla(w_k \cdot v_k)$ with the weights of
    `stage_derivatives`, by one reverse pass per stage (an adjoint: no Jacobian is formed)."""
    masks = lay.masks()
    vec = stage_function(prob, lay, ys)
    w = _lagrangian_weights(lay, masks, lam, nu, z)

    def one(y, k, ww):
        v, pullback = jax.vjp(lambda q: vec(q, k), y)
        return v, pullback(ww)[0]

    V, grad = jax.vmap(one)(ys, jnp.arange(lay.M + 1), w)
    f, F, e, g = lay.split(V)
    return jnp.sum(f), _defects(lay, ys, F), e * masks.eq, g, grad


def stage_derivatives(
    prob: AbstractStagewiseNLP,
    lay: StageLayout,
    ys: Float[Array, "M+1 ny"],
    lam: Float[Array, "M+1 nx"],
    nu: Float[Array, "M+1 ne"],
    z: Float[Array, "M+1 ng"],
    hessian: str = "forward-over-reverse",
) -> StageDerivatives:
    """Values, Jacobians and the Lagrangian Hessian of every stage (one `vmap`).

    ``hessian``: 'forward-over-reverse' (the Hessian of the weighted stage Lagrangian only)
    or 'forward-over-forward' (every per-output Hessian, then weighted)."""
    masks = lay.masks()
    vec = stage_function(prob, lay, ys)
    ks = jnp.arange(lay.M + 1)
    w = _lagrangian_weights(lay, masks, lam, nu, z)
    if hessian == "forward-over-forward":
        V, J, T = jax.vmap(lambda y, k: _forward_over_forward(vec, y, k))(ys, ks)
        H = jnp.einsum("ko,koij->kij", w, T)
    else:
        curved = curved_variables(prob, lay)
        V, J, H = jax.vmap(lambda y, k, ww: _forward_over_reverse(vec, y, k, ww, curved))(
            ys, ks, w)
    return _assemble(lay, masks, ys, V, J, 0.5 * (H + jnp.swapaxes(H, 1, 2)))


def check_linear_variables(prob: AbstractStagewiseNLP, ys: Float[Array, "M+1 ny"],
                           tol: float = 0.0, seed: int = 0) -> None:
    """Raise ValueError unless the stage functions of ``prob`` have no curvature along its
    `linear_variables` at the knots ``ys``: the Hessian of the stage Lagrangian, taken along
    every direction with random multipliers on every row in use (so no output's curvature
    can cancel another's), has zero rows for them, to within ``tol`` of its largest entry. A
    check of a problem's declaration (run it at a few points of its domain), not for a
    solve."""
    lay = stage_layout(prob)
    curved = curved_variables(prob, lay, 0.0)
    if curved is None:  # nothing declared
        return
    linear = [i for i in range(lay.ny) if i not in curved]
    keys = jax.random.split(jax.random.key(seed), 3)
    lam, nu, z = (jax.random.normal(key, (lay.M + 1, n), ys.dtype)
                  for key, n in zip(keys, (lay.nx, lay.ne, lay.ng)))
    w = _lagrangian_weights(lay, lay.masks(), lam, nu, z)  # the solver's weighting, random

    @jax.jit
    def hessians(ys, w):
        vec = stage_function(prob, lay, ys)
        return jax.vmap(lambda y, k, ww: _forward_over_reverse(vec, y, k, ww)[2])(
            ys, jnp.arange(lay.M + 1), w)

    H = hessians(ys, w)
    largest = float(jnp.max(jnp.where(jnp.isfinite(H), jnp.abs(H), 0.0)))
    for i in linear:
        row = float(jnp.max(jnp.abs(H[:, i, :])))
        if not row <= tol * largest:
            raise ValueError(f"{type(prob).__name__}.linear_variables() declares y[{i}], but "
                             f"the stage functions curve along it: a second derivative of "
                             f"{row:.3g} (largest {largest:.3g})")
