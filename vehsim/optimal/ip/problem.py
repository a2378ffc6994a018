r"""The problem interface: a stage-structured NLP, its padded layout and its stage function.

Over knots $k = 0..M$ with states $x_k \in \mathbb{R}^{n_x}$ and controls
$u_k \in \mathbb{R}^{n_u}$ ($u_M$ unused):

$$\min \sum_{k<M} \ell_k(x_k, u_k) + \phi(x_M)$$
$$\text{s.t.}\quad x_{k+1} = F_k(x_k, u_k),\quad h_k(x_k, u_k) \ge 0,
\quad e_0(x_0) = 0,\ i_0(x_0) \ge 0,\quad e_M(x_M) = 0,\ i_M(x_M) \ge 0.$$

Every knot carries the same padded blocks, $y_k = (x_k, u_k)$ with $u_M = 0$, equalities
padded to $n_e = \max(n_{e_0}, n_{e_M}, 1)$ and inequalities $g_k = (h_k, i_0, i_M)$, and 0/1
masks mark the rows in use at each knot. One vector function of $(y_k, k)$ then holds every
output of stage $k$, so derivatives are taken per stage under one `vmap`.
"""

from __future__ import annotations

import abc
import functools
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float


class AbstractStagewiseNLP(eqx.Module):
    """A stage-structured NLP (multiple shooting). Subclasses hold their parameters as array
    fields (so a batch of problems is a batched module) and implement the stage functions.

    Sizes are static int fields of the subclass: ``num_stages`` ($M$, segments),
    ``state_size`` ($n_x$), ``control_size`` ($n_u$).
    """

    @abc.abstractmethod
    def transition(self, x: Array, u: Array, k: Array) -> Array:
        """$F_k(x_k, u_k)$: the state at knot $k+1$ reached from knot $k$."""

    def transition_and_path(self, x: Array, u: Array, k: Array) -> tuple[Array, Array]:
        """$(F_k, h_k)$ together (override to share work, e.g. one integration)."""
        return self.transition(x, u, k), self.path_inequality(x, u, k)

    def stage_cost(self, x: Array, u: Array, k: Array) -> Array:
        r"""$\ell_k(x_k, u_k)$ (default 0)."""
        return jnp.zeros(())

    def terminal_cost(self, x: Array) -> Array:
        r"""$\phi(x_M)$ (default 0)."""
        return jnp.zeros(())

    def path_inequality(self, x: Array, u: Array, k: Array) -> Array:
        r"""$h_k(x_k, u_k) \ge 0$ for $k < M$ (default none)."""
        return jnp.zeros((0,))

    def initial_equality(self, x: Array) -> Array:
        """$e_0(x_0) = 0$ (default none)."""
        return jnp.zeros((0,))

    def initial_inequality(self, x: Array) -> Array:
        r"""$i_0(x_0) \ge 0$ (default none)."""
        return jnp.zeros((0,))

    def terminal_equality(self, x: Array) -> Array:
        """$e_M(x_M) = 0$ (default none)."""
        return jnp.zeros((0,))

    def terminal_inequality(self, x: Array) -> Array:
        r"""$i_M(x_M) \ge 0$ (default none)."""
        return jnp.zeros((0,))

    def linear_variables(self) -> tuple[int, ...]:
        r"""Indices into $y_k = (x_k, u_k)$ of the variables in which every stage function
        is affine with constant coefficients (a time state $t$ that only accumulates, a
        slack that enters additively): their rows and columns of the stage Lagrangian's
        Hessian vanish, so `stage_derivatives` takes second derivatives along the other
        directions only where they are a large enough share (`LINEAR_SHARE_MIN`): the same
        Hessian, fewer tangents. Default none. A wrong entry silently drops curvature:
        `check_linear_variables` tests a declaration."""
        return ()


class StageMasks(eqx.Module):
    """0/1 masks of the padded layout, one row per knot: equality rows (``eq``), inequality
    rows (``g``), defect multipliers (``lam``, knots $k < M$), controls (``u``, $k < M$) and
    primal unknowns (``y`` = (x, u): every state, the controls of $k < M$)."""

    eq: Float[Array, "M+1 ne"]
    g: Float[Array, "M+1 ng"]
    lam: Float[Array, "M+1 nx"]
    u: Float[Array, "M+1 nu"]
    y: Float[Array, "M+1 ny"]


class StageLayout(eqx.Module):
    """Static sizes of the padded stage layout: ``M`` stages, ``nx`` states, ``nu`` controls,
    ``ne`` padded equalities, ``nh`` path, ``ni0``/``niT`` initial/terminal inequalities,
    ``ne0``/``neT`` initial/terminal equalities."""

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
    def ny(self) -> int:
        """Primal unknowns per knot, $y_k = (x_k, u_k)$."""
        return self.nx + self.nu

    @property
    def ng(self) -> int:
        """Padded inequalities per knot, $g_k = (h_k, i_0, i_M)$."""
        return self.nh + self.ni0 + self.niT

    @property
    def nb(self) -> int:
        r"""Size of a KKT block, $(x_k, u_k, \lambda_k, \nu_k)$."""
        return 2 * self.nx + self.nu + self.ne

    def masks(self) -> StageMasks:
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
        y = np.concatenate([np.ones((M + 1, self.nx)), u], 1)
        return StageMasks(eq=jnp.asarray(eq), g=jnp.asarray(g), lam=jnp.asarray(lam),
                          u=jnp.asarray(u), y=jnp.asarray(y))

    def join(self, xs: Float[Array, "M+1 nx"], us: Float[Array, "M nu"]) -> Float[Array, "M+1 ny"]:
        """Knots and controls as the padded unknowns $y_k = (x_k, u_k)$, $u_M = 0$."""
        return jnp.concatenate([xs, jnp.concatenate([us, jnp.zeros((1, self.nu))], 0)], axis=1)

    def split(self, V: Float[Array, "M+1 n"]) -> tuple[Array, Array, Array, Array]:
        """The stage vectors (or their Jacobians) split into (cost, F, e, g)."""
        i_F, i_e, i_g = 1, 1 + self.nx, 1 + self.nx + self.ne
        return V[:, 0], V[:, i_F:i_e], V[:, i_e:i_g], V[:, i_g:]


def stage_layout(prob: AbstractStagewiseNLP) -> StageLayout:
    """The padded layout of ``prob`` (sizes read from the shapes of its stage functions)."""
    nx, nu, M = prob.state_size, prob.control_size, prob.num_stages
    x = jax.ShapeDtypeStruct((nx,), jnp.float64)
    u = jax.ShapeDtypeStruct((nu,), jnp.float64)
    k = jax.ShapeDtypeStruct((), jnp.int32)
    size = lambda f, *a: jax.eval_shape(f, *a).shape[0]
    ne0 = size(prob.initial_equality, x)
    neT = size(prob.terminal_equality, x)
    return StageLayout(
        M=M, nx=nx, nu=nu, ne=max(ne0, neT, 1),
        nh=size(prob.path_inequality, x, u, k),
        ni0=size(prob.initial_inequality, x), niT=size(prob.terminal_inequality, x),
        ne0=ne0, neT=neT,
    )


def stage_function(prob: AbstractStagewiseNLP, lay: StageLayout,
                   ys: Array) -> Callable[[Array, Array], Array]:
    """$(y_k, k) \\mapsto (\\ell_k + [k = M]\\phi, F_k, e_k, g_k)$ for $k = 0..M$ as one vector:
    one function to differentiate (one trace, one integration per stage). Rows not in use at
    knot $k$ are filled (0 for equalities, 1 for inequalities) and masked by `StageMasks`.

    The functions not in use at a knot are evaluated at a knot where they are (``ys``,
    without derivatives): the stage functions at $k = M$ with the last control $u_{M-1}$,
    the initial ones at $x_0$, the terminal ones at $x_M$. A masked value then never comes
    from a point outside the problem's domain (a cost $1/u$ at the dummy control $u_M = 0$),
    whose infinite derivatives would turn the masked zeros of a reverse-mode Hessian into
    NaN (the double-`where` rule)."""
    M, nx = lay.M, lay.nx
    anchors = jax.lax.stop_gradient((ys[0, :nx], ys[M, :nx], ys[M - 1, nx:]))
    return functools.partial(_stage_vector, prob, lay, anchors)


LINEAR_SHARE_MIN = 0.25
"""The share of $y_k$'s directions that `linear_variables` must declare for the Hessian to
skip them (`curved_variables`). Their Jacobian columns then take a forward pass of their own,
which on a CPU costs about what one skipped direction saves: a horizon problem's one linear
direction (of 12) is not worth it, a closed lap's nine (of 20) are (docs/performance.md,
"Linear directions skipped in the Hessian"). Skipping changes how XLA fuses the pass, so the
numbers agree to rounding, not always bit for bit."""


def curved_variables(prob: AbstractStagewiseNLP, lay: StageLayout,
                     share_min: float = LINEAR_SHARE_MIN) -> tuple[int, ...] | None:
    """The indices of $y_k$ not in ``prob.linear_variables()`` (sorted), or None (every
    direction taken) where those are fewer than ``share_min`` of the $n_y$. Raises
    ValueError for an index outside $0..n_y-1$ or repeated."""
    linear = tuple(int(i) for i in prob.linear_variables())
    if len(set(linear)) != len(linear) or not all(0 <= i < lay.ny for i in linear):
        raise ValueError(f"{type(prob).__name__}.linear_variables() must be distinct indices "
                         f"into y = (x, u), 0..{lay.ny - 1}; got {linear}")
    if not linear or len(linear) < share_min * lay.ny:
        return None
    return tuple(i for i in range(lay.ny) if i not in linear)


def _pad(v, n):
    return jnp.concatenate([v, jnp.zeros((n - v.shape[0],), v.dtype)])


@eqx.filter_jit
def _stage_vector(prob, lay, anchors, y, k):
    """`stage_function`'s vector at ``(y, k)``. A jitted function of fixed identity: the
    solver differentiates and evaluates the stage vector several times per iteration (values,
    Jacobians, the Hessian, the line search's trials), and each use then reuses its traced
    program (and JAX's cached transformations of it) instead of tracing the problem's Python
    again. XLA inlines the call: the compiled program computes the same numbers."""
    M, nx = lay.M, lay.nx
    x, u = y[:nx], y[nx:]
    x_first, x_last, u_last = anchors
    km = jnp.minimum(k, M - 1)
    u = jnp.where(k < M, u, u_last)
    x_initial = jnp.where(k == 0, x, x_first)
    x_terminal = jnp.where(k == M, x, x_last)
    F, h = prob.transition_and_path(x, u, km)
    cost = jnp.where(k < M, prob.stage_cost(x, u, km), 0.0) + jnp.where(
        k == M, prob.terminal_cost(x_terminal), 0.0
    )
    e0 = _pad(prob.initial_equality(x_initial), lay.ne)
    eT = _pad(prob.terminal_equality(x_terminal), lay.ne)
    e = jnp.where(k == 0, e0, jnp.where(k == M, eT, 0.0))
    i0 = prob.initial_inequality(x_initial)
    iT = prob.terminal_inequality(x_terminal)
    g = jnp.concatenate(
        [jnp.where(k < M, h, 1.0), jnp.where(k == 0, i0, 1.0), jnp.where(k == M, iT, 1.0)]
    )
    return jnp.concatenate([jnp.reshape(cost, (1,)), F, e, g])


def problem_sizes(prob: AbstractStagewiseNLP) -> dict[str, int]:
    """Sizes of the structured problem (for reports): variables, equalities, inequalities
    and the KKT block size."""
    lay = stage_layout(prob)
    n_var = (lay.M + 1) * lay.nx + lay.M * lay.nu
    n_eq = lay.M * lay.nx + lay.ne0 + lay.neT
    n_ineq = lay.M * lay.nh + lay.ni0 + lay.niT
    return dict(variables=n_var, equalities=n_eq, inequalities=n_ineq, block_size=lay.nb)
