r"""Fixed-step solvers for linear friction-state equations on a data grid.

`ExponentialIntegrator` integrates $\dot y = b(t) - a(t)\odot y$ ($a \ge 0$) by the
exponential midpoint rule: unconditionally stable and exact in the quasi-static limit, which
is what the stiff friction state of eq. 22 needs when it is driven by measured speeds.
`StepMapTerm` and `StepMapSolver` run any exact one-step map $y \mapsto y^+$ through
`diffrax.diffeqsolve` (so that forward-mode sensitivities of the map share the solve).
"""

from __future__ import annotations

from typing import Any, ClassVar

import diffrax as dfx
import jax
import jax.numpy as jnp

from .._math import one_minus_exp_over


class ExponentialIntegrator(dfx.AbstractSolver):
    r"""Exponential (Lawson-free) midpoint rule for $\dot y = b(t) - a(t)\odot y$, $a\ge0$.

    With $f_m = f(t_m, y_0)$ and $a = -\partial f/\partial y$ (diagonal, one JVP) at the
    midpoint $t_m$ of the step $h$: $y_1 = y_0 + h\,\varphi(ah)\,f_m$,
    $\varphi(x) = (1-e^{-x})/x$, i.e. $y_1 = e^{-ah}y_0 + h\varphi(ah)b$: exact when $a$, $b$
    are constant over the step, second order otherwise, unconditionally stable. Fixed steps
    only (no error estimate); for vector fields affine in $y$ with a diagonal linear part.
    """

    term_structure: ClassVar = dfx.AbstractTerm
    interpolation_cls: ClassVar = dfx.LocalLinearInterpolation

    def order(self, terms):
        return 2

    def init(self, terms, t0, t1, y0, args):
        return None

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        h = t1 - t0
        f, dfdy = jax.jvp(lambda y: terms.vf(t0 + 0.5 * h, y, args), (y0,),
                          (jnp.ones_like(y0),))
        y1 = y0 + h * one_minus_exp_over(-dfdy * h) * f
        return y1, None, dict(y0=y0, y1=y1), None, dfx.RESULTS.successful

    def func(self, terms, t0, y0, args):
        return terms.vf(t0, y0, args)


class StepMapTerm(dfx.AbstractTerm):
    r"""A term whose `vf` is the exact step map of a unit step, $y \mapsto y^+$ (for
    `StepMapSolver`; not a $dy/dt$)."""

    step_map: Any

    def vf(self, t, y, args):
        return self.step_map(t, y, args)

    def contr(self, t0, t1, **kwargs):
        return t1 - t0

    def prod(self, vf, control):
        raise NotImplementedError("a step map has no product with a control")


class StepMapSolver(dfx.AbstractSolver):
    r"""Fixed unit steps $y_1 = \Phi(t_m, y_0)$ of a `StepMapTerm` ($t_m$ the midpoint)."""

    term_structure: ClassVar = StepMapTerm
    interpolation_cls: ClassVar = dfx.LocalLinearInterpolation

    def order(self, terms):
        return 2

    def init(self, terms, t0, t1, y0, args):
        return None

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        y1 = terms.vf(0.5 * (t0 + t1), y0, args)
        return y1, None, dict(y0=y0, y1=y1), None, dfx.RESULTS.successful

    def func(self, terms, t0, y0, args):
        raise NotImplementedError("a step map has no vector field")
