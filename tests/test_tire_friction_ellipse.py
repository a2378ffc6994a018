"""Friction-ellipse Magic Formula of docs/maneuvers.md."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import assert_grad_matches_fd, module_grad_matches_fd

from vehsim import FrictionEllipseTire, LinearTire, preset, rally_gravel_tire


def _spec_numpy(B, C, D, kappa, tan_alpha):
    """The formulas of docs/maneuvers.md, literally, in NumPy (s != 0)."""
    sx = -kappa / (1 + kappa)
    sy = tan_alpha / (1 + kappa)
    s = np.sqrt(sx**2 + sy**2)
    mu = D * np.sin(C * np.arctan(B * s))
    return -(sx / s) * mu, -(sy / s) * mu


def test_matches_spec_formulas_and_is_an_ellipse():
    tire = rally_gravel_tire()
    rng = np.random.default_rng(0)
    kappa = rng.uniform(-0.99, 1.0, 200)
    tan_alpha = rng.uniform(-2.0, 2.0, 200)
    mx, my = jax.vmap(tire.mu)(kappa, tan_alpha)
    ex, ey = _spec_numpy(7.0, 1.6, 0.52, kappa, tan_alpha)
    np.testing.assert_allclose(mx, ex, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(my, ey, rtol=1e-12, atol=1e-14)
    # isotropic: |mu| = mu(s) <= D, peak D reached in pure longitudinal slip
    assert np.all(np.hypot(mx, my) <= 0.52 + 1e-12)
    k = jnp.linspace(0.0, 1.0, 20001)
    assert abs(float(jnp.max(tire.mu(k, 0.0 * k)[0])) - 0.52) < 1e-6
    assert preset("rally_gravel_tire").B == 7.0


def test_signs_follow_abstract_tire_convention():
    tire = rally_gravel_tire()
    mx, _ = tire.mu(0.1, 0.0)  # driving
    assert mx > 0
    mx, _ = tire.mu(-0.1, 0.0)  # braking
    assert mx < 0
    _, my = tire.mu(0.0, -0.1)  # sliding to the right -> force to the left
    assert my > 0


def test_abstract_tire_forces_equal_slip_form():
    tire = rally_gravel_tire()
    r, Fz = 0.3, 4000.0
    for vx, vy, kappa in [(10.0, 1.0, 0.05), (20.0, -3.0, -0.5), (3.0, 0.2, 0.9)]:
        omega = (1 + kappa) * vx / r
        f = tire.forces(tire.init_state(), vx, vy, omega, r, Fz)
        mx, my = tire.mu(kappa, vy / vx)
        np.testing.assert_allclose(f, [mx * Fz, my * Fz, 0.0], rtol=1e-12, atol=1e-9)
    assert tire.dynamics(tire.init_state(), 1.0, 0.0, 1.0, r, Fz).shape == (0,)


def test_locked_wheel_slides_with_limit_friction():
    tire = rally_gravel_tire()
    f = tire.forces(tire.init_state(), 12.0, -5.0, 0.0, 0.3, 1000.0)
    mu_lock = 0.52 * np.sin(1.6 * np.pi / 2)
    np.testing.assert_allclose(np.hypot(f[0], f[1]), mu_lock * 1000.0, rtol=1e-4)
    # force opposes the sliding velocity (12, -5)
    np.testing.assert_allclose(f[1] / f[0], -5.0 / 12.0, rtol=1e-4)


def test_a_wheel_rolling_backwards_gets_the_mirrored_forces():
    """Driving backwards (V_x < 0, omega < 0) is the forward case seen in a mirror: the
    forces change sign with the velocities, not saturate (the slips are over |omega r|)."""
    tire = rally_gravel_tire()
    r, Fz = 0.3, 1000.0
    for vx, vy, kappa in [(10.0, 0.3, 0.0), (5.0, -0.4, -0.2), (8.0, 1.0, 0.1)]:
        omega = (1 + kappa) * vx / r
        ahead = tire.forces(tire.init_state(), vx, vy, omega, r, Fz)
        back = tire.forces(tire.init_state(), -vx, -vy, -omega, r, Fz)
        np.testing.assert_allclose(back, -ahead, rtol=1e-12, atol=1e-9)


def test_gradients_finite_at_zero_slip_and_match_fd():
    tire = rally_gravel_tire()
    g = jax.grad(lambda k: tire.mu(k, 0.0)[0])(0.0)
    np.testing.assert_allclose(g, 7.0 * 1.6 * 0.52, rtol=1e-12)  # slope B C D
    g = jax.grad(lambda a: tire.mu(0.0, a)[1])(0.0)
    np.testing.assert_allclose(g, -7.0 * 1.6 * 0.52, rtol=1e-12)
    # at rest (vx = omega = 0) the forces and their gradients are finite
    gr = jax.grad(lambda v: tire.forces(tire.init_state(), v, 0.0, 0.0, 0.3, 1.0)[0])(0.0)
    assert np.isfinite(gr)
    # parameters, at zero slip and at a combined-slip point
    for kappa, ta in [(0.0, 0.0), (0.12, -0.2)]:
        module_grad_matches_fd(lambda t: t.mu(kappa, ta)[0] + 2 * t.mu(kappa, ta)[1],
                               tire, ["B", "C", "D"])
    assert_grad_matches_fd(lambda x: tire.mu(x[0], x[1])[1], jnp.array([1e-7, 2e-7]))


def test_invalid_parameters_raise():
    with pytest.raises(ValueError, match="FrictionEllipseTire.B"):
        FrictionEllipseTire(B=-1.0, C=1.6, D=0.5)
    with pytest.raises(ValueError, match="LinearTire.c_alpha"):
        LinearTire(c_kappa=10.0, c_alpha=0.0)


def test_slip_law_is_finite_and_continuous_through_a_locked_wheel_in_both_modes():
    """`mu(kappa, tan_alpha)` at kappa = -1 (a locked wheel): the slips over |1 + kappa|
    floored as `forces` floors |omega r|, so the value is the sliding one, the same just
    above and below lock, with equal derivatives in both modes; elsewhere the slips are
    -kappa / (1 + kappa) as before."""
    tire = rally_gravel_tire()

    def mu(k):
        return jnp.stack(tire.mu(k, 0.1))

    at_lock = mu(-1.0)
    np.testing.assert_allclose(np.linalg.norm(at_lock), 0.52 * np.sin(1.6 * np.pi / 2),
                               rtol=1e-4)
    for k in (-1.0 + 1e-9, -1.0 - 1e-9):
        np.testing.assert_allclose(mu(k), at_lock, rtol=1e-8)
    rev, fwd = jax.jacrev(mu)(-1.0), jax.jacfwd(mu)(-1.0)
    assert np.all(np.isfinite(rev)) and np.allclose(rev, fwd, rtol=1e-12, atol=0)
    for k in (-0.9, -0.2, 0.0, 0.3):
        s = np.array([-k, 0.1]) / (1.0 + k)
        g = 0.52 * np.sin(1.6 * np.arctan(7.0 * np.hypot(*s))) / np.hypot(*s)
        np.testing.assert_allclose(mu(k), -s * g, rtol=1e-12)


def test_peak_slip_is_where_the_force_peaks_with_finite_derivatives():
    """`peak_slip` is the arg max of $\\mu(s)$ on a fine grid (B = 7, C = 1.6: 0.2138; and a
    stiff tire of the plant's shape), infinite for $C \\le 1$ (the force rises for ever),
    and its derivatives in $B, C$ are finite in both modes there too and match central
    differences where it is finite."""
    s = np.linspace(0.0, 1.0, 200001)
    for B, C in ((7.0, 1.6), (32.6, 1.53), (3.0, 1.9)):
        tire = FrictionEllipseTire(B=B, C=C, D=0.52)
        grid = s[np.argmax(np.asarray(tire.mu_of_s(jnp.asarray(s))))]
        assert float(tire.peak_slip) == pytest.approx(grid, abs=1e-5)
    assert float(FrictionEllipseTire(B=7.0, C=1.6, D=1.0).peak_slip) == pytest.approx(
        0.213800823, rel=1e-8)
    assert np.isinf(float(FrictionEllipseTire(B=7.0, C=1.0, D=1.0).peak_slip))

    def peak(B, C):
        return FrictionEllipseTire(B=B, C=C, D=1.0).peak_slip

    g = jax.grad(peak, argnums=(0, 1))(7.0, 1.6)
    h = 1e-6
    fd = ((peak(7.0 + h, 1.6) - peak(7.0 - h, 1.6)) / (2 * h),
          (peak(7.0, 1.6 + h) - peak(7.0, 1.6 - h)) / (2 * h))
    np.testing.assert_allclose(np.asarray(g), np.asarray(fd), rtol=1e-6)
    _, tangent = jax.jvp(peak, (7.0, 1.6), (1.0, 0.0))
    assert float(tangent) == pytest.approx(float(g[0]), rel=1e-10)
    # at C <= 1 the value is infinite; its derivatives are zero in both modes, not NaN
    for C in (1.0, 0.9):
        gB, gC = jax.grad(peak, argnums=(0, 1))(7.0, C)
        _, tangent = jax.jvp(peak, (7.0, C), (1.0, 1.0))
        assert float(gB) == 0.0 and float(gC) == 0.0 and float(tangent) == 0.0


def test_lateral_ratio_is_the_ellipses_lateral_semi_axis():
    """With `lateral_ratio` $\\rho_y$ the side force is the circle's times $\\rho_y$ and the
    braking and driving force the circle's, at every slip (the spec's formulas with $\\mu_y$
    scaled); the peak in pure side slip is $\\rho_y D$; 1 is the circle itself, and a ratio
    that is not positive is refused by name."""
    rng = np.random.default_rng(1)
    kappa = rng.uniform(-0.9, 1.0, 100)
    tan_alpha = rng.uniform(-1.0, 1.0, 100)
    tire = FrictionEllipseTire(B=7.0, C=1.6, D=0.52, lateral_ratio=0.9)
    mx, my = jax.vmap(tire.mu)(kappa, tan_alpha)
    ex, ey = _spec_numpy(7.0, 1.6, 0.52, kappa, tan_alpha)
    np.testing.assert_allclose(mx, ex, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(my, 0.9 * ey, rtol=1e-12, atol=1e-14)
    side = jax.vmap(lambda t: tire.mu(0.0, t)[1])(jnp.linspace(0.0, 3.0, 30001))
    assert float(jnp.max(jnp.abs(side))) == pytest.approx(0.9 * 0.52, rel=1e-6)
    circle = FrictionEllipseTire(B=7.0, C=1.6, D=0.52)
    assert float(circle.lateral_ratio) == 1.0
    np.testing.assert_array_equal(jax.vmap(circle.mu)(kappa, tan_alpha)[1],
                                  jax.vmap(rally_gravel_tire().mu)(kappa, tan_alpha)[1])
    with pytest.raises(ValueError, match="lateral_ratio"):
        FrictionEllipseTire(B=7.0, C=1.6, D=0.52, lateral_ratio=0.0)


def test_lateral_stiffness_scales_the_side_slip_in_the_combined_slip():
    """With `lateral_stiffness` $k_y$ the forces are the isotropic tire's at the side slip
    $k_y s_y$, the side component times $k_y$ as well (the force opposes the scaled slip,
    not the slip), NumPy from the formulas; pure side slip has $k_y$ times the braking
    slope at zero slip and its peak at $s^*/k_y$; braking alone does not change; the
    gradient at zero slip is finite; a scale that is not positive is refused by name."""
    rng = np.random.default_rng(2)
    kappa = rng.uniform(-0.9, 1.0, 100)
    tan_alpha = rng.uniform(-1.0, 1.0, 100)
    ky = 0.6
    tire = FrictionEllipseTire(B=30.0, C=1.5, D=0.55, lateral_ratio=0.9, lateral_stiffness=ky)
    mx, my = jax.vmap(tire.mu)(kappa, tan_alpha)
    sx, sy = -kappa / (1 + kappa), ky * tan_alpha / (1 + kappa)
    s = np.sqrt(sx**2 + sy**2)
    mu = 0.55 * np.sin(1.5 * np.arctan(30.0 * s))
    np.testing.assert_allclose(mx, -(sx / s) * mu, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(my, -0.9 * (sy / s) * mu, rtol=1e-12, atol=1e-14)
    iso = FrictionEllipseTire(B=30.0, C=1.5, D=0.55, lateral_ratio=0.9)
    np.testing.assert_array_equal(tire.mu(kappa, 0.0 * kappa)[0], iso.mu(kappa, 0.0 * kappa)[0])
    side_slope = jax.grad(lambda t: tire.mu(0.0, t)[1])(0.0)
    braking_slope = jax.grad(lambda k: tire.mu(k, 0.0)[0])(0.0)
    assert float(side_slope) == pytest.approx(-0.9 * ky * float(braking_slope), rel=1e-12)
    t = jnp.linspace(0.0, 0.5, 200001)
    side = jnp.abs(tire.mu(0.0 * t, t)[1])
    assert float(t[jnp.argmax(side)]) == pytest.approx(float(tire.peak_slip) / ky, abs=1e-5)
    g = jax.grad(lambda k, a: tire.mu(k, a)[1], argnums=(0, 1))(0.0, 0.0)
    assert all(np.isfinite(float(v)) for v in g)
    with pytest.raises(ValueError, match="lateral_stiffness"):
        FrictionEllipseTire(B=7.0, C=1.6, D=0.52, lateral_stiffness=-1.0)
