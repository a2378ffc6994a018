"""Magic Formula 1987 (Bakker, Nyborg, Pacejka): hand values, a peer, symmetry, gradients."""

import math
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import assert_grad_matches_fd

from vehsim.params import bakker1987
from vehsim.tire.base import AbstractTire
from vehsim.tire.magic_formula import (
    MagicFormula1987,
    MagicFormula1987Params,
    aligning_coefficients,
    combined_forces,
    combined_forces as _combined_forces,
    lateral_coefficients,
    longitudinal_coefficients,
    pure_aligning_moment,
    pure_lateral_force,
    pure_longitudinal_force,
)


MF = bakker1987()


def test_hand_computed_values_at_4kN():
    """The 1987 formulas written out by hand (Fz = 4 kN, alpha = 5 deg, kappa = 10 %)."""
    fz = 4.0
    # lateral, C = 1.30
    D = -22.1 * fz**2 + 1011 * fz                    # = -353.6 + 4044 = 3690.4 N
    assert D == pytest.approx(3690.4)
    BCD = 1078 * math.sin(1.82 * math.atan(0.208 * fz))  # atan(0.832) = 0.69410
    E = 0.0 * fz**2 - 0.354 * fz + 0.707             # = -0.709
    B = BCD / (1.30 * D)
    x = 5.0
    fy = D * math.sin(1.30 * math.atan(B * x - E * (B * x - math.atan(B * x))))
    assert BCD == pytest.approx(1078 * math.sin(1.82 * 0.6941), rel=1e-4)
    np.testing.assert_allclose(pure_lateral_force(MF, math.radians(5.0), 4000.0), fy, rtol=1e-12)
    # longitudinal, C = 1.65
    D = -21.3 * fz**2 + 1144 * fz                    # = -340.8 + 4576 = 4235.2 N
    assert D == pytest.approx(4235.2)
    BCD = (49.6 * fz**2 + 226 * fz) * math.exp(-0.069 * fz)  # = 1697.6 * exp(-0.276)
    E = -0.006 * fz**2 + 0.056 * fz + 0.486          # = -0.096 + 0.224 + 0.486 = 0.614
    assert E == pytest.approx(0.614)
    B = BCD / (1.65 * D)
    x = 10.0
    fx = D * math.sin(1.65 * math.atan(B * x - E * (B * x - math.atan(B * x))))
    np.testing.assert_allclose(pure_longitudinal_force(MF, 0.10, 4000.0), fx, rtol=1e-12)
    # aligning moment, C = 2.40
    D = -2.72 * fz**2 - 2.28 * fz                    # = -43.52 - 9.12 = -52.64 N m
    BCD = (-1.86 * fz**2 - 2.73 * fz) * math.exp(-0.110 * fz)  # = -40.68 * exp(-0.44)
    E = -0.070 * fz**2 + 0.643 * fz - 4.04           # = -1.12 + 2.572 - 4.04 = -2.588
    assert (D, E) == (pytest.approx(-52.64), pytest.approx(-2.588))
    B = BCD / (2.40 * D)
    x = 5.0
    mz = D * math.sin(2.40 * math.atan(B * x - E * (B * x - math.atan(B * x))))
    np.testing.assert_allclose(pure_aligning_moment(MF, math.radians(5.0), 4000.0), mz,
                               rtol=1e-12)
    # Plausibility of the numbers themselves: peak friction ~ 0.92 (lateral), ~1.06 (long.)
    assert 3300 < float(pure_lateral_force(MF, math.radians(8.0), 4000.0)) < 3700
    assert mz < 0  # aligning for alpha > 0 with our signs


def test_against_commonroad_peer():
    """commonroad-vehicle-models' pure-slip Magic Formula coincides with the 1987 formula when
    its shifts, camber terms and scalings are zero: p_dx1 = D/Fz, p_kx1 = BCD/Fz, p_cx1 = C,
    p_ex1 = E (it negates kappa internally, hence the sign flip)."""
    tm = pytest.importorskip("vehiclemodels.utils.tire_model")
    from vehsim.tire.magic_formula import (
        aligning_coefficients,
        lateral_coefficients,
        longitudinal_coefficients,
    )

    for Fz in (2500.0, 4000.0, 6500.0):
        fz = Fz / 1000.0
        B, C, D, E = (float(v) for v in longitudinal_coefficients(MF, Fz))
        px = types.SimpleNamespace(p_hx1=0.0, p_vx1=0.0, p_dx1=D / fz, p_dx3=0.0, p_cx1=C,
                                   p_ex1=E, p_kx1=B * C * D / fz)
        for kappa in (-0.4, -0.05, 0.02, 0.1, 0.3):
            peer = tm.formula_longitudinal(-100.0 * kappa, 0.0, fz, px)
            np.testing.assert_allclose(pure_longitudinal_force(MF, kappa, Fz), peer, rtol=1e-12)
        for coeffs, ours in ((lateral_coefficients, pure_lateral_force),
                             (aligning_coefficients, pure_aligning_moment)):
            B, C, D, E = (float(v) for v in coeffs(MF, Fz))
            py = types.SimpleNamespace(p_hy1=0.0, p_hy3=0.0, p_vy1=0.0, p_vy3=0.0, p_dy1=D / fz,
                                       p_dy3=0.0, p_cy1=C, p_ey1=E, p_ky1=B * C * D / fz)
            for alpha_deg in (-12.0, -1.0, 2.0, 6.0, 15.0):
                peer = tm.formula_lateral(alpha_deg, 0.0, fz, py)[0]
                np.testing.assert_allclose(ours(MF, math.radians(alpha_deg), Fz), peer,
                                           rtol=1e-12)


def test_combined_slip_recovers_pure_slip_and_symmetry():
    combined_forces = jax.jit(_combined_forces)
    kappa = jnp.linspace(-0.6, 0.6, 13)
    alpha = jnp.deg2rad(jnp.linspace(-20.0, 20.0, 11))
    f = combined_forces(MF, kappa, jnp.zeros_like(kappa), 4000.0)
    np.testing.assert_allclose(f[:, 0], pure_longitudinal_force(MF, kappa, 4000.0), rtol=1e-12)
    np.testing.assert_allclose(f[:, 1:], 0.0, atol=1e-12)
    f = combined_forces(MF, jnp.zeros_like(alpha), alpha, 4000.0)
    np.testing.assert_allclose(f[:, 1], pure_lateral_force(MF, alpha, 4000.0), rtol=1e-12)
    np.testing.assert_allclose(f[:, 2], pure_aligning_moment(MF, alpha, 4000.0), rtol=1e-12,
                               atol=1e-9)
    K, A = jnp.meshgrid(kappa, alpha)
    f = combined_forces(MF, K, A, 4000.0)
    g = combined_forces(MF, -K, A, 4000.0)
    h = combined_forces(MF, K, -A, 4000.0)
    np.testing.assert_allclose(g[..., 0], -f[..., 0], atol=1e-9)  # F_x odd in kappa
    np.testing.assert_allclose(h[..., 1:], -f[..., 1:], atol=1e-9)  # F_y, M_z odd in alpha
    # Combined slip reduces both forces (friction is shared), never increases them.
    assert np.all(np.abs(f[..., 0]) <= np.abs(pure_longitudinal_force(MF, K, 4000.0)) + 1e-9)
    assert np.all(np.abs(f[..., 1]) <= np.abs(pure_lateral_force(MF, A, 4000.0)) + 1e-9)


def test_tire_interface_signs_units_and_gradients():
    tire = MagicFormula1987(MF)
    assert isinstance(tire, AbstractTire)
    assert tire.init_state().shape == (0,)
    # Sliding right (vy < 0) at 20 m/s, 5 deg: F_y > 0, M_z < 0, the pure-slip values.
    a = math.radians(5.0)
    F = tire.forces(tire.init_state(), 20 * math.cos(a), -20 * math.sin(a),
                    20 * math.cos(a) / 0.3, 0.3, 4000.0)
    np.testing.assert_allclose(F[1], pure_lateral_force(MF, a, 4000.0), rtol=2e-3)
    assert F[1] > 0 and F[2] < 0 and abs(F[0]) < 1e-6 * F[1]
    # Finite, correct gradients at standstill and at zero slip.
    def f(x):
        out = tire.forces(jnp.zeros((0,)), x[0], x[1], x[2], 0.3, x[3])
        return jnp.sum(out * jnp.array([1.0, 0.7, 3.0]))

    f = jax.jit(f)
    for x in ([0.0, 0.0, 0.0, 4000.0], [10.0, 0.0, 10.0 / 0.3, 4000.0]):
        assert_grad_matches_fd(f, jnp.array(x), rtol=1e-5, atol=1e-6, eps=1e-7)
    g = jax.jacfwd(lambda x: combined_forces(MF, x[0], x[1], 4000.0))(jnp.zeros(2))
    assert np.all(np.isfinite(g))
    # slope at zero slip = BCD (per % and per degree): units converted inside
    np.testing.assert_allclose(g[0, 0], 100 * (49.6 * 16 + 226 * 4) * math.exp(-0.276),
                               rtol=1e-12)


def test_bad_coefficients_raise():
    with pytest.raises(ValueError, match="b must have 8"):
        MagicFormula1987Params(a=np.zeros(13), b=np.zeros(7), c=np.zeros(13))


def test_load_derivative_at_no_load_is_the_mean_of_the_one_sided_slopes():
    """At F_z = 0 the forces are 0 for F_z <= 0 and rise linearly above: both modes give the
    mean of the one-sided slopes, which a central difference gives, for the combined forces
    and the aligning moment (each was 0: B filled with 0 at D = 0, and the trail's 0/0),
    and B keeps its limit (the value at 1e-9 N)."""
    tire = MagicFormula1987(MF)
    h = 1e-6
    for f in (lambda fz: tire.forces(jnp.zeros(0), 20.0, -1.0, 60.0, 0.3, fz),
              lambda fz: combined_forces(MF, -0.1, 0.05, fz)):
        central = (f(h) - f(-h)) / (2 * h)
        right = (f(h) - f(0.0)) / h
        assert np.all(np.abs(np.asarray(right)) > 1e-4)  # a slope there is to get
        for mode in (jax.jacrev, jax.jacfwd):
            np.testing.assert_allclose(mode(f)(0.0), central, rtol=1e-6)
    for coefficients in (lateral_coefficients, longitudinal_coefficients, aligning_coefficients):
        np.testing.assert_allclose(coefficients(MF, 0.0)[0], coefficients(MF, 1e-9)[0],
                                   rtol=1e-9)
