r"""Unicycle kinematics and the two chained-form transformations (report 2.1, eq. 3).

A pose is the array $(x, y, \gamma)$ [m, m, rad]; the goal is the origin with heading 0.
The unicycle moves as $\dot x = v\cos\gamma$, $\dot y = v\sin\gamma$, $\dot\gamma = \omega$;
a differential drive with wheel base $b$ has wheel speeds $v_{L,R} = v \mp \omega b/2$.

Every controller of Table 1 except the polar one (controller 4) is written for the
*nonholonomic integrator*

$$\dot x_1 = u_1,\qquad \dot x_2 = u_2,\qquad \dot x_3 = x_1 u_2,$$

the form for which $s := x_3 - x_1x_2/2$ obeys $2\dot s = x_1u_2 - u_1x_2$ (eq. 2); the
coordinates of eq. 3 bring the unicycle to it. A *system* is a
change of coordinates pose -> $(x_1, x_2, x_3)$ together with the input map
$(u_1, u_2) \to (v, \omega)$. Positions are divided by a length scale $\ell$ (field `length`)
so that the chained coordinates are dimensionless and the controller gains mean the same on
any robot size.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import check_positive
from .._fields import array_field
from .._math import wrap_angle


Pose = Float[Array, "3"]
Chained = Float[Array, "3"]


def unicycle_rhs(pose: Pose, v, omega) -> Pose:
    r"""$(\dot x, \dot y, \dot\gamma) = (v\cos\gamma, v\sin\gamma, \omega)$."""
    return jnp.stack([v * jnp.cos(pose[2]), v * jnp.sin(pose[2]), omega * jnp.ones_like(v)])


def unicycle_step(pose: Pose, v, omega, h) -> Pose:
    r"""Exact pose after time $h$ at constant $(v, \omega)$ (an arc; a segment when $\omega=0$).

    The chord has length $v h\,\mathrm{sinc}(\omega h/2)$ and direction $\gamma + \omega h/2$,
    which is smooth (and differentiable) through $\omega = 0$.
    """
    half = 0.5 * omega * h
    chord = v * h * jnp.sinc(half / jnp.pi)
    mid = pose[2] + half
    return jnp.stack([pose[0] + chord * jnp.cos(mid), pose[1] + chord * jnp.sin(mid),
                      pose[2] + 2 * half])


def chained_rhs(x: Chained, u: Float[Array, 2]) -> Chained:
    r"""$(\dot x_1, \dot x_2, \dot x_3) = (u_1, u_2, x_1u_2)$ (the form eq. 2 implies)."""
    return jnp.stack([u[0], u[1], x[0] * u[1]])


def s_function(x: Chained):
    r"""$s(x) = x_3 - x_1x_2/2$ (after eq. 1), with $2\dot s = x_1u_2 - u_1x_2$ (eq. 2)."""
    return x[2] - 0.5 * x[0] * x[1]


def wheel_speeds(v, omega, wheel_base):
    r"""$(v_L, v_R) = (v - \omega b/2,\ v + \omega b/2)$ for a differential drive."""
    return jnp.stack([v - 0.5 * omega * wheel_base, v + 0.5 * omega * wheel_base])


def body_velocity(wheels: Float[Array, 2], wheel_base):
    r"""$(v, \omega) = ((v_L+v_R)/2,\ (v_R-v_L)/b)$, the inverse of `wheel_speeds`."""
    return 0.5 * (wheels[0] + wheels[1]), (wheels[1] - wheels[0]) / wheel_base


class AbstractSystem(eqx.Module):
    r"""A transformation of the unicycle to the nonholonomic integrator (eqs. 2-3).

    Subclasses define `to_chained` (pose -> $x$), `to_pose` (its inverse) and `velocity`
    ($(u_1,u_2)$ at a pose -> $(v, \omega)$).
    """

    @abc.abstractmethod
    def to_chained(self, pose: Pose) -> Chained:
        """Chained coordinates $(x_1, x_2, x_3)$ of a pose."""

    @abc.abstractmethod
    def to_pose(self, x: Chained) -> Pose:
        """The pose with chained coordinates `x` (inverse of `to_chained`)."""

    @abc.abstractmethod
    def velocity(self, pose: Pose, u: Float[Array, 2], x: Chained | None = None
                 ) -> tuple[Array, Array]:
        r"""Unicycle inputs $(v, \omega)$ that produce $\dot x = (u_1, u_2, x_1u_2)$
        (`x`: the chained coordinates of `pose`, if already computed)."""


class SystemI(AbstractSystem):
    r"""System I, report eq. 3 (positions in units of $\ell$, $\tilde x = x/\ell$):

    $$x_1 = \tilde x\cos\gamma + \tilde y\sin\gamma,\quad x_2 = \gamma,\quad
      x_3 = \tilde x\sin\gamma - \tilde y\cos\gamma.$$

    Then $\dot x_1 = v/\ell - x_3\omega$, $\dot x_2 = \omega$, $\dot x_3 = x_1\omega$, so
    $(v, \omega) = (\ell(u_1 + x_3u_2),\ u_2)$. A global diffeomorphism for
    $\gamma \in (-\pi, \pi]$ (the heading is wrapped before transforming); never singular.
    Inverse: $\tilde x = x_1\cos x_2 + x_3\sin x_2$, $\tilde y = x_1\sin x_2 - x_3\cos x_2$.
    """

    length: Float[Array, ""] = array_field(default=0.1)

    def __check_init__(self):
        check_positive("SystemI", "length", self.length)

    def to_chained(self, pose: Pose) -> Chained:
        x, y, g = pose[0] / self.length, pose[1] / self.length, wrap_angle(pose[2])
        c, s = jnp.cos(g), jnp.sin(g)
        return jnp.stack([x * c + y * s, g, x * s - y * c])

    def to_pose(self, x: Chained) -> Pose:
        c, s = jnp.cos(x[1]), jnp.sin(x[1])
        return jnp.stack([(x[0] * c + x[2] * s) * self.length,
                          (x[0] * s - x[2] * c) * self.length, x[1]])

    def velocity(self, pose: Pose, u: Float[Array, 2], x: Chained | None = None
                 ) -> tuple[Array, Array]:
        x = self.to_chained(pose) if x is None else x
        return self.length * (u[0] + x[2] * u[1]), u[1]


class SystemII(AbstractSystem):
    r"""System II: the classical chained form $z = (\tilde x, \tan\gamma, \tilde y)$
    (Murray and Sastry 1993), $\dot z_1 = u_1$, $\dot z_2 = u_2$, $\dot z_3 = z_2u_1$, brought
    to the integrator's form by $x_3 = z_1z_2 - z_3$:

    $$x_1 = \tilde x,\quad x_2 = \tan\gamma,\quad x_3 = \tilde x\tan\gamma - \tilde y.$$

    Input map: $u_1 = \dot{\tilde x} = v\cos\gamma/\ell$, $u_2 = \omega/\cos^2\gamma$, so
    $(v, \omega) = (\ell u_1/\cos\gamma,\ u_2\cos^2\gamma)$. **Singular** at
    $\gamma = \pm\pi/2$ (the robot perpendicular to the goal heading): $x_2$ and $v$ blow up
    there, and it cannot tell $\gamma$ from $\gamma+\pi$ (it is a chart on
    $|\gamma| < \pi/2$). Inverse: $\gamma = \arctan x_2$, $\tilde y = x_1x_2 - x_3$.
    """

    length: Float[Array, ""] = array_field(default=0.1)

    def __check_init__(self):
        check_positive("SystemII", "length", self.length)

    def to_chained(self, pose: Pose) -> Chained:
        x, y, t = pose[0] / self.length, pose[1] / self.length, jnp.tan(pose[2])
        return jnp.stack([x, t, x * t - y])

    def to_pose(self, x: Chained) -> Pose:
        return jnp.stack([x[0] * self.length, (x[0] * x[1] - x[2]) * self.length,
                          jnp.arctan(x[1])])

    def velocity(self, pose: Pose, u: Float[Array, 2], x: Chained | None = None
                 ) -> tuple[Array, Array]:
        c = jnp.cos(pose[2])
        return self.length * u[0] / c, u[1] * c * c
