r"""A primal-dual interior-point method for stage-structured (multiple-shooting) NLPs.

The problem, over knots $k = 0..M$ with states $x_k \in \mathbb{R}^{n_x}$ and controls
$u_k \in \mathbb{R}^{n_u}$ ($u_M$ unused), is

$$\min \sum_{k<M} \ell_k(x_k, u_k) + \phi(x_M)$$
$$\text{s.t.}\quad x_{k+1} = F_k(x_k, u_k),\quad h_k(x_k, u_k) \ge 0,
\quad e_0(x_0) = 0,\ i_0(x_0) \ge 0,\quad e_M(x_M) = 0,\ i_M(x_M) \ge 0.$$

Every function depends on one stage only, so first and second derivatives are taken per
stage (``vmap`` of ``jacfwd``/``hessian``) and the Newton (KKT) system is block tridiagonal:
ordering the unknowns per stage as $(x_k, u_k, \lambda_k, \nu_k)$ (defect multiplier
$\lambda_k$ of $x_{k+1} - F_k = 0$, boundary multipliers $\nu_k$), block $k$ couples with
block $k+1$ only through the identity between $\lambda_k$ and $x_{k+1}$. The system is
factorised by a block $LDL^T$ (Riccati-like) recursion in ``lax.scan``; the inertia of the
pivots (Sylvester) drives the IPOPT-style Hessian regularisation. A free final time (or any
global parameter) is best carried as a state with $p_{k+1} = p_k$, which keeps the band
(a single dense column coupling every defect is exactly what ruins sparse solvers).

Inequalities get slacks $g(w) - s = 0$, $s > 0$ and the primal-dual barrier equations
$S z = \mu e$, condensed into the stage blocks ($J_g^T \Sigma J_g$, $\Sigma = S^{-1}Z$).
Steps obey the fraction-to-boundary rule and an $\ell_1$ exact-penalty merit line search;
the barrier parameter follows the monotone Fiacco-McCormick rule. The whole solve is one
``lax.while_loop``: it compiles once, and ``vmap`` runs a batch of problems together.
"""

from __future__ import annotations

import abc
import sys
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._checks import is_concrete
from .._fields import array_field, int_field


class AbstractStagewiseNLP(eqx.Module):
    """A stage-structured NLP (multiple shooting). Subclasses hold their parameters as array
    fields (so a batch of problems is a batched module) and implement the stage functions.

    Sizes are class-level: `num_stages` (M, segments), `state_size`, `control_size`.
    """

    # subclasses define the static int fields num_stages, state_size, control_size

    @abc.abstractmethod
    def transition(self, x: Array, u: Array, k: Array) -> Array:
        """$F_k(x_k, u_k)$: the state at knot $k+1$ reached from knot $k$."""

    def transition_and_path(self, x: Array, u: Array, k: Array) -> tuple[Array, Array]:
        """$(F_k, h_k)$ together (override to share work, e.g. one integration)."""
        return self.transition(x, u, k), self.path_inequality(x, u, k)

    def stage_cost(self, x: Array, u: Array, k: Array) -> Array:
        """$\\ell_k(x_k, u_k)$ (default 0)."""
        return jnp.zeros(())

    def terminal_cost(self, x: Array) -> Array:
        """$\\phi(x_M)$ (default 0)."""
        return jnp.zeros(())

    def path_inequality(self, x: Array, u: Array, k: Array) -> Array:
        """$h_k(x_k, u_k) \\ge 0$ for $k < M$ (default none)."""
        return jnp.zeros((0,))

    def initial_equality(self, x: Array) -> Array:
        return jnp.zeros((0,))

    def initial_inequality(self, x: Array) -> Array:
        return jnp.zeros((0,))

    def terminal_equality(self, x: Array) -> Array:
        return jnp.zeros((0,))

    def terminal_inequality(self, x: Array) -> Array:
        return jnp.zeros((0,))


class IPOptions(eqx.Module):
    """Interior-point settings. ``tol``: scaled KKT error for convergence; ``max_iter``;
    ``mu0``: initial barrier; ``verbose``: print one line per iteration to stderr;
    ``hessian``: 'forward-over-reverse' (Hessian of the weighted stage Lagrangian; fastest
    to run) or 'forward-over-forward' (all per-output Hessians in one pass; quicker to
    compile)."""

    tol: float = eqx.field(static=True, default=1e-8)
    constr_tol: float = eqx.field(static=True, default=1e-9)
    max_iter: Int[Array, ""] = int_field(default=300)
    log_size: int = eqx.field(static=True, default=1000)
    hessian: str = eqx.field(static=True, default="forward-over-reverse")
    mu0: Float[Array, ""] = array_field(default=0.1)
    verbose: bool = eqx.field(static=True, default=False)


# status codes
SUCCESS = 0
MAX_ITERATIONS = 1
NONFINITE = 2
STATUS_MESSAGES = {
    SUCCESS: "converged",
    MAX_ITERATIONS: "iteration limit reached before convergence",
    NONFINITE: "non-finite values in the iterates",
}


class IPSolution(eqx.Module):
    """Result of `interior_point`: knots ``xs`` (M+1, nx), controls ``us`` (M, nu), multipliers,
    ``status`` (0 converged, 1 iteration limit, 2 non-finite), ``iterations``, the final
    ``objective`` and residuals (``inf_pr``: max constraint violation, ``inf_du``: max
    Lagrangian-gradient entry, ``compl``: max complementarity), and a per-iteration ``log``
    (dict of arrays of length ``log_size``; entries past ``iterations`` are NaN)."""

    xs: Float[Array, "M+1 nx"]
    us: Float[Array, "M nu"]
    lam: Float[Array, "M+1 nx"]
    nu: Array
    z: Array
    status: Int[Array, ""]
    iterations: Int[Array, ""]
    objective: Float[Array, ""]
    inf_pr: Float[Array, ""]
    inf_du: Float[Array, ""]
    compl: Float[Array, ""]
    log: dict

    @property
    def converged(self):
        return self.status == SUCCESS

    @property
    def message(self) -> str:
        return STATUS_MESSAGES.get(int(self.status), "unknown")


class _Layout(eqx.Module):
    """Static sizes and masks of the padded stage layout."""

    M: int = eqx.field(static=True)
    nx: int = eqx.field(static=True)
    nu: int = eqx.field(static=True)
    ne: int = eqx.field(static=True)
    nh: int = eqx.field(static=True)
    ni0: int = eqx.field(static=True)
    niT: int = eqx.field(static=True)
    ne0: int = eqx.field(static=True)
    neT: int = eqx.field(static=True)

    @property
    def ny(self):
        return self.nx + self.nu

    @property
    def ng(self):
        return self.nh + self.ni0 + self.niT

    @property
    def nb(self):
        return 2 * self.nx + self.nu + self.ne

    def masks(self):
        M = self.M
        k = np.arange(M + 1)[:, None]
        eq = np.zeros((M + 1, self.ne))
        eq[0, : self.ne0] = 1.0
        eq[M, : self.neT] = 1.0
        g = np.concatenate(
            [
                np.broadcast_to(k < M, (M + 1, self.nh)),
                np.broadcast_to(k == 0, (M + 1, self.ni0)),
                np.broadcast_to(k == M, (M + 1, self.niT)),
            ],
            axis=1,
        ).astype(float)
        lam = (k < M).astype(float) * np.ones((1, self.nx))
        u = (k < M).astype(float) * np.ones((1, self.nu))
        return jnp.asarray(eq), jnp.asarray(g), jnp.asarray(lam), jnp.asarray(u)


def _layout(prob: AbstractStagewiseNLP) -> _Layout:
    nx, nu, M = prob.state_size, prob.control_size, prob.num_stages
    x = jax.ShapeDtypeStruct((nx,), jnp.float64)
    u = jax.ShapeDtypeStruct((nu,), jnp.float64)
    k = jax.ShapeDtypeStruct((), jnp.int32)
    size = lambda f, *a: jax.eval_shape(f, *a).shape[0]
    ne0 = size(prob.initial_equality, x)
    neT = size(prob.terminal_equality, x)
    return _Layout(
        M=M, nx=nx, nu=nu, ne=max(ne0, neT, 1),
        nh=size(prob.path_inequality, x, u, k),
        ni0=size(prob.initial_inequality, x), niT=size(prob.terminal_inequality, x),
        ne0=ne0, neT=neT,
    )


def _stage_function(prob: AbstractStagewiseNLP, lay: _Layout):
    """All stage outputs of y = (x, u) at stage k (0..M) as one vector
    (cost, F, e, g): one function to differentiate (one trace, one integration)."""
    M, nx = lay.M, lay.nx

    def pad(v, n):
        return jnp.concatenate([v, jnp.zeros((n - v.shape[0],), v.dtype)])

    def vec(y, k):
        x, u = y[:nx], y[nx:]
        km = jnp.minimum(k, M - 1)
        F, h = prob.transition_and_path(x, u, km)
        cost = jnp.where(k < M, prob.stage_cost(x, u, km), 0.0) + jnp.where(
            k == M, prob.terminal_cost(x), 0.0
        )
        e0 = pad(prob.initial_equality(x), lay.ne)
        eT = pad(prob.terminal_equality(x), lay.ne)
        e = jnp.where(k == 0, e0, jnp.where(k == M, eT, 0.0))
        i0 = prob.initial_inequality(x)
        iT = prob.terminal_inequality(x)
        g = jnp.concatenate(
            [jnp.where(k < M, h, 1.0), jnp.where(k == 0, i0, 1.0), jnp.where(k == M, iT, 1.0)]
        )
        return jnp.concatenate([jnp.reshape(cost, (1,)), F, e, g])

    return vec


def _block_factor(Kd, nx, nu, eps):
    """Block LDL^T of the block-tridiagonal KKT matrix: diagonal blocks ``Kd`` (M+1, nb, nb),
    sub-diagonal blocks all equal to the identity from lambda_k (cols) to x_{k+1} (rows).
    Returns pivot eigen-decompositions and the number of negative / tiny pivot eigenvalues."""
    lam_sl = slice(nx + nu, 2 * nx + nu)

    def step(carry, Kk):
        D = Kk.at[:nx, :nx].add(-carry)
        D = 0.5 * (D + D.T)
        # symmetric Ruiz equilibration (a congruence: inertia kept) so that graded pivots
        # (barrier terms 1e10 beside 1e-9 regularisations) keep their small eigenvalues
        d = jnp.ones(D.shape[0])
        for _ in range(3):
            r = jnp.max(jnp.abs(D * d[:, None] * d[None, :]), axis=1)
            d = d / jnp.sqrt(jnp.where(r > 0, r, 1.0))
        w, V = jnp.linalg.eigh(D * d[:, None] * d[None, :])
        V = V * d[:, None]  # D^{-1} = (dV) diag(1/w) (dV)^T
        Vl = V[lam_sl, :]
        winv = jnp.where(jnp.abs(w) > 0, 1.0 / jnp.where(w == 0, 1.0, w), 0.0)
        S = (Vl * winv[None, :]) @ Vl.T
        neg = jnp.sum(w < 0)
        tiny = jnp.sum(~jnp.isfinite(w)) + jnp.sum(w == 0)
        return S, (w, V, neg, tiny)

    _, (W, V, neg, tiny) = jax.lax.scan(step, jnp.zeros((nx, nx)), Kd)
    return W, V, jnp.sum(neg), jnp.sum(tiny)


def _block_matvec(Kd, v, nx, nu):
    """K v for the block-tridiagonal KKT matrix (diagonal blocks + lambda_k/x_{k+1} identities)."""
    lam_sl = slice(nx + nu, 2 * nx + nu)
    out = jnp.einsum("kij,kj->ki", Kd, v)
    out = out.at[1:, :nx].add(v[:-1, lam_sl])
    out = out.at[:-1, lam_sl].add(v[1:, :nx])
    return out


def _block_solve(W, V, rhs, nx, nu):
    """Solve with the factor from `_block_factor` (forward and backward block sweeps)."""
    lam_sl = slice(nx + nu, 2 * nx + nu)

    def dinv(w, v, r):
        winv = jnp.where(w == 0, 0.0, 1.0 / jnp.where(w == 0, 1.0, w))
        return v @ (winv * (v.T @ r))

    def fwd(carry, inp):
        w, v, r = inp
        y = r.at[:nx].add(-carry)
        return dinv(w, v, y)[lam_sl], y

    _, ys = jax.lax.scan(fwd, jnp.zeros((nx,)), (W, V, rhs))

    def bwd(carry, inp):
        w, v, y = inp
        y = y.at[lam_sl].add(-carry)
        sol = dinv(w, v, y)
        return sol[:nx], sol

    _, sols = jax.lax.scan(bwd, jnp.zeros((nx,)), (W, V, ys), reverse=True)
    return sols


def interior_point(
    prob: AbstractStagewiseNLP,
    xs0: Float[Array, "M+1 nx"],
    us0: Float[Array, "M nu"],
    options: IPOptions = IPOptions(),
    *,
    throw: bool = True,
) -> IPSolution:
    """Solve ``prob`` from the guess (``xs0``, ``us0``) by the structured interior-point method.

    **Arguments:** ``prob`` (an `AbstractStagewiseNLP`), the initial knots and controls,
    ``options`` (`IPOptions`), ``throw``: raise on non-convergence (``False`` for batches).

    **Returns:** an `IPSolution` with status, residuals and iteration log.
    """
    sol = _interior_point(prob, jnp.asarray(xs0, float), jnp.asarray(us0, float), options)
    if throw:
        if is_concrete(sol.status):
            if int(sol.status) != SUCCESS:
                raise RuntimeError(
                    f"interior point did not converge: {sol.message} after "
                    f"{int(sol.iterations)} iterations; residuals inf_pr={float(sol.inf_pr):.3e}, "
                    f"inf_du={float(sol.inf_du):.3e}, compl={float(sol.compl):.3e} "
                    "(use throw=False to get the partial solution)"
                )
        else:
            xs = eqx.error_if(sol.xs, sol.status != SUCCESS, "interior point did not converge")
            sol = eqx.tree_at(lambda s: s.xs, sol, xs)
    return sol


def _strong(tree):
    """Strongly typed copies of the array leaves: a weakly typed loop carry (``jnp.asarray(0.0)``)
    makes `lax.while_loop` trace its body a second time to fix the types (twice the tracing
    of the whole Newton step)."""
    return jax.tree.map(lambda a: jnp.asarray(a, dtype=jnp.result_type(a)), tree)


def _print_iter(it, f, inf_pr, inf_du, mu, alpha, delta, nls):
    print(
        f"  ip {int(it):4d}  obj {float(f): .8e}  inf_pr {float(inf_pr):.2e}  "
        f"inf_du {float(inf_du):.2e}  mu {float(mu):.1e}  alpha {float(alpha):.2e}  "
        f"reg {float(delta):.1e}  ls {int(nls)}",
        file=sys.stderr,
        flush=True,
    )


@eqx.filter_jit
def _interior_point(prob, xs0, us0, options: IPOptions) -> IPSolution:
    lay = _layout(prob)
    M, nx, nu, ne, ny = lay.M, lay.nx, lay.nu, lay.ne, lay.ny
    vec = _stage_function(prob, lay)
    meq, mg, mlam, mu_mask = lay.masks()
    ks = jnp.arange(M + 1)
    kappa_sigma = 1e10
    tau_min = 0.99
    s_max = 100.0
    delta_c = 1e-9
    eta = 1e-4
    n_neg_expected = (M + 1) * (nx + ne)
    i_F, i_e, i_g = 1, 1 + nx, 1 + nx + ne

    def ys_of(xs, us):
        return jnp.concatenate([xs, jnp.concatenate([us, jnp.zeros((1, nu))], 0)], axis=1)

    def split(V):
        return V[:, 0], V[:, i_F:i_e], V[:, i_e:i_g], V[:, i_g:]

    def values(ys):
        f, F, e, g = split(jax.vmap(vec)(ys, ks))
        c = jnp.concatenate([ys[1:, :nx] - F[:-1], jnp.zeros((1, nx))], 0)
        return jnp.sum(f), c, e * meq, g

    def merit(ys, s, mu):
        """Barrier objective and constraint violation (l1)."""
        f, c, e, g = values(ys)
        logs = jnp.where(mg > 0, jnp.log(jnp.where(mg > 0, s, 1.0)), 0.0)
        viol = jnp.sum(jnp.abs(c)) + jnp.sum(jnp.abs(e)) + jnp.sum(jnp.abs((g - s) * mg))
        return f - mu * jnp.sum(logs), viol, f

    def second_order(y, k):
        """Value, Jacobian and per-output Hessians of the stage vector in one forward-over-
        forward pass (compact to compile: the tangents are batched, no transposes)."""

        def f1(yy):
            v = vec(yy, k)
            return v, v

        def f2(yy):
            J, v = jax.jacfwd(f1, has_aux=True)(yy)
            return J, (J, v)

        T, (J, v) = jax.jacfwd(f2, has_aux=True)(y)
        return v, J, T

    def derivatives(ys, lam, nu_, z):
        """Values, Jacobians and the Lagrangian Hessian of every stage (one vmap)."""
        w = jnp.concatenate([jnp.ones((M + 1, 1)), -lam * mlam, nu_ * meq, -z * mg], 1)
        if options.hessian == "forward-over-forward":
            V, J, T = jax.vmap(second_order)(ys, ks)
            H = jnp.einsum("ko,koij->kij", w, T)
        else:
            def second(y, k, ww):
                # one forward pass over the reverse pass: the tangents of the gradient of
                # the weighted stage Lagrangian are its Hessian, those of the primal
                # outputs the Jacobian (one traced derivative instead of two)
                def grad_and_value(yy):
                    v, pullback = jax.vjp(lambda z: vec(z, k), yy)
                    return (pullback(ww)[0], v), v

                (H, J), V = jax.jacfwd(grad_and_value, has_aux=True)(y)
                return V, J, H

            V, J, H = jax.vmap(second)(ys, ks, w)
        H = 0.5 * (H + jnp.swapaxes(H, 1, 2))
        f, F, e, g = split(V)
        c = jnp.concatenate([ys[1:, :nx] - F[:-1], jnp.zeros((1, nx))], 0)
        grad_f = J[:, 0]
        A = J[:, i_F:i_e] * mlam[:, :, None]
        Je = J[:, i_e:i_g] * meq[:, :, None]
        Jg = J[:, i_g:] * mg[:, :, None]
        return jnp.sum(f), c, e * meq, g, grad_f, A, Je, Jg, H

    def kkt_residuals(ys, lam, nu_, z, s, c, e, g, grad_f, A, Je, Jg, mu):
        # Lagrangian gradient per stage: grad f + Je' nu - A' lam - Jg' z + [lam_{k-1} on x_k]
        rd = (
            grad_f
            + jnp.einsum("kij,ki->kj", Je, nu_ * meq)
            - jnp.einsum("kij,ki->kj", A, lam * mlam)
            - jnp.einsum("kij,ki->kj", Jg, z * mg)
        )
        rd = rd.at[1:, :nx].add(lam[:-1] * mlam[:-1])
        rd = rd * jnp.concatenate([jnp.ones((M + 1, nx)), mu_mask], 1)
        inf_du = jnp.max(jnp.abs(rd))
        inf_pr = jnp.maximum(
            jnp.maximum(jnp.max(jnp.abs(c)), jnp.max(jnp.abs(e), initial=0.0)),
            jnp.max(jnp.abs((g - s) * mg), initial=0.0),
        )
        compl0 = jnp.max(jnp.abs((s * z) * mg), initial=0.0)
        compl_mu = jnp.max(jnp.abs((s * z - mu) * mg), initial=0.0)
        n_mult = (M + 1) * (nx + ne) + jnp.sum(mg)
        s_d = jnp.maximum(
            s_max,
            (jnp.sum(jnp.abs(lam)) + jnp.sum(jnp.abs(nu_)) + jnp.sum(jnp.abs(z * mg))) / n_mult,
        ) / s_max
        s_c = jnp.maximum(s_max, jnp.sum(jnp.abs(z * mg)) / jnp.maximum(jnp.sum(mg), 1.0)) / s_max
        base = jnp.maximum(inf_du / s_d, inf_pr)
        err0 = jnp.maximum(base, compl0 / s_c)
        err_mu = jnp.maximum(base, compl_mu / s_c)
        return inf_pr, inf_du, compl0, err0, err_mu

    # ---- initialisation
    ys = ys_of(xs0, us0)
    _, c0, e0, g0 = values(ys)
    mu0 = options.mu0
    s = jnp.where(mg > 0, jnp.maximum(g0, jnp.minimum(1e-2, 10.0 * mu0)), 1.0)
    z = jnp.where(mg > 0, mu0 / s, 0.0)
    theta_init = jnp.sum(jnp.abs(c0)) + jnp.sum(jnp.abs(e0 * meq)) + jnp.sum(jnp.abs((g0 - s) * mg))
    lam = jnp.zeros((M + 1, nx))
    nu_ = jnp.zeros((M + 1, ne))
    nanlog = jnp.full((options.log_size,), jnp.nan)
    log0 = dict(objective=nanlog, inf_pr=nanlog, inf_du=nanlog, mu=nanlog, alpha=nanlog,
                regularisation=nanlog)
    state0 = dict(
        ys=ys, s=s, z=z, lam=lam, nu=nu_, mu=jnp.asarray(mu0),
        delta_last=jnp.asarray(0.0), it=jnp.asarray(0), done=jnp.asarray(False),
        status=jnp.asarray(MAX_ITERATIONS), log=log0,
        err=jnp.asarray(jnp.inf), inf_pr=jnp.asarray(jnp.inf), inf_du=jnp.asarray(jnp.inf),
        compl=jnp.asarray(jnp.inf), f=jnp.asarray(jnp.nan),
        filter_theta=jnp.full((64,), jnp.inf), filter_phi=jnp.full((64,), jnp.inf),
        filter_next=jnp.asarray(0), theta_min=1e-4 * jnp.maximum(1.0, theta_init),
        theta_max=1e4 * jnp.maximum(1.0, theta_init),
    )
    state0 = _strong(state0)

    def body(st):
        ys, s, z, lam, nu_, mu = st["ys"], st["s"], st["z"], st["lam"], st["nu"], st["mu"]
        f, c, e, g, grad_f, A, Je, Jg, H = derivatives(ys, lam, nu_, z)
        inf_pr, inf_du, compl, err0, err_mu = kkt_residuals(
            ys, lam, nu_, z, s, c, e, g, grad_f, A, Je, Jg, mu
        )
        converged = (err0 <= options.tol) & (inf_pr <= options.constr_tol)
        # barrier update (monotone)
        mu_changed = (err_mu <= 10.0 * mu) & (mu > options.tol / 10.0)
        mu = jnp.where(
            mu_changed,
            jnp.maximum(options.tol / 10.0, jnp.minimum(0.2 * mu, mu**1.5)),
            mu,
        )
        tau = jnp.maximum(tau_min, 1.0 - mu)

        # ---- condensed Newton system
        sg = jnp.where(mg > 0, s, 1.0)
        Sigma = jnp.where(mg > 0, z / sg, 0.0)
        rhs_y = -(
            grad_f
            + jnp.einsum("kij,ki->kj", Je, nu_)
            - jnp.einsum("kij,ki->kj", A, lam * mlam)
        )
        rhs_y = rhs_y.at[1:, :nx].add(-lam[:-1] * mlam[:-1])
        rhs_y = rhs_y + jnp.einsum("kij,ki->kj", Jg, (mu / sg - Sigma * (g - s)) * mg)
        um = jnp.concatenate([jnp.ones((M + 1, nx)), mu_mask], 1)
        rhs_y = rhs_y * um
        rhs = jnp.concatenate([rhs_y, -c, -e], axis=1)

        W0 = H + jnp.einsum("kij,ki,kil->kjl", Jg, Sigma, Jg)
        W0 = W0 * um[:, :, None] * um[:, None, :] + jax.vmap(jnp.diag)(1.0 - um)
        ze = jnp.zeros((M + 1, nx, ne))

        def assemble(delta):
            Wd = W0 + delta * jax.vmap(jnp.diag)(um)
            dl = -jax.vmap(jnp.diag)(jnp.where(mlam > 0, delta_c, 1.0))
            de = -jax.vmap(jnp.diag)(jnp.where(meq > 0, delta_c, 1.0))
            row1 = jnp.concatenate([Wd, -jnp.swapaxes(A, 1, 2), jnp.swapaxes(Je, 1, 2)], 2)
            row2 = jnp.concatenate([-A, dl, ze], 2)
            row3 = jnp.concatenate([Je, jnp.swapaxes(ze, 1, 2), de], 2)
            return jnp.concatenate([row1, row2, row3], 1)

        def factor(delta):
            Kd = assemble(delta)
            Wv, Vv, neg, tiny = _block_factor(Kd, nx, nu, 1e-13)
            sol = _block_solve(Wv, Vv, rhs, nx, nu)
            # one step of iterative refinement, then insist on an accurate solve
            res = rhs - _block_matvec(Kd, sol, nx, nu)
            sol = sol + _block_solve(Wv, Vv, res, nx, nu)
            res = rhs - _block_matvec(Kd, sol, nx, nu)
            # componentwise backward error (Oettli-Prager)
            scale = _block_matvec(jnp.abs(Kd), jnp.abs(sol), nx, nu) + jnp.abs(rhs)
            accurate = jnp.max(jnp.abs(res)) <= 1e-10 * jnp.max(scale)
            ok = (neg == n_neg_expected) & (tiny == 0) & accurate & jnp.all(jnp.isfinite(sol))
            return sol, ok

        # inertia correction
        d_first = jnp.where(
            st["delta_last"] == 0.0, 1e-4, jnp.maximum(1e-20, st["delta_last"] / 3.0)
        )

        def ic_cond(c_):
            return (~c_[2]) & (c_[3] < 40)

        def ic_body(c_):
            delta, _, _, n = c_
            delta = jnp.where(
                n == 0, 0.0,
                jnp.where(n == 1, d_first,
                          delta * jnp.where(st["delta_last"] == 0.0, 100.0, 8.0)),
            )
            sol, ok = factor(delta)
            return delta, sol, ok, n + 1

        nb = lay.nb
        init = _strong((0.0, jnp.zeros((M + 1, nb)), False, 0))
        delta, sol, ok, _ = jax.lax.while_loop(ic_cond, ic_body, init)
        delta_last = jnp.where(delta > 0, delta, st["delta_last"])
        dy = sol[:, :ny] * um
        dlam = sol[:, ny : ny + nx] * mlam
        dnu = sol[:, ny + nx :] * meq
        ds = (jnp.einsum("kij,kj->ki", Jg, dy) + g - s) * mg
        dz = (mu / sg - z - Sigma * ds) * mg

        # fraction to boundary
        def max_step(v, dv):
            ratio = jnp.where((dv < 0) & (mg > 0), -tau * v / jnp.where(dv < 0, dv, -1.0), jnp.inf)
            return jnp.minimum(1.0, jnp.min(ratio))

        alpha_p = max_step(s, ds)
        alpha_d = max_step(jnp.where(mg > 0, z, 1.0), dz)

        # filter line search (Waechter and Biegler 2006, without restoration phase)
        phi0, theta0, _ = merit(ys, s, mu)
        dphi = jnp.sum(grad_f * dy) - mu * jnp.sum(jnp.where(mg > 0, ds / sg, 0.0))
        theta_min = st["theta_min"]
        fil_theta, fil_phi = st["filter_theta"], st["filter_phi"]
        fil_theta = jnp.where(mu_changed, jnp.inf, fil_theta)
        fil_phi = jnp.where(mu_changed, jnp.inf, fil_phi)

        def acceptable(alpha):
            phi, theta, _ = merit(ys + alpha * dy, s + alpha * ds, mu)
            switching = (dphi < 0) & (
                alpha * (-dphi) ** 2.3 > 1.0 * jnp.maximum(theta0, 0.0) ** 1.1
            )
            armijo = phi <= phi0 + eta * alpha * dphi
            f_type = switching & (theta0 <= theta_min)
            suff = (theta <= (1 - 1e-5) * theta0) | (phi <= phi0 - 1e-5 * theta0)
            in_filter = jnp.any((theta >= fil_theta) & (phi >= fil_phi))
            ok_h = suff & ~in_filter & (theta <= st["theta_max"])
            ok = jnp.where(f_type, armijo & (theta <= st["theta_max"]), ok_h)
            return ok & jnp.isfinite(phi) & jnp.isfinite(theta), f_type

        def ls_cond(c_):
            alpha, n, accepted, _ = c_
            return (~accepted) & (n < 30)

        def ls_body(c_):
            alpha, n, _, _ = c_
            alpha = jnp.where(n == 0, alpha, 0.5 * alpha)
            ok, f_type = acceptable(alpha)
            return alpha, n + 1, ok, f_type

        alpha, nls, ls_ok, f_type = jax.lax.while_loop(
            ls_cond, ls_body, _strong((alpha_p, 0, False, False))
        )
        # augment the filter after h-type steps (and after a failed search, to move on)
        augment = ~f_type & ls_ok
        slot = st["filter_next"] % fil_theta.shape[0]
        fil_theta = jnp.where(augment, fil_theta.at[slot].set((1 - 1e-5) * theta0), fil_theta)
        fil_phi = jnp.where(augment, fil_phi.at[slot].set(phi0 - 1e-5 * theta0), fil_phi)
        # a failed search (no restoration phase here): take the shortest trial step and
        # forget the filter, so that the next iteration is not blocked by its own history
        fil_theta = jnp.where(ls_ok, fil_theta, jnp.inf)
        fil_phi = jnp.where(ls_ok, fil_phi, jnp.inf)
        filter_next = st["filter_next"] + augment.astype(jnp.int32)
        ys_n = ys + alpha * dy
        s_n = jnp.where(mg > 0, jnp.maximum(s + alpha * ds, 1e-300), 1.0)
        z_n = jnp.where(mg > 0, z + alpha_d * dz, 0.0)
        z_n = jnp.where(
            mg > 0,
            jnp.clip(z_n, mu / (kappa_sigma * s_n), kappa_sigma * mu / s_n),
            0.0,
        )
        lam_n = lam + alpha * dlam
        nu_n = nu_ + alpha * dnu

        it = st["it"]
        logs = st["log"]
        logs = dict(
            objective=logs["objective"].at[it].set(f),
            inf_pr=logs["inf_pr"].at[it].set(inf_pr),
            inf_du=logs["inf_du"].at[it].set(inf_du),
            mu=logs["mu"].at[it].set(mu),
            alpha=logs["alpha"].at[it].set(alpha),
            regularisation=logs["regularisation"].at[it].set(delta),
        )
        if options.verbose:
            jax.debug.callback(_print_iter, it, f, inf_pr, inf_du, mu, alpha, delta, nls)

        finite = jnp.all(jnp.isfinite(ys_n)) & jnp.all(jnp.isfinite(lam_n))
        last = it == options.max_iter - 1
        keep = lambda new, old: jnp.where(converged | ~finite | last, old, new)
        status = jnp.where(converged, SUCCESS, jnp.where(finite, MAX_ITERATIONS, NONFINITE))
        return dict(
            ys=keep(ys_n, ys), s=keep(s_n, s), z=keep(z_n, z), lam=keep(lam_n, lam),
            nu=keep(nu_n, nu_), mu=mu, delta_last=delta_last,
            filter_theta=fil_theta, filter_phi=fil_phi, filter_next=filter_next,
            theta_min=st["theta_min"], theta_max=st["theta_max"],
            it=it + jnp.where(converged, 0, 1), done=converged | ~finite, status=status,
            log=logs, err=err0, inf_pr=inf_pr, inf_du=inf_du, compl=compl, f=f,
        )

    def cond(st):
        return (~st["done"]) & (st["it"] < options.max_iter)

    st = jax.lax.while_loop(cond, body, state0)
    ys, lam, nu_, z = st["ys"], st["lam"], st["nu"], st["z"]
    # residuals were evaluated at the returned iterate (no step is taken on the last pass)
    f, inf_pr, inf_du, compl = st["f"], st["inf_pr"], st["inf_du"], st["compl"]
    status = st["status"]
    return IPSolution(
        xs=ys[:, :nx], us=ys[:-1, nx:], lam=lam, nu=nu_, z=z, status=status,
        iterations=st["it"], objective=f, inf_pr=inf_pr, inf_du=inf_du, compl=compl,
        log=st["log"],
    )


def stage_jacobian_sparsity(prob: AbstractStagewiseNLP) -> dict[str, Any]:
    """Sizes of the structured problem (for reports): variables, constraints, block size."""
    lay = _layout(prob)
    n_var = (lay.M + 1) * lay.nx + lay.M * lay.nu
    n_eq = lay.M * lay.nx + lay.ne0 + lay.neT
    n_ineq = lay.M * lay.nh + lay.ni0 + lay.niT
    return dict(variables=n_var, equalities=n_eq, inequalities=n_ineq, block_size=lay.nb)
