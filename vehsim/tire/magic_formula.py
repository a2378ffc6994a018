r"""Magic Formula of Bakker, Nyborg and Pacejka (1987, SAE 870421): pure and combined slip.

Pure slip, for each of $F_x(\kappa)$, $F_y(\alpha)$, $M_z(\alpha)$:
$$y(x) = D\sin\bigl(C\arctan(Bx - E(Bx - \arctan Bx))\bigr),\qquad B = \frac{BCD}{CD},$$
with (load $F_z$ in kN, as in the paper)

- lateral, $x = \alpha$ [deg], $C = 1.30$: $D = a_1F_z^2 + a_2F_z$,
  $BCD = a_3\sin(a_4\arctan(a_5F_z))$, $E = a_6F_z^2 + a_7F_z + a_8$ [N];
- longitudinal, $x = \kappa$ [%], $C = 1.65$: $D = b_1F_z^2 + b_2F_z$,
  $BCD = (b_3F_z^2 + b_4F_z)e^{-b_5F_z}$, $E = b_6F_z^2 + b_7F_z + b_8$ [N];
- aligning moment, $x = \alpha$ [deg], $C = 2.40$: $D = c_1F_z^2 + c_2F_z$,
  $BCD = (c_3F_z^2 + c_4F_z)e^{-c_5F_z}$, $E = c_6F_z^2 + c_7F_z + c_8$ [N m].

Camber is not modelled (the camber coefficients $a_9..a_{13}$, $c_9..c_{13}$ are stored in
the preset for completeness); the formula has no shifts at zero camber.

**Units are handled inside:** callers give $F_z$ [N], $\alpha$ [rad] and the slip ratio
$\kappa$ (not percent), and get N and N m.

**Signs** (those of `AbstractTire` and `vehsim.tire.lugre2d`):
$\alpha = \operatorname{atan2}(-v_y, v_x)$ is positive when the wheel slides to its right;
then $F_y > 0$ (to the left) and $M_z < 0$
(aligning; $c_1, c_2 < 0$ make $D_z < 0$). $\kappa = (\omega r - v_x)/|v_x|$, $F_x > 0$ driving.

**Combined slip** by the similarity method the 1987 paper introduced: with the slip vector
$\sigma = (\sigma_x, \sigma_y) = (\kappa, \tan\alpha)$ and $|\sigma|$ its norm, the pure
characteristics are evaluated at the equivalent slips $\kappa_\text{eq} = |\sigma|$,
$\alpha_\text{eq} = \arctan|\sigma|$ and shared out along the slip direction,
$$F_x = \frac{\sigma_x}{|\sigma|}F_{x0}(\kappa_\text{eq}),\quad
  F_y = \frac{\sigma_y}{|\sigma|}F_{y0}(\alpha_\text{eq}),\quad
  M_z = \frac{M_{z0}(\alpha_\text{eq})}{F_{y0}(\alpha_\text{eq})}F_y,$$
the last keeping the pure-slip pneumatic trail. Pure slip is recovered exactly. The paper
writes the theoretical slips with a common factor $1/(1+\kappa)$ and adds corrections for
$\mu_x \ne \mu_y$; we keep the simplest symmetric form (**unverified against the paper's
combined-slip section**), so that $F_x$ is odd in $\kappa$ and $F_y$, $M_z$ odd in $\alpha$.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import check_positive
from .._fields import array_field
from .._math import safe_div, safe_norm
from .base import AbstractTire


class MagicFormula1987Params(eqx.Module):
    r"""Coefficients of the 1987 Magic Formula (units of the paper: kN, deg, %, N, N m).

    - `a` (13,): lateral $a_1..a_{13}$; `b` (8,): longitudinal $b_1..b_8$;
      `c` (13,): aligning $c_1..c_{13}$; `C_y`, `C_x`, `C_z`: shape factors (1.30, 1.65, 2.40).
    """

    a: Float[Array, 13] = array_field()
    b: Float[Array, 8] = array_field()
    c: Float[Array, 13] = array_field()
    C_y: Float[Array, ""] = array_field(default=1.30)
    C_x: Float[Array, ""] = array_field(default=1.65)
    C_z: Float[Array, ""] = array_field(default=2.40)

    def __check_init__(self):
        for name, n in (("a", 13), ("b", 8), ("c", 13)):
            shape = jnp.shape(getattr(self, name))
            if shape[-1:] != (n,):
                raise ValueError(f"MagicFormula1987Params.{name} must have {n} entries, "
                                 f"got shape {shape}")


def magic_formula(x, B, C, D, E):
    r"""$D\sin(C\arctan(Bx - E(Bx - \arctan Bx)))$."""
    return D * _shape(x, B, C, E)


def _shape(x, B, C, E):
    r"""The Magic Formula over its peak $D$: $\sin(C\arctan(Bx - E(Bx - \arctan Bx)))$."""
    bx = B * x
    return jnp.sin(C * jnp.arctan(bx - E * (bx - jnp.arctan(bx))))


def _load_kN(Fz):
    """The load in kN, 0 for a wheel off the ground; at exactly 0 its derivative is the mean
    of the one-sided ones (1/2000 per N), as a central difference gives."""
    return jnp.maximum(jnp.asarray(Fz, dtype=float) / 1000.0, 0.0)


def _stiffness_factor(BCD, C, D, limit):
    r"""$B = BCD/(CD)$, and where $D = 0$ (no load) its limit as $F_z \to 0^+$, `limit`, so
    that the force's load derivative there is its right-hand slope, not 0."""
    return jnp.where(D == 0, limit, safe_div(BCD, C * D))


def lateral_coefficients(params: MagicFormula1987Params, Fz):
    """(B, C, D, E) of $F_{y0}$ at load `Fz` [N] (B per degree)."""
    a, fz = params.a, _load_kN(Fz)
    D = a[0] * fz**2 + a[1] * fz
    BCD = a[2] * jnp.sin(a[3] * jnp.arctan(a[4] * fz))
    E = a[5] * fz**2 + a[6] * fz + a[7]
    limit = safe_div(a[2] * a[3] * a[4], params.C_y * a[1])
    return _stiffness_factor(BCD, params.C_y, D, limit), params.C_y, D, E


def _exponential_stiffness_coefficients(p, C, Fz):
    """(B, C, D, E) for the 1987 form shared by $F_{x0}$ and $M_{z0}$:
    $D = p_1F_z^2 + p_2F_z$, $BCD = (p_3F_z^2 + p_4F_z)e^{-p_5F_z}$,
    $E = p_6F_z^2 + p_7F_z + p_8$ ($F_z$ in kN)."""
    fz = _load_kN(Fz)
    D = p[0] * fz**2 + p[1] * fz
    BCD = (p[2] * fz**2 + p[3] * fz) * jnp.exp(-p[4] * fz)
    E = p[5] * fz**2 + p[6] * fz + p[7]
    return _stiffness_factor(BCD, C, D, safe_div(p[3], C * p[1])), C, D, E


def longitudinal_coefficients(params: MagicFormula1987Params, Fz):
    """(B, C, D, E) of $F_{x0}$ at load `Fz` [N] (B per percent)."""
    return _exponential_stiffness_coefficients(params.b, params.C_x, Fz)


def aligning_coefficients(params: MagicFormula1987Params, Fz):
    """(B, C, D, E) of $M_{z0}$ at load `Fz` [N] (B per degree)."""
    return _exponential_stiffness_coefficients(params.c, params.C_z, Fz)


def pure_longitudinal_force(params: MagicFormula1987Params, kappa, Fz):
    r"""$F_{x0}(\kappa)$ [N], slip ratio $\kappa$ (converted to % inside), load [N]."""
    return magic_formula(100.0 * jnp.asarray(kappa), *longitudinal_coefficients(params, Fz))


def pure_lateral_force(params: MagicFormula1987Params, alpha, Fz):
    r"""$F_{y0}(\alpha)$ [N], slip angle [rad] (converted to degrees inside), load [N]."""
    return magic_formula(jnp.rad2deg(alpha), *lateral_coefficients(params, Fz))


def pure_aligning_moment(params: MagicFormula1987Params, alpha, Fz):
    r"""$M_{z0}(\alpha)$ [N m], slip angle [rad], load [N]."""
    return magic_formula(jnp.rad2deg(alpha), *aligning_coefficients(params, Fz))


def combined_forces_tan(params: MagicFormula1987Params, kappa, tan_alpha, Fz):
    r"""$(F_x, F_y, M_z)$ for slip ratio $\kappa$ and $\tan\alpha$ (module docstring)."""
    kappa, tan_alpha = jnp.broadcast_arrays(jnp.asarray(kappa, dtype=float),
                                            jnp.asarray(tan_alpha, dtype=float))
    sigma = safe_norm(jnp.stack([kappa, tan_alpha], axis=-1))
    alpha_eq = jnp.arctan(sigma)
    fx0 = pure_longitudinal_force(params, sigma, Fz)
    fy0 = pure_lateral_force(params, alpha_eq, Fz)
    # sigma_i / |sigma| * F0(|sigma|): F0 is odd with F0(0) = 0, so F0(s)/s is smooth; use
    # the slope at 0 where sigma = 0 (value 0, finite gradient).
    Bx, Cx, Dx, _ = longitudinal_coefficients(params, Fz)
    By, Cy, Dy, _ = lateral_coefficients(params, Fz)
    slope_x = 100.0 * Bx * Cx * Dx
    slope_y = jnp.rad2deg(1.0) * By * Cy * Dy
    fx = kappa * jnp.where(sigma == 0, slope_x, safe_div(fx0, sigma))
    fy = tan_alpha * jnp.where(sigma == 0, slope_y, safe_div(fy0, sigma))
    # the trail M_z0 / F_y0 with the peaks' ratio D_z / D_y = (c1 F_z + c2) / (a1 F_z + a2)
    # taken out, so that it keeps its limit as the load goes to 0
    Bz, Cz, _, Ez = aligning_coefficients(params, Fz)
    fz = _load_kN(Fz)
    peaks = safe_div(params.c[0] * fz + params.c[1], params.a[0] * fz + params.a[1])
    _, _, _, Ey = lateral_coefficients(params, Fz)
    alpha_deg = jnp.rad2deg(alpha_eq)
    trail0 = peaks * safe_div(Bz * Cz, By * Cy)
    trail = jnp.where(sigma == 0, trail0, peaks * safe_div(_shape(alpha_deg, Bz, Cz, Ez),
                                                           _shape(alpha_deg, By, Cy, Ey)))
    return jnp.stack([fx, fy, trail * fy], axis=-1)


def combined_forces(params: MagicFormula1987Params, kappa, alpha, Fz):
    r"""$(F_x, F_y, M_z)$ [N, N, N m] at slip ratio $\kappa$, slip angle $\alpha$ [rad],
    load $F_z$ [N]."""
    return combined_forces_tan(params, kappa, jnp.tan(alpha), Fz)


class MagicFormula1987(AbstractTire):
    r"""The 1987 Magic Formula as a static `AbstractTire` (state of shape `(0,)`).

    $\kappa = (\omega r - v_x)/\sqrt{v_x^2 + v_\epsilon^2}$ and
    $\tan\alpha = -v_y/\sqrt{v_x^2 + v_\epsilon^2}$: the regularising speed $v_\epsilon$
    [m/s] (default 0.5) keeps forces and gradients finite at standstill, where slips are
    undefined; above a few $v_\epsilon$ the slips are the usual ones.
    """

    params: MagicFormula1987Params
    v_eps: Float[Array, ""] = array_field(default=0.5)

    def __check_init__(self):
        check_positive(type(self).__name__, "v_eps", self.v_eps)

    def init_state(self):
        return jnp.zeros((0,))

    def dynamics(self, state, vx, vy, omega, r, Fz):
        return jnp.zeros((0,))

    def forces(self, state, vx, vy, omega, r, Fz):
        den = jnp.sqrt(vx * vx + self.v_eps**2)
        return combined_forces_tan(self.params, (omega * r - vx) / den, -vy / den, Fz)
