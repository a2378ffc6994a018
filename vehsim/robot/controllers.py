r"""The eight unicycle controllers of report Table 1.

Controllers 1-3 and 5-8 are *chained* controllers: pure functions
$(t, x) \mapsto (u_1, u_2)$ of the chained state $x = (x_1, x_2, x_3)$ of eq. 3, with
$\dot x_1 = u_1$, $\dot x_2 = u_2$, $\dot x_3 = x_1u_2$ and $s = x_3 - x_1x_2/2$. Laws
written in the papers for the chained form $\dot z_3 = z_2u_1$ (or for Brockett's
integrator) are rewritten in this form, which is the same system with the coordinates
relabelled (the docstrings give the law as used here). They act on the robot through an
`AbstractSystem` (System I or II): `velocity(t, pose, system)` returns $(v, \omega)$.
Controller 4 (Aicardi et al.) is written in polar coordinates of the pose and ignores the
system.

Gains are array fields, so a bank of controllers (`default_controllers`) is one PyTree and a
whole grid of runs is one vmapped, jitted call (`vehsim.robot.khepera.simulate_robot_grid`).
The "documented time" of each controller (`DOCUMENTED_TIME`) is the time its closed loop
on the ideal plant needs to bring the generic pose of the tests to 1 mm and 1 degree.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import check_count, check_positive, is_concrete
from .._fields import array_field
from .._math import safe_sqrt, wrap_angle
from .unicycle import AbstractSystem, Chained, Pose, s_function


def _safe_den(den):
    """(den with zeros replaced by 1, is_zero): the first half of the double-where trick."""
    zero = den == 0
    return jnp.where(zero, jnp.ones_like(den), den), zero


class AbstractController(eqx.Module):
    r"""A feedback law for the unicycle: `velocity(t, pose, system)` -> $(v, \omega)$.

    Subclasses name the gains that must be positive in `positive_gains`; they are checked
    at construction (a `ValueError` naming the controller and the gain)."""

    positive_gains: ClassVar[tuple[str, ...]] = ()

    def __check_init__(self):
        for name in self.positive_gains:
            check_positive(type(self).__name__, name, getattr(self, name))

    @abc.abstractmethod
    def velocity(self, t, pose: Pose, system: AbstractSystem) -> tuple[Array, Array]:
        r"""Unicycle inputs $(v, \omega)$ [m/s, rad/s] at time `t` and (measured) `pose`."""


class AbstractChainedController(AbstractController):
    r"""A law $u = k(t, x)$ for the nonholonomic integrator of eq. 3."""

    @abc.abstractmethod
    def __call__(self, t, x: Chained) -> Float[Array, 2]:
        r"""Chained inputs $(u_1, u_2)$ at time `t` and chained state `x`."""

    def velocity(self, t, pose: Pose, system: AbstractSystem) -> tuple[Array, Array]:
        x = system.to_chained(pose)
        u = jax.lax.optimization_barrier(self(t, x))
        return system.velocity(pose, u, x)


class DiscontinuousController(AbstractChainedController):
    r"""Controller 1: the discontinuous exponential law of eq. 1 with the region of eq. 4.

    With $\nu = \sqrt{x_1^2+x_2^2}$ and $\eta = s/\nu$ (eq. 4),

    $$u_1 = -kx_1 + \mu\frac{s}{\nu^2}x_2,\qquad u_2 = -kx_2 - \mu\frac{s}{\nu^2}x_1$$

    in the good region $D^g = \{|\eta| < \bar\eta\}$, and $u_1 = k_s\,\mathrm{sgn}(s)$,
    $u_2 = 0$ in $D^b = \{|\eta| \ge \bar\eta\}$ (including the $x_3$-axis $\nu = 0$).
    In $D^g$: $\dot s = -\mu s/2$, $\dot\nu = -k\nu$, hence
    $\dot\eta = (k - \mu/2)\eta$: for $\mu > 2k$ the region $D^g$ is invariant and the
    state converges exponentially. In $D^b$ the state leaves in finite time ($\nu$ grows
    linearly). Gains used: $k = 1$, $\mu = 3$, $\bar\eta = 2$, $k_s = 2$ (1/s).

    **Documented time** (`DOCUMENTED_TIME`): 8 s -- from the generic pose $(-0.1\,\mathrm{m},
    0.05\,\mathrm{m}, 0.3)$ on the ideal plant (System I) it is within 1 mm and 1 deg of the
    origin from 8 s on.
    """

    k: Float[Array, ""] = array_field(default=1.0)
    mu: Float[Array, ""] = array_field(default=3.0)
    eta_bar: Float[Array, ""] = array_field(default=2.0)
    k_s: Float[Array, ""] = array_field(default=2.0)

    def __check_init__(self):
        check_positive("DiscontinuousController", "k", self.k)
        if is_concrete(self.k) and is_concrete(self.mu) and not float(self.mu) > 2 * float(self.k):
            raise ValueError(f"DiscontinuousController needs mu > 2 k (invariance of D^g), got "
                             f"mu={float(self.mu)}, k={float(self.k)}")
        check_positive("DiscontinuousController", "eta_bar", self.eta_bar)
        check_positive("DiscontinuousController", "k_s", self.k_s)

    def in_bad_region(self, x: Chained):
        r"""True in $D^b_{\bar\eta} = \{|s| \ge \bar\eta\,\nu\}$ (eq. 4), $\nu = 0$ included."""
        s = s_function(x)
        nu2 = x[0] ** 2 + x[1] ** 2
        return (s * s >= self.eta_bar**2 * nu2) & (s != 0)

    def __call__(self, t, x: Chained) -> Float[Array, 2]:
        s = s_function(x)
        bad = self.in_bad_region(x)
        nu2, _ = _safe_den(x[0] ** 2 + x[1] ** 2)
        nu2 = jnp.where(bad, jnp.ones_like(nu2), nu2)
        a = self.mu * s / nu2
        good_u = jnp.stack([-self.k * x[0] + a * x[1], -self.k * x[1] - a * x[0]])
        bad_u = jnp.stack([self.k_s * jnp.sign(s), jnp.zeros_like(s)])
        return jnp.where(bad, bad_u, good_u)


def _sat(z):
    r"""$\mathrm{sat}(z) = \min\{1, |z|\}\,\mathrm{sgn}(z)$."""
    return jnp.clip(z, -1.0, 1.0)


class BoundedController(AbstractChainedController):
    r"""Controller 2: the bounded discontinuous law of eqs. 5-7.

    $$u_1 = -k\frac{x_1}{\sqrt{\nu^2+1}} + \mu\,\mathrm{sat}_2(s,\nu),\qquad
      u_2 = -k\frac{x_2}{\sqrt{\nu^2+1}} - \mu\,\mathrm{sat}_1(s,\nu),$$

    $\mathrm{sat}_i = \mathrm{sat}(s/\nu)\,x_i/\nu$ for $\nu\ne0$ and $\mathrm{sgn}(s)$ for
    $\nu = 0$ (eq. 7). The gain $k$ switches with the region: $k = k_{in}$ where
    $|\eta| < 1$ and $k = k_{out}$ where $|\eta| \ge 1$, with (6a) $\mu > 2k_{in} > 0$ and
    (6b) $\mu > -2k_{out} > 0$ (checked at construction). Outside, $\nu$ grows and
    $2\dot s = -\mu\,\mathrm{sgn}(s)\,\nu$ so $|\eta|$ falls below 1; inside,
    $\dot s = -\mu s/2$ and $\nu$ decays. Each input obeys
    $|u_i| \le \max(|k_{in}|, |k_{out}|) + \mu$ (`input_bound`).
    Gains used: $k_{in} = 1$, $k_{out} = -0.5$, $\mu = 3$ (1/s).

    **Documented time** (`DOCUMENTED_TIME`): 8 s -- from the generic pose $(-0.1\,\mathrm{m},
    0.05\,\mathrm{m}, 0.3)$ on the ideal plant (System I) it is within 1 mm and 1 deg of the
    origin from 8 s on.
    """

    k_in: Float[Array, ""] = array_field(default=1.0)
    k_out: Float[Array, ""] = array_field(default=-0.5)
    mu: Float[Array, ""] = array_field(default=3.0)

    def __check_init__(self):
        if is_concrete(self.k_in) and is_concrete(self.mu):
            if not (float(self.mu) > 2 * float(self.k_in) > 0):
                raise ValueError(
                    f"BoundedController needs mu > 2 k_in > 0 (eq. 6a), got mu={float(self.mu)}"
                    f", k_in={float(self.k_in)}")
        if is_concrete(self.k_out) and is_concrete(self.mu):
            if not (float(self.mu) > -2 * float(self.k_out) > 0):
                raise ValueError(
                    f"BoundedController needs mu > -2 k_out > 0 (eq. 6b), got mu="
                    f"{float(self.mu)}, k_out={float(self.k_out)}")

    def input_bound(self):
        r"""$\max(|k_{in}|, |k_{out}|) + \mu$, a bound on $|u_1|$ and $|u_2|$."""
        return jnp.maximum(jnp.abs(self.k_in), jnp.abs(self.k_out)) + self.mu

    def __call__(self, t, x: Chained) -> Float[Array, 2]:
        s = s_function(x)
        nu2 = x[0] ** 2 + x[1] ** 2
        nu2_safe, zero = _safe_den(nu2)
        nu_safe = jnp.sqrt(nu2_safe)
        eta = s / nu_safe
        sat_eta = _sat(eta)
        sat1 = jnp.where(zero, jnp.sign(s), sat_eta * x[0] / nu_safe)
        sat2 = jnp.where(zero, jnp.sign(s), sat_eta * x[1] / nu_safe)
        outside = zero | (jnp.abs(eta) >= 1)
        k = jnp.where(outside & (s != 0), self.k_out, self.k_in)
        den = jnp.sqrt(nu2 + 1)
        return jnp.stack([-k * x[0] / den + self.mu * sat2, -k * x[1] / den - self.mu * sat1])


class TwoStageController(AbstractChainedController):
    r"""Controller 3: the two-stage switching law of Khennouf and Canudas de Wit [16].

    Their construction for Brockett's integrator $\dot z = x_1u_2 - x_2u_1$ (here
    $z = 2s$) first steers the state onto the manifold $M = \{W = c|z|\}$,
    $W = x_1^2 + x_2^2$, and then keeps it on $M$ while both decay exponentially:

    - stage 1, $W < c|z|$ (near the $x_3$-axis): $u = k_1\sqrt{|z|}\,(x_1, x_2)/\sqrt W$
      (or $(k_1\sqrt{|z|}, 0)$ on the axis), which makes $\sqrt W$ grow at rate
      $k_1\sqrt{|z|}$ with $z$ fixed, so $M$ is reached in finite time (the speed scales
      like the homogeneous size $\sqrt{|z|}$, so it vanishes at the origin);
    - stage 2, $W \ge c|z|$: $u_1 = -kx_1 + \alpha x_2$, $u_2 = -kx_2 - \alpha x_1$ with
      $\alpha = 2kz/W$, giving $\dot W = -2kW$ and $\dot z = -\alpha W = -2kz$, so $W/|z|$
      is constant: a state that enters stage 2 through $\partial M$ slides *on* the
      switching surface, which is what makes this law chatter on a real plant.

    (Law reconstructed from the paper's construction; its exact switching function is not
    in the report.) Gains used: $k = 1$, $k_1 = 2$, $c = 1$.

    **Documented time** (`DOCUMENTED_TIME`): 8 s -- from the generic pose $(-0.1\,\mathrm{m},
    0.05\,\mathrm{m}, 0.3)$ on the ideal plant (System I) it is within 1 mm and 1 deg of the
    origin from 8 s on.
    """

    k: Float[Array, ""] = array_field(default=1.0)
    k1: Float[Array, ""] = array_field(default=2.0)
    c: Float[Array, ""] = array_field(default=1.0)

    positive_gains: ClassVar[tuple[str, ...]] = ("k", "k1", "c")

    def __call__(self, t, x: Chained) -> Float[Array, 2]:
        z = 2 * s_function(x)
        w = x[0] ** 2 + x[1] ** 2
        stage1 = w < self.c * jnp.abs(z)
        w_safe, zero = _safe_den(w)
        root = jnp.sqrt(w_safe)
        speed = self.k1 * safe_sqrt(jnp.abs(z))
        u_stage1 = jnp.where(zero, jnp.stack([speed, 0 * speed]),
                             speed * jnp.stack([x[0], x[1]]) / root)
        alpha = 2 * self.k * z / w_safe
        u_stage2 = jnp.stack([-self.k * x[0] + alpha * x[1], -self.k * x[1] - alpha * x[0]])
        return jnp.where(stage1, u_stage1, u_stage2)


class PolarController(AbstractController):
    r"""Controller 4: Aicardi, Casalino, Bicchi and Balestrino [17], polar coordinates.

    With $e = \sqrt{x^2+y^2}$, $\theta = \mathrm{atan2}(-y, -x)$ (direction of the goal
    seen from the robot) and $\alpha = \theta - \gamma$ (wrapped to $(-\pi,\pi]$),
    the kinematics are $\dot e = -v\cos\alpha$, $\dot\alpha = -\omega + v\sin\alpha/e$,
    $\dot\theta = v\sin\alpha/e$, and the law

    $$v = \lambda e\cos\alpha,\qquad
      \omega = k\alpha + \lambda\frac{\cos\alpha\sin\alpha}{\alpha}(\alpha + h\theta)$$

    makes $V = \tfrac12(e^2 + \alpha^2 + h\theta^2)$ decrease:
    $\dot V = -\lambda e^2\cos^2\alpha - k\alpha^2$. Smooth in $(e,\alpha,\theta)$ but
    $\theta$ is undefined at $e = 0$: near the goal, sensor noise in $(x, y)$ moves $\theta$
    by large amounts, which shows up as heading oscillations. Gains used: $\lambda = 1$
    (1/s), $k = 3$ (1/s), $h = 1.5$.

    **Documented time** (`DOCUMENTED_TIME`): 10 s -- from the generic pose $(-0.1\,\mathrm{m},
    0.05\,\mathrm{m}, 0.3)$ on the ideal plant (System I) it is within 1 mm and 1 deg of the
    origin from 10 s on.
    """

    lam: Float[Array, ""] = array_field(default=1.0)
    k: Float[Array, ""] = array_field(default=3.0)
    h: Float[Array, ""] = array_field(default=1.5)

    positive_gains: ClassVar[tuple[str, ...]] = ("lam", "k", "h")

    def velocity(self, t, pose: Pose, system: AbstractSystem) -> tuple[Array, Array]:
        x, y = pose[0], pose[1]
        e2 = x * x + y * y
        at_goal = e2 == 0
        e = jnp.sqrt(jnp.where(at_goal, jnp.ones_like(e2), e2))
        e = jnp.where(at_goal, jnp.zeros_like(e), e)
        theta = jnp.arctan2(-y, jnp.where(at_goal, -jnp.ones_like(x), -x))
        theta = jnp.where(at_goal, jnp.zeros_like(theta), theta)
        alpha = wrap_angle(theta - pose[2])
        small = jnp.abs(alpha) < 1e-6
        a_safe = jnp.where(small, jnp.ones_like(alpha), alpha)
        sinc = jnp.where(small, 1.0 - alpha**2 / 6, jnp.sin(a_safe) / a_safe)
        v = self.lam * e * jnp.cos(alpha)
        omega = self.k * alpha + self.lam * jnp.cos(alpha) * sinc * (alpha + self.h * theta)
        return v, omega


class TeelMurrayWalshController(AbstractChainedController):
    r"""Controller 5: Teel, Murray and Walsh [12], smooth time-periodic feedback.

    $$u_1 = -k x_1 + a\,x_3\cos\omega t,\qquad u_2 = -k x_2 - a\,x_3^2\sin\omega t.$$

    Averaging ($x_1 \approx a x_3(\cos+\sin)/2$, $\dot x_2 \approx -a x_3^2(\cos+\sin)/2$
    for $k = \omega = 1$) gives $\dot x_3 \approx -a^2x_3^3/4$: asymptotic but only
    polynomial convergence, $x_3 \sim 1/\sqrt t$ -- very slow near the origin.
    Gains used: $k = 1$, $a = 1$, $\omega = 1$ rad/s.

    **Documented time** (`DOCUMENTED_TIME`): none. The law is smooth, so the closed loop is
    $C^1$, and a $C^1$ closed loop that converged exponentially would have an exponentially
    stable linearisation, which the nonholonomic integrator cannot have ($\dot x_3 = 0$ to
    first order): a time-varying feedback that stabilises a driftless system exponentially
    is necessarily non-Lipschitz (M'Closkey and Murray 1997 [21], which is why they went to
    the homogeneous laws of controllers 6 and 8). From the generic pose on the ideal plant
    the heading is within 1 deg after 400 s, but the largest position error over
    $[t/2, t]$ is still above 1 mm at $t = 1600$ s (about 6-7 mm) and halves when $t$
    quadruples ($t^{-1/2}$), so 1 mm would take of order $10^4$-$10^5$ s (extrapolated).
    A larger $a$ helps little (at 1600 s: 4.3 mm for $a = 2$, 3.7 mm for $a = 4$), and no gain
    makes it exponential.
    """

    k: Float[Array, ""] = array_field(default=1.0)
    a: Float[Array, ""] = array_field(default=1.0)
    omega: Float[Array, ""] = array_field(default=1.0)

    positive_gains: ClassVar[tuple[str, ...]] = ("k", "a", "omega")

    def __call__(self, t, x: Chained) -> Float[Array, 2]:
        wt = self.omega * t
        return jnp.stack([-self.k * x[0] + self.a * x[2] * jnp.cos(wt),
                          -self.k * x[1] - self.a * x[2] ** 2 * jnp.sin(wt)])


def _homogeneous_law(x, rho, t, k, a, omega):
    rho_safe, zero = _safe_den(rho)
    u1 = -k * x[0] + a * jnp.where(zero, 0.0, x[2] / rho_safe) * jnp.cos(omega * t)
    u2 = -k * x[1] - a * jnp.where(zero, 0.0, x[2] ** 2 / rho_safe**3) * jnp.sin(omega * t)
    return jnp.stack([u1, u2])


class MCloskeyMurray93Controller(AbstractChainedController):
    r"""Controller 6: M'Closkey and Murray 1993 [13], time-periodic, homogeneous of degree 1.

    Dilation weights $(1, 1, 2)$ and the homogeneous norm
    $\rho = (x_1^4 + x_2^4 + x_3^2)^{1/4}$:

    $$u_1 = -kx_1 + a\frac{x_3}{\rho}\cos\omega t,\qquad
      u_2 = -kx_2 - a\frac{x_3^2}{\rho^3}\sin\omega t.$$

    Every term scales like $\rho$, so the averaged system (with $\dot x_3 \approx
    -a^2x_3^3/(4\rho^4)$) converges exponentially in $\rho$ -- but slowly, since its rate
    is set by the oscillation. Gains used: $k = 1$, $a = 1$, $\omega = 1$ rad/s.

    **Documented time** (`DOCUMENTED_TIME`): 40 s -- from the generic pose $(-0.1\,\mathrm{m},
    0.05\,\mathrm{m}, 0.3)$ on the ideal plant (System I) it is within 1 mm and 1 deg of the
    origin from 40 s on.
    """

    k: Float[Array, ""] = array_field(default=1.0)
    a: Float[Array, ""] = array_field(default=1.0)
    omega: Float[Array, ""] = array_field(default=1.0)

    positive_gains: ClassVar[tuple[str, ...]] = ("k", "a", "omega")

    def __call__(self, t, x: Chained) -> Float[Array, 2]:
        q = x[0] ** 4 + x[1] ** 4 + x[2] ** 2
        q_safe, zero = _safe_den(q)
        rho = jnp.where(zero, 0.0, jnp.sqrt(jnp.sqrt(q_safe)))
        return _homogeneous_law(x, rho, t, self.k, self.a, self.omega)


class PometController(AbstractChainedController):
    r"""Controller 7: Pomet's Lyapunov-based time-varying law [9].

    Pomet's construction: with $V(t, x) = \tfrac12[(x_1 + x_3\cos t)^2 + x_2^2 + x_3^2]$
    and $\dot x_3 = x_1u_2$,

    $$\dot V = p\,(u_1 - \omega x_3\sin\omega t) + u_2\,b,\quad p = x_1 + x_3\cos\omega t,\
      b = p\,x_1\cos\omega t + x_2 + x_1x_3,$$

    (written with $\cos\omega t$ for $\cos t$) and the feedback
    $u_1 = -p + \omega x_3\sin\omega t$, $u_2 = -b$ makes $\dot V = -p^2 - b^2 \le 0$; the
    time variation makes the origin globally asymptotically stable (not exponentially).
    With a gain $k > 0$ ($u_1 = -kp + \omega x_3\sin\omega t$, $u_2 = -kb$) the same argument
    gives $\dot V = -k(p^2 + b^2)$. Gains used: $k = 1$, $\omega = 1$ rad/s.

    **Documented time** (`DOCUMENTED_TIME`): none, for the reason given in
    `TeelMurrayWalshController` (a smooth time-varying law cannot converge exponentially).
    Measured on the ideal plant from the generic pose: heading within 1 deg after 400 s,
    position error still 6-7 mm at 1600 s and halving when $t$ quadruples. Its gain $k$
    cannot make it exponential either.
    """

    k: Float[Array, ""] = array_field(default=1.0)
    omega: Float[Array, ""] = array_field(default=1.0)

    positive_gains: ClassVar[tuple[str, ...]] = ("k", "omega")

    def lyapunov(self, t, x: Chained):
        """Pomet's $V(t, x)$ (non-increasing along closed-loop solutions)."""
        c = jnp.cos(self.omega * t)
        return 0.5 * ((x[0] + x[2] * c) ** 2 + x[1] ** 2 + x[2] ** 2)

    def __call__(self, t, x: Chained) -> Float[Array, 2]:
        wt = self.omega * t
        c, s = jnp.cos(wt), jnp.sin(wt)
        p = x[0] + x[2] * c
        # dV/dt includes the explicit time derivative -x3 sin(wt) * omega * p
        u1 = -self.k * p + self.omega * x[2] * s
        b = p * x[0] * c + x[1] + x[0] * x[2]
        return jnp.stack([u1, -self.k * b])


def homogeneous_norm_newton(x: Chained, steps: int = 6):
    r"""$\rho(x) > 0$ solving $x_1^2/\rho^2 + x_2^2/\rho^2 + x_3^2/\rho^4 = 1$ by Newton.

    This is the implicit homogeneous norm of M'Closkey and Murray 1997 (the dilation
    $\Delta_\lambda x = (\lambda x_1, \lambda x_2, \lambda^2 x_3)$ with $\lambda = 1/\rho$
    brings $x$ to the unit sphere). Newton on $f(r) = r^4 - a r^2 - x_3^2$ with $r = \rho$,
    $a = x_1^2 + x_2^2$, started from $r_0 = \sqrt{a} + \sqrt{|x_3|} \ge \rho$: $f$ is convex on
    $[\rho, \infty)$ (as $\rho \ge \sqrt a$), so the iterates decrease monotonically to
    $\rho$. A fixed number of steps, so it runs inside `jit`/`vmap`. Returns 0 at the
    origin. (For three states the root is also
    $\rho^2 = (a + \sqrt{a^2 + 4x_3^2})/2$, which the tests use as the reference.)
    """
    a = x[0] ** 2 + x[1] ** 2
    b = x[2] ** 2
    r0 = safe_sqrt(a) + safe_sqrt(safe_sqrt(b))
    r0_safe, zero = _safe_den(r0)

    def body(_, r):
        f = r**4 - a * r**2 - b
        df = 4 * r**3 - 2 * a * r
        return r - f / df

    r = r0_safe
    for i in range(steps):  # unrolled (a few steps): no loop
        r = body(i, r)
    return jnp.where(zero, 0.0, r)


class MCloskeyMurray97Controller(AbstractChainedController):
    r"""Controller 8: M'Closkey and Murray 1997 [21], homogeneous exponential stabiliser.

    Same structure as controller 6 but with the homogeneous norm defined implicitly by
    $\|\Delta_{1/\rho}x\|_2 = 1$, i.e. $x_1^2/\rho^2 + x_2^2/\rho^2 + x_3^2/\rho^4 = 1$, whose
    dilation parameter is found by a Newton iteration each step
    (`homogeneous_norm_newton`, the difficulty the report mentions), and faster gains:

    $$u_1 = -kx_1 + a\frac{x_3}{\rho}\cos\omega t,\qquad
      u_2 = -kx_2 - a\frac{x_3^2}{\rho^3}\sin\omega t,$$

    exponentially stable (the closed loop is homogeneous of degree 0 and its
    averaged part has rate $\approx a^2/4$). Gains used: $k = 2$, $a = 2$, $\omega = 2$
    rad/s, 6 Newton steps.

    **Documented time** (`DOCUMENTED_TIME`): 25 s -- from the generic pose $(-0.1\,\mathrm{m},
    0.05\,\mathrm{m}, 0.3)$ on the ideal plant (System I) it is within 1 mm and 1 deg of the
    origin from 25 s on.
    """

    k: Float[Array, ""] = array_field(default=2.0)
    a: Float[Array, ""] = array_field(default=2.0)
    omega: Float[Array, ""] = array_field(default=2.0)
    newton_steps: int = eqx.field(static=True, default=6)

    positive_gains: ClassVar[tuple[str, ...]] = ("k", "a", "omega")

    def __check_init__(self):
        check_count(type(self).__name__, "newton_steps", self.newton_steps)

    def __call__(self, t, x: Chained) -> Float[Array, 2]:
        rho = homogeneous_norm_newton(x, self.newton_steps)
        return _homogeneous_law(x, rho, t, self.k, self.a, self.omega)


CONTROLLER_NAMES: tuple[str, ...] = (
    "1 discontinuous (eq. 1)", "2 bounded (eq. 5)", "3 Khennouf-Canudas", "4 Aicardi polar",
    "5 Teel-Murray-Walsh", "6 M'Closkey-Murray 93", "7 Pomet", "8 M'Closkey-Murray 97",
)


def default_controllers() -> tuple[AbstractController, ...]:
    """The eight controllers of Table 1 with the gains of their docstrings, in order."""
    return (DiscontinuousController(), BoundedController(), TwoStageController(),
            PolarController(), TeelMurrayWalshController(), MCloskeyMurray93Controller(),
            PometController(), MCloskeyMurray97Controller())


DOCUMENTED_TIME: dict[str, float | None] = {
    "DiscontinuousController": 8.0,
    "BoundedController": 8.0,
    "TwoStageController": 8.0,
    "PolarController": 10.0,
    "TeelMurrayWalshController": None,
    "MCloskeyMurray93Controller": 40.0,
    "PometController": None,
    "MCloskeyMurray97Controller": 25.0,
}
r"""Time [s] from which each controller keeps the generic pose (-0.1 m, 0.05 m, 0.3 rad)
within 1 mm and 1 deg of the origin on the ideal plant (System I, default gains); each
controller's docstring states the same. `None`: never in practice (controllers 5 and 7 are
smooth, hence only polynomially convergent, $x_3 \sim t^{-1/2}$; see their docstrings)."""
